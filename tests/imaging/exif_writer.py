"""A minimal EXIF / TIFF writer for the imaging tests (not part of nerfpipe: the package only reads).

``tiff_blob`` lays out a little TIFF: header, IFD0, then optional Exif, GPS and IFD1 (thumbnail) IFDs, then a
data area holding every value longer than 4 bytes and every ``Blob``. IFDs come before the data, as in a DNG,
so cutting the file inside the data area leaves the directories readable and only the strips missing.
``exif_app1``/``splice_after_soi`` and ``png_with_exif`` put such a blob into a JPEG or PNG.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

BYTE, ASCII, SHORT, LONG, RATIONAL, UNDEFINED, SRATIONAL = 1, 2, 3, 4, 5, 7, 10

TAG_EXIF_IFD = 0x8769
TAG_GPS_IFD = 0x8825


@dataclass(frozen=True)
class Blob:
    """A LONG field whose value is the offset of these bytes, placed in the data area (strips, thumbnails)."""

    data: bytes


@dataclass(frozen=True)
class _IfdRef:
    name: str


Field = tuple[int, Any]


def _value_bytes(field_type: int, value: Any, order: str) -> tuple[int, bytes]:
    """(count, packed bytes) of one field value."""
    if field_type == ASCII:
        raw = value.encode("utf-8") + b"\x00"
        return len(raw), raw
    if field_type in (BYTE, UNDEFINED) and isinstance(value, bytes):
        return len(value), value
    if field_type in (RATIONAL, SRATIONAL):
        code = "I" if field_type == RATIONAL else "i"
        flat = [part for pair in value for part in pair]
        return len(value), struct.pack(f"{order}{len(flat)}{code}", *flat)
    code = {BYTE: "B", UNDEFINED: "B", SHORT: "H", LONG: "I"}[field_type]
    return len(value), struct.pack(f"{order}{len(value)}{code}", *value)


def tiff_blob(
    ifd0: dict[int, Field],
    exif: dict[int, Field] | None = None,
    gps: dict[int, Field] | None = None,
    ifd1: dict[int, Field] | None = None,
    byte_order: str = "<",
) -> bytes:
    """A TIFF structure with the given tags: ``{tag: (type, value)}``.

    Values: ``str`` for ASCII, ``bytes`` for UNDEFINED, a tuple of ints for BYTE/SHORT/LONG, a tuple of
    (numerator, denominator) pairs for RATIONAL/SRATIONAL, or ``Blob`` for a LONG offset to some data.
    The Exif and GPS IFD pointers are added to IFD0 when those dicts are given; IFD1 is chained after IFD0.
    """
    ifds: dict[str, dict[int, Any]] = {"ifd0": dict(ifd0)}
    if exif is not None:
        ifds["ifd0"][TAG_EXIF_IFD] = (LONG, _IfdRef("exif"))
        ifds["exif"] = dict(exif)
    if gps is not None:
        ifds["ifd0"][TAG_GPS_IFD] = (LONG, _IfdRef("gps"))
        ifds["gps"] = dict(gps)
    if ifd1 is not None:
        ifds["ifd1"] = dict(ifd1)

    offsets: dict[str, int] = {}
    position = 8
    for name, fields in ifds.items():
        offsets[name] = position
        position += 2 + 12 * len(fields) + 4
    data_area = bytearray()
    data_start = position

    def place(raw: bytes) -> int:
        # Word-align every value, as TIFF 6.0 asks.
        if len(data_area) % 2:
            data_area.append(0)
        offset = data_start + len(data_area)
        data_area.extend(raw)
        return offset

    out = bytearray(b"II*\x00" if byte_order == "<" else b"MM\x00*")
    out += struct.pack(byte_order + "I", 8)
    for name, fields in ifds.items():
        out += struct.pack(byte_order + "H", len(fields))
        for tag in sorted(fields):
            field_type, value = fields[tag]
            if isinstance(value, _IfdRef):
                count, inline = 1, struct.pack(byte_order + "I", offsets[value.name])
            elif isinstance(value, Blob):
                count, inline = 1, struct.pack(byte_order + "I", place(value.data))
            else:
                count, raw = _value_bytes(field_type, value, byte_order)
                inline = raw.ljust(4, b"\x00") if len(raw) <= 4 else struct.pack(byte_order + "I", place(raw))
            out += struct.pack(byte_order + "HHI", tag, field_type, count) + inline
        next_ifd = offsets["ifd1"] if name == "ifd0" and "ifd1" in ifds else 0
        out += struct.pack(byte_order + "I", next_ifd)
    assert len(out) == data_start
    return bytes(out + data_area)


def orientation_tiff(orientation: int, byte_order: str = "<") -> bytes:
    """An EXIF TIFF holding only an Orientation tag."""
    return tiff_blob({0x0112: (SHORT, (orientation,))}, byte_order=byte_order)


def exif_app1(tiff: bytes) -> bytes:
    """A JPEG APP1 segment carrying ``tiff`` as EXIF."""
    payload = b"Exif\x00\x00" + tiff
    return b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload


def splice_after_soi(jpeg: bytes, segment: bytes) -> bytes:
    """Insert a marker segment right after the JPEG start-of-image marker (where EXIF APP1 belongs)."""
    assert jpeg[:2] == b"\xff\xd8"
    return jpeg[:2] + segment + jpeg[2:]


def encode_jpeg(image_bgr: np.ndarray, quality: int = 100, progressive: bool = False) -> bytes:
    """JPEG bytes from OpenCV (which writes no EXIF of its own)."""
    params = [cv2.IMWRITE_JPEG_QUALITY, quality, cv2.IMWRITE_JPEG_PROGRESSIVE, int(progressive)]
    ok, encoded = cv2.imencode(".jpg", image_bgr, params)
    assert ok
    return encoded.tobytes()


def jpeg_with_exif(image_bgr: np.ndarray, tiff: bytes, quality: int = 100) -> bytes:
    """A JPEG of ``image_bgr`` with ``tiff`` spliced in as its EXIF."""
    return splice_after_soi(encode_jpeg(image_bgr, quality), exif_app1(tiff))


def png_chunk(chunk_type: bytes, payload: bytes) -> bytes:
    """One PNG chunk: length, type, payload, CRC-32 over type and payload."""
    crc = zlib.crc32(chunk_type + payload)
    return struct.pack(">I", len(payload)) + chunk_type + payload + struct.pack(">I", crc)


def png_with_exif(png: bytes, tiff: bytes) -> bytes:
    """``png`` with an ``eXIf`` chunk inserted right after IHDR (8-byte signature + 25-byte IHDR chunk)."""
    head = 8 + 25
    assert png[12:16] == b"IHDR"
    return png[:head] + png_chunk(b"eXIf", tiff) + png[head:]


def png_gray_alpha(gray_alpha: np.ndarray) -> bytes:
    """An 8-bit gray+alpha PNG (colour type 4) of an (H, W, 2) uint8 array; OpenCV cannot write these."""
    height, width = gray_alpha.shape[:2]
    rows = b"".join(b"\x00" + gray_alpha[y].tobytes() for y in range(height))
    header = struct.pack(">IIBBBBB", width, height, 8, 4, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + png_chunk(b"IHDR", header)
        + png_chunk(b"IDAT", zlib.compress(rows))
        + png_chunk(b"IEND", b"")
    )


def uncompressed_rgb_tiff(image_rgb: np.ndarray, extra_ifd0: dict[int, Field] | None = None) -> bytes:
    """A baseline RGB TIFF (one uncompressed strip after the directory) of an (H, W, 3) uint8 array."""
    height, width = image_rgb.shape[:2]
    strip = np.ascontiguousarray(image_rgb).tobytes()
    ifd0: dict[int, Field] = {
        0x0100: (LONG, (width,)),
        0x0101: (LONG, (height,)),
        0x0102: (SHORT, (8, 8, 8)),
        0x0103: (SHORT, (1,)),  # no compression
        0x0106: (SHORT, (2,)),  # RGB
        0x0111: (LONG, Blob(strip)),
        0x0115: (SHORT, (3,)),
        0x0116: (LONG, (height,)),
        0x0117: (LONG, (len(strip),)),
        0x011C: (SHORT, (1,)),  # chunky
        **(extra_ifd0 or {}),
    }
    return tiff_blob(ifd0)
