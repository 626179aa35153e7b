"""Whether a photo file is whole, checked before any decoder sees it.

Its container is sniffed from its bytes, and its structure walked: a JPEG's markers to EOI, a PNG's
chunks, CRCs and enough image data for its size, a TIFF's IFDs and strips within the file. libjpeg,
libpng and libtiff fill what is missing and only warn.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path
from typing import Literal

from nerfpipe.imaging.tiff import (
    TIFF_BIG_ENDIAN_MAGIC,
    TIFF_LITTLE_ENDIAN_MAGIC,
    TiffView,
    entry_in_bounds,
    entry_ints,
    ifd_runs_past_end,
    open_tiff,
    read_ifd,
)
from nerfpipe.pipeline.errors import BadPhotoError

CONTAINER_NAMES = {"jpeg": "JPEG", "png": "PNG", "tiff": "TIFF", "raw": "camera RAW"}
_JPEG_EOI, _JPEG_SOS = 0xD9, 0xDA
_TIFF_EXIF_IFD_TAG = 0x8769

JPEG_SOI = b"\xff\xd8"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
RECOPY_ADVICE = "copy it again from the camera or card, or remove it from the photo folder"

# BigTIFF headers: decodable by OpenCV (libtiff), but with 8-byte offsets our IFD reader does not walk.
_BIGTIFF_MAGICS = (b"II+\x00", b"MM\x00+")

# In entropy-coded JPEG data a 0xFF byte is followed by 0x00 (stuffing) or RST0-7 (0xD0-0xD7); any other byte
# after 0xFF is a real marker (ITU T.81 B.1.1.5). A 0xFF run is fill, so the marker is the last 0xFF of the run.
_JPEG_MARKER_AFTER_SCAN = re.compile(rb"\xff[\x01-\xcf\xd8-\xfe]")
_JPEG_STANDALONE_MARKERS = frozenset({0x01, *range(0xD0, 0xD8)})
# TIFF tags pointing at image data, as (offsets tag, byte counts tag): strips, tiles, and the JPEG thumbnail
# of IFD1 (JPEGInterchangeFormat / JPEGInterchangeFormatLength).
_TIFF_DATA_TAGS = ((0x0111, 0x0117), (0x0144, 0x0145), (0x0201, 0x0202))
_TIFF_SUB_IFDS_TAG = 0x014A
# PNG colour type -> samples per pixel (PNG spec 11.2.2); and deflate's best compression ratio (RFC 1951)
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
_DEFLATE_MAX_RATIO = 1032
# DNGs and NEFs hold a handful of IFDs; more means a loop we have not caught or garbage.
_MAX_TIFF_IFDS = 256


def sniff_container(data: bytes) -> Literal["jpeg", "png", "tiff"] | None:
    """The image container named by the file's magic bytes, or ``None`` for anything else (including CR3, RAF)."""
    if data.startswith(JPEG_SOI + b"\xff"):
        return "jpeg"
    if data.startswith(PNG_SIGNATURE):
        return "png"
    if data[:4] in (TIFF_LITTLE_ENDIAN_MAGIC, TIFF_BIG_ENDIAN_MAGIC, *_BIGTIFF_MAGICS):
        return "tiff"
    return None


def check_integrity(path: Path, data: bytes, kind: str) -> None:
    """Raise ``BadPhotoError`` if ``data``, the bytes of ``path`` (extension kind ``kind``), is not a whole photo.

    The container is taken from the magic bytes when they are a known one, so a PNG saved as ``.jpg`` is
    checked (and later decoded) as the PNG it is. JPEG must reach its end-of-image marker after the last scan,
    PNG its IEND chunk, and the image data of every TIFF IFD must lie inside the file. RAW containers that are
    not TIFF-based (CR3, RAF, ...) are left to LibRaw.
    """
    if kind not in CONTAINER_NAMES:
        raise ValueError(f"kind must be one of {', '.join(CONTAINER_NAMES)}, got {kind!r}")
    if not data:
        raise BadPhotoError(path, "is empty (0 bytes)", RECOPY_ADVICE)
    container = sniff_container(data)
    if container is None:
        if kind == "raw":
            return
        raise BadPhotoError(
            path,
            f"is not a valid {CONTAINER_NAMES[kind]} file",
            "its content is not a JPEG, PNG or TIFF image; re-export it or remove it from the photo folder",
        )
    if container == "jpeg":
        _check_jpeg(path, data)
    elif container == "png":
        _check_png(path, data)
    else:
        _check_tiff(path, data)


HEAD_BYTES = 1 << 20  # a photo's head: its magic bytes, and a JPEG's segments up to its first scan


def check_head(path: Path, kind: str, size: int = HEAD_BYTES) -> bytes:
    """Read the first ``size`` bytes of ``path`` and raise ``BadPhotoError`` if they are no photo's start: empty,
    not the magic bytes of a JPEG, PNG or TIFF (camera RAW excepted), or a JPEG whose segments before its
    first scan are corrupt. A file is checked this way before it is hashed or read whole (a 3 GB file of
    zeros named .jpg costs a megabyte). Returns the head."""
    try:
        with open(path, "rb") as f:
            head = f.read(size)
    except OSError as err:
        raise BadPhotoError(path, f"cannot be read ({err.strerror or err})",
                            "check that it exists and that you may read it") from err
    if not head:
        raise BadPhotoError(path, "is empty (0 bytes)", RECOPY_ADVICE)
    container = sniff_container(head)
    if container is None and kind != "raw":
        raise BadPhotoError(path, f"is not a valid {CONTAINER_NAMES[kind]} file",
                            "its content is not a JPEG, PNG or TIFF image; re-export it or remove it from the photo folder")
    if container == "jpeg":
        _check_jpeg(path, head, whole=False)
    return head


def _truncated(path: Path, detail: str) -> BadPhotoError:
    return BadPhotoError(path, f"is truncated ({detail})", RECOPY_ADVICE)


def _check_jpeg(path: Path, data: bytes, whole: bool = True) -> None:
    """Walk the JPEG segments by their lengths and require an end-of-image marker after the last scan.

    Segments (APPn with EXIF and its thumbnail, DQT, DHT, SOF, ...) are skipped by length, so the EOI of an
    embedded thumbnail is never mistaken for ours. After each start-of-scan the entropy-coded data runs to the
    next real marker; progressive JPEGs have several scans, each walked in turn. Not ``whole``: ``data`` is the
    file's head, walked to its first scan; running out of it says nothing.
    """
    position = 2
    seen_scan = False

    def ran_out() -> None:
        if whole:
            raise _truncated(path, "JPEG ends before its end-of-image marker")

    while True:
        if position + 2 > len(data):
            ran_out()
            return
        if data[position] != 0xFF:
            # Stray bytes between segments: libjpeg skips to the next marker with a warning; so do we.
            position = data.find(b"\xff", position)
            if position < 0:
                ran_out()
                return
            continue
        marker = data[position + 1]
        if marker == 0xFF:
            position += 1
            continue
        if marker == _JPEG_EOI:
            if not seen_scan:
                raise BadPhotoError(
                    path, "is not a valid JPEG file (it ends before any image data)", RECOPY_ADVICE
                )
            return
        if marker in _JPEG_STANDALONE_MARKERS or marker == 0x00:
            position += 2
            continue
        if position + 4 > len(data):
            ran_out()
            return
        (length,) = struct.unpack_from(">H", data, position + 2)
        if length < 2:
            raise BadPhotoError(
                path, f"is not a valid JPEG file (corrupt segment at byte {position})", RECOPY_ADVICE
            )
        position += 2 + length
        if position > len(data):
            ran_out()
            return
        if marker == _JPEG_SOS:
            if not whole:
                return
            seen_scan = True
            next_marker = _JPEG_MARKER_AFTER_SCAN.search(data, position)
            if next_marker is None:
                raise _truncated(path, "JPEG ends before its end-of-image marker")
            position = next_marker.start()


def _check_png(path: Path, data: bytes) -> None:
    """Walk the PNG chunks by their lengths up to IEND; a chunk running past the end means a cut-off file.

    The image data must also be long enough for the size IHDR states: deflate shrinks data at most 1032
    times (RFC 1951's longest match, 258 bytes, costs at least 2 bits), so shorter IDAT data cannot hold the
    image, and libpng would print its own error line before OpenCV gives up.
    """
    position = len(PNG_SIGNATURE)
    idat_bytes, raw_bytes = 0, 0
    while True:
        if position + 8 > len(data):
            raise _truncated(path, "PNG ends before its IEND chunk")
        length, chunk_type = struct.unpack_from(">I4s", data, position)
        # PNG chunk lengths are limited to 2^31 - 1 (PNG spec 5.3).
        if length >= 2**31:
            raise BadPhotoError(
                path, f"is not a valid PNG file (corrupt chunk at byte {position})", RECOPY_ADVICE
            )
        if chunk_type == b"IHDR" and length >= 10 and position + 18 <= len(data):
            width, height, bit_depth, colour_type = struct.unpack_from(">IIBB", data, position + 8)
            channels = _PNG_CHANNELS.get(colour_type, 1)
            raw_bytes = height * (1 + (width * channels * bit_depth + 7) // 8)  # a filter byte starts each row
        elif chunk_type == b"IDAT":
            idat_bytes += length
        position += 12 + length
        if position > len(data):
            raise _truncated(path, f"PNG chunk {chunk_type.decode('latin-1')!r} runs past the end of the file")
        if chunk_type == b"IEND":
            break
    if idat_bytes * _DEFLATE_MAX_RATIO < raw_bytes:
        raise BadPhotoError(
            path,
            f"is not a valid PNG file (its {idat_bytes} bytes of image data cannot hold the "
            f"{width}x{height} image its header states)",
            RECOPY_ADVICE,
        )


def _check_tiff(path: Path, data: bytes) -> None:
    """Require every IFD (chain, SubIFDs, Exif IFD) and all strip / tile / thumbnail data inside the file."""
    tiff = open_tiff(data)
    if tiff is None:
        # BigTIFF: left to libtiff.
        return
    data_end = _tiff_image_data_end(path, tiff)
    if data_end > len(data):
        raise _truncated(path, f"image data runs to byte {data_end} but the file has {len(data)} bytes")


def _tiff_image_data_end(path: Path, tiff: TiffView) -> int:
    """The largest end offset of the image data that the IFDs of ``tiff`` reference.

    Raises ``BadPhotoError`` when an IFD, an offset table or any value of an image IFD (the IFD0 chain and
    SubIFDs, which libtiff and LibRaw read in full) lies past the end of the file, i.e. the file was cut, or
    when the first IFD is garbage. Values in the Exif IFD are metadata: a bad one there does not stop decoding.
    """
    data_end = 0
    pending = [(tiff.first_ifd_offset, True)]
    visited: set[int] = set()
    while pending and len(visited) < _MAX_TIFF_IFDS:
        offset, is_image_ifd = pending.pop()
        if offset == 0 or offset in visited:
            continue
        visited.add(offset)
        ifd = read_ifd(tiff, offset)
        if ifd is None:
            if ifd_runs_past_end(tiff, offset):
                raise _truncated(path, f"TIFF directory at byte {offset} lies past the end of the file")
            if offset == tiff.first_ifd_offset:
                raise BadPhotoError(path, "is not a valid TIFF file (corrupt first directory)", RECOPY_ADVICE)
            # A garbage pointer to a secondary IFD (e.g. in a maker's private tags) does not stop decoding.
            continue
        if is_image_ifd:
            for entry in ifd.entries.values():
                if not entry_in_bounds(tiff, entry):
                    raise _truncated(path, f"TIFF tag 0x{entry.tag:04X} lies past the end of the file")
        for offsets_tag, counts_tag in _TIFF_DATA_TAGS:
            offsets_entry, counts_entry = ifd.entries.get(offsets_tag), ifd.entries.get(counts_tag)
            if offsets_entry is None or counts_entry is None:
                continue
            if not (entry_in_bounds(tiff, offsets_entry) and entry_in_bounds(tiff, counts_entry)):
                raise _truncated(path, "TIFF strip or tile table lies past the end of the file")
            starts = entry_ints(tiff, offsets_entry) or ()
            sizes = entry_ints(tiff, counts_entry) or ()
            ends = [start + size for start, size in zip(starts, sizes, strict=False) if size > 0]
            data_end = max([data_end, *ends])
        for pointer_tag, child_is_image_ifd in ((_TIFF_SUB_IFDS_TAG, True), (_TIFF_EXIF_IFD_TAG, False)):
            entry = ifd.entries.get(pointer_tag)
            children = entry_ints(tiff, entry) if entry is not None else None
            pending.extend((child, child_is_image_ifd) for child in children or ())
        pending.append((ifd.next_offset, is_image_ifd))
    return data_end
