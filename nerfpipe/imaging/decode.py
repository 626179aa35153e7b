"""Turn one photo file (JPEG, PNG, TIFF or camera RAW) into upright RGB(A) pixels, or say clearly why not.

Every later stage (feature extraction, undistortion, training) sees the same thing: an (H, W, 3) or
(H, W, 4) uint8/uint16 array with the EXIF orientation already applied, plus the EXIF summary. Bad inputs
(empty, truncated, mislabelled, undecodable) raise ``BadPhotoError`` naming the file and what to do, before a
decoder gets the chance to return half a picture: libjpeg and libpng fill a cut-off image with grey and only
warn, which would silently poison the reconstruction.

Photos are read as bytes with Python (so any path the OS accepts works, spaces and non-ASCII included) and are
never written to.
"""

from __future__ import annotations

import hashlib
import io
import logging
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from nerfpipe.imaging.colour_models import pillow_warnings, tiff_colour_model, to_rgb
from nerfpipe.imaging.exif import ExifSummary, read_exif
from nerfpipe.imaging.integrity import (
    CONTAINER_NAMES,
    HEAD_BYTES,
    RECOPY_ADVICE,
    check_head,
    check_integrity,
    sniff_container,
)
from nerfpipe.imaging.photo import DecodedPhoto, RawOptions, SizeLimits, check_size
from nerfpipe.imaging.tiff import open_tiff, read_ifd
from nerfpipe.imaging.video import VIDEO_EXTENSIONS
from nerfpipe.pipeline.errors import BadPhotoError, InputError

log = logging.getLogger("nerfpipe")

PhotoKind = Literal["jpeg", "png", "tiff", "raw"]


IMAGE_EXTENSIONS = frozenset({".jpg", ".jpeg", ".jpe", ".jfif", ".png", ".tif", ".tiff"})
# The camera RAW formats LibRaw opens (LibRaw's list of supported formats, by file extension).
RAW_EXTENSIONS = frozenset(
    {
        ".3fr", ".ari", ".arw", ".bay", ".cap", ".cr2", ".cr3", ".crw", ".data", ".dcr", ".dcs", ".dng",
        ".drf", ".eip", ".erf", ".fff", ".gpr", ".iiq", ".k25", ".kdc", ".mdc", ".mef", ".mos", ".mrw",
        ".nef", ".nrw", ".obm", ".orf", ".pef", ".ptx", ".pxn", ".r3d", ".raf", ".raw", ".rwl", ".rw2",
        ".rwz", ".sr2", ".srf", ".srw", ".sti", ".x3f",
    }
)  # fmt: skip
# Files that cameras, phones, editors and capture apps leave next to photos; they are skipped without a word.
SIDECAR_EXTENSIONS = frozenset(
    {
        ".txt", ".md", ".json", ".npy", ".npz", ".yml", ".yaml", ".xml", ".xmp", ".csv", ".bin", ".db",
        ".ini", ".log", ".pp3", ".dop", ".thm", ".aae", ".lrv", ".pdf", ".html", ".ply", ".obj",
    }
)  # fmt: skip

_KIND_BY_EXTENSION: dict[str, PhotoKind] = {
    ".jpg": "jpeg",
    ".jpeg": "jpeg",
    ".jpe": "jpeg",
    ".jfif": "jpeg",
    ".png": "png",
    ".tif": "tiff",
    ".tiff": "tiff",
    **{extension: "raw" for extension in RAW_EXTENSIONS},
}
_HEIC_EXTENSIONS = frozenset({".heic", ".heif", ".hif"})
_VIDEO_EXTENSIONS = VIDEO_EXTENSIONS | {".insv"}
_CONVERT_TO_PNG_EXTENSIONS = frozenset({".gif", ".bmp", ".webp"})

_TIFF_ORIENTATION_TAG = 0x0112
_TIFF_SHORT = 3

@dataclass(frozen=True)
class PhotoHeader:
    """What a photo's header says, read without decoding: its stored size, channels and bytes per sample."""

    width: int
    height: int
    channels: int
    bytes_per_sample: int

    @property
    def pixels(self) -> int:
        return self.width * self.height


def read_header(source: Path | bytes) -> PhotoHeader | None:
    """The header of a JPEG, PNG or TIFF (a path or the file's bytes), parsed by Pillow without decoding.

    ``None`` for camera RAW, for containers Pillow does not parse and for headers it cannot read: the decoder
    says what is wrong with those. The plugin classes are used directly because ``PIL.Image.open`` applies
    Pillow's own decompression-bomb limit, which would hide the size.
    """
    from PIL import JpegImagePlugin, PngImagePlugin, TiffImagePlugin

    with pillow_warnings(source if not isinstance(source, bytes) else None):
        return _read_header(source, JpegImagePlugin, PngImagePlugin, TiffImagePlugin)


def _read_header(source: Path | bytes, JpegImagePlugin: Any, PngImagePlugin: Any, TiffImagePlugin: Any) -> PhotoHeader | None:
    try:
        if isinstance(source, bytes):
            data = source
        else:
            with open(source, "rb") as f:
                data = f.read(HEAD_BYTES)  # Pillow walks a JPEG's garbage byte by byte: give it no more
        container = sniff_container(data)
        plugin = {"jpeg": JpegImagePlugin.JpegImageFile, "png": PngImagePlugin.PngImageFile,
                  "tiff": TiffImagePlugin.TiffImageFile}.get(container or "")
        if plugin is None:
            return None
        # a TIFF's IFD may be anywhere in the file: Pillow seeks to it in the file itself
        whole = container == "tiff" and not isinstance(source, bytes)
        with plugin(str(source) if whole else io.BytesIO(data)) as image:
            width, height = image.size
            mode = image.mode
            channels = len(image.getbands())
    except Exception:  # Pillow raises SyntaxError, OSError, ValueError, struct.error... on headers it cannot read
        return None
    return PhotoHeader(width, height, channels, 2 if "16" in mode or mode in ("I", "F") else 1)


def photo_kind(path: Path | str) -> PhotoKind | None:
    """``"jpeg"``, ``"png"``, ``"tiff"`` or ``"raw"`` from the file extension (any case); ``None`` otherwise."""
    return _KIND_BY_EXTENSION.get(Path(path).suffix.lower())


def unsupported_advice(path: Path | str) -> str:
    """What to tell the user about a file in the photo folder that is neither a photo nor a known sidecar."""
    suffix = Path(path).suffix.lower()
    if suffix in _HEIC_EXTENSIONS:
        return "HEIC is not supported; export the photos as JPEG"
    if suffix in _VIDEO_EXTENSIONS:
        return "a video among photos: pass the video on its own (nerfpipe run VIDEO), or move it out of the photo folder"
    if suffix in _CONVERT_TO_PNG_EXTENSIONS:
        return f"{suffix} images are not supported; convert it to PNG"
    return "it is not a photo nerfpipe reads (JPEG, PNG, TIFF or camera RAW); move it out of the photo folder"


def apply_orientation(image: np.ndarray, orientation: int) -> np.ndarray:
    """The upright view of a stored image with EXIF orientation ``orientation`` (1..8), as a contiguous array.

    ``image`` is (H, W) or (H, W, C); values 5..8 swap H and W. Meaning of each value (EXIF 2.3, tag 0x0112:
    where the stored 0th row and 0th column are when the picture is viewed upright) and the fix:

    ====  ==================  =====================================
    1     top, left           as stored
    2     top, right          mirror left-right
    3     bottom, right       rotate 180
    4     bottom, left        mirror top-bottom
    5     left, top           transpose (mirror about the diagonal)
    6     right, top          rotate 90 clockwise
    7     right, bottom       transverse (mirror about the anti-diagonal)
    8     left, bottom        rotate 90 counter-clockwise
    ====  ==================  =====================================
    """
    if orientation == 1:
        upright = image
    elif orientation == 2:
        upright = image[:, ::-1]
    elif orientation == 3:
        upright = image[::-1, ::-1]
    elif orientation == 4:
        upright = image[::-1]
    elif orientation == 5:
        upright = image.swapaxes(0, 1)
    elif orientation == 6:
        upright = image.swapaxes(0, 1)[:, ::-1]
    elif orientation == 7:
        upright = image.swapaxes(0, 1)[::-1, ::-1]
    elif orientation == 8:
        upright = image.swapaxes(0, 1)[::-1]
    else:
        raise ValueError(f"EXIF orientation must be 1..8, got {orientation}")
    return np.ascontiguousarray(upright)


def read_photo(path: Path, raw: RawOptions = RawOptions(), limits: SizeLimits = SizeLimits(),
               sha256: str | None = None) -> DecodedPhoto:
    """Read, check and decode one photo into upright RGB(A) pixels (see ``DecodedPhoto``).

    JPEG, PNG and TIFF are decoded by OpenCV without its own orientation handling, and the EXIF orientation
    is applied here; camera RAW is developed by LibRaw (rawpy) as 16-bit sRGB following ``raw``.
    Raises ``BadPhotoError`` for unsupported, unreadable, empty, truncated or undecodable files, and
    ``PhotoSizeError`` for a photo outside ``limits``, from its header, before decoding it. ``sha256``: the
    hash the file was cached under; bytes read that hash otherwise (the file changed since) raise ``InputError``,
    so pixels are never stored under another file's hash.
    """
    path = Path(path)
    kind = photo_kind(path)
    if kind is None:
        raise BadPhotoError(path, "is not a supported photo format", unsupported_advice(path))
    head = check_head(path, kind)  # before the whole file is read: a huge file of garbage costs its head only
    header = read_header(head) if kind != "raw" else None
    if header is not None:
        check_size(path, (header.width, header.height), limits)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise BadPhotoError(
            path, f"cannot be read ({err.strerror or err})", "check that it exists and that you may read it"
        ) from err
    if sha256 is not None and hashlib.sha256(data).hexdigest() != sha256:
        raise InputError(path, "changed while nerfpipe was reading it (its content is not what was hashed when the "
                               "run began)", "let whatever writes it finish, then run again")
    check_integrity(path, data, kind)
    exif = read_exif(data)
    if kind == "raw":
        from nerfpipe.imaging.raw import develop_raw  # rawpy loads LibRaw: only when a RAW shows up

        return develop_raw(path, data, exif, raw, limits)
    if header is None and (header := read_header(data)) is not None:  # a TIFF whose IFD lies past the head
        check_size(path, (header.width, header.height), limits)
    return _decode_image(path, data, exif)


def _decode_image(path: Path, data: bytes, exif: ExifSummary) -> DecodedPhoto:
    """Decode a JPEG (libjpeg-turbo, strictly), PNG or TIFF (OpenCV) and make it upright RGB(A)."""
    container = sniff_container(data) or "jpeg"
    if container == "tiff" and exif.orientation != 1:
        # OpenCV's TIFF decoder applies the Orientation tag itself, even with IMREAD_UNCHANGED (its JPEG and
        # PNG decoders do not), and how much of it has changed between versions. Decoding a copy that says
        # "as stored" keeps one rule for every container: OpenCV decodes, we orient.
        data = _tiff_with_stored_orientation(data)
    container_name = CONTAINER_NAMES[container]
    stored = _decode_jpeg_strictly(path, data) if container == "jpeg" else None
    try:
        # IMREAD_UNCHANGED keeps 16-bit depth and alpha, and (unlike IMREAD_COLOR) leaves orientation to us.
        if stored is None:
            stored = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as err:
        raise BadPhotoError(
            path, f"cannot be decoded (corrupt or not really a {container_name}: {err.msg})", RECOPY_ADVICE
        ) from err
    if stored is None or stored.size == 0:
        raise BadPhotoError(path, f"cannot be decoded (corrupt or not really a {container_name})", RECOPY_ADVICE)
    if container == "tiff":
        stored = tiff_colour_model(path, data, stored)
    pixels = to_rgb(path, stored)
    pixels = apply_orientation(pixels, exif.orientation)
    return DecodedPhoto(
        pixels=pixels,
        bit_depth=8 if pixels.dtype == np.uint8 else 16,
        has_alpha=pixels.shape[2] == 4,
        exif=exif,
        is_raw=False,
        linear=False,
        source_size=(pixels.shape[1], pixels.shape[0]),
    )


def _decode_jpeg_strictly(path: Path, data: bytes) -> np.ndarray | None:
    """A JPEG's pixels as BGR, decoded by libjpeg-turbo (simplejpeg) with its warnings as errors.

    libjpeg decodes damaged image data with a warning on stderr ("Corrupt JPEG data: ... extraneous bytes")
    and grey or green blocks where the data was; OpenCV passes that image on as if whole. Here a JPEG that
    decodes only with such a warning raises ``BadPhotoError``. ``None`` for a JPEG simplejpeg does not decode
    at all (CMYK, 12-bit, arithmetic coding), which OpenCV then tries."""
    import simplejpeg  # libjpeg-turbo's TurboJPEG API, as ingest's decoder of JPEGs

    try:
        return simplejpeg.decode_jpeg(data, colorspace="BGR", strict=True)
    except ValueError as strict_error:
        try:
            simplejpeg.decode_jpeg(data, colorspace="BGR", strict=False)
        except ValueError:
            return None
        raise BadPhotoError(path, f"has damaged image data (libjpeg: {str(strict_error).strip()})",
                            RECOPY_ADVICE) from None


def _tiff_with_stored_orientation(data: bytes) -> bytes:
    """A copy of TIFF ``data`` whose IFD0 Orientation tag reads 1 (as stored); the file itself is not touched."""
    tiff = open_tiff(data)
    ifd0 = read_ifd(tiff, tiff.first_ifd_offset) if tiff is not None else None
    entry = ifd0.entries.get(_TIFF_ORIENTATION_TAG) if ifd0 is not None else None
    if tiff is None or entry is None or entry.type != _TIFF_SHORT or entry.count != 1:
        return data
    patched = bytearray(data)
    struct.pack_into(tiff.byte_order + "H", patched, entry.value_offset, 1)
    return bytes(patched)


