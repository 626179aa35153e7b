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

import io
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from nerfpipe.imaging.exif import ExifSummary, read_exif
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
from nerfpipe.imaging.video import VIDEO_EXTENSIONS
from nerfpipe.pipeline.errors import BadPhotoError

PhotoKind = Literal["jpeg", "png", "tiff", "raw"]

JPEG_SOI = b"\xff\xd8"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

IMAGE_EXTENSIONS = frozenset({".jpg", ".jpeg", ".png", ".tif", ".tiff"})
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
    ".png": "png",
    ".tif": "tiff",
    ".tiff": "tiff",
    **{extension: "raw" for extension in RAW_EXTENSIONS},
}
_CONTAINER_NAMES = {"jpeg": "JPEG", "png": "PNG", "tiff": "TIFF", "raw": "camera RAW"}
_HEIC_EXTENSIONS = frozenset({".heic", ".heif", ".hif"})
_VIDEO_EXTENSIONS = VIDEO_EXTENSIONS | {".insv"}
_CONVERT_TO_PNG_EXTENSIONS = frozenset({".gif", ".bmp", ".webp"})

_RECOPY_ADVICE = "copy it again from the camera or card, or remove it from the photo folder"
# BigTIFF headers: decodable by OpenCV (libtiff), but with 8-byte offsets our IFD reader does not walk.
_BIGTIFF_MAGICS = (b"II+\x00", b"MM\x00+")
# In entropy-coded JPEG data a 0xFF byte is followed by 0x00 (stuffing) or RST0-7 (0xD0-0xD7); any other byte
# after 0xFF is a real marker (ITU T.81 B.1.1.5). A 0xFF run is fill, so the marker is the last 0xFF of the run.
_JPEG_MARKER_AFTER_SCAN = re.compile(rb"\xff[\x01-\xcf\xd8-\xfe]")
_JPEG_STANDALONE_MARKERS = frozenset({0x01, *range(0xD0, 0xD8)})
_JPEG_EOI, _JPEG_SOS = 0xD9, 0xDA
# TIFF tags pointing at image data, as (offsets tag, byte counts tag): strips, tiles, and the JPEG thumbnail
# of IFD1 (JPEGInterchangeFormat / JPEGInterchangeFormatLength).
_TIFF_DATA_TAGS = ((0x0111, 0x0117), (0x0144, 0x0145), (0x0201, 0x0202))
_TIFF_SUB_IFDS_TAG = 0x014A
_TIFF_EXIF_IFD_TAG = 0x8769
_TIFF_ORIENTATION_TAG = 0x0112
_TIFF_SHORT = 3
# PNG colour type -> samples per pixel (PNG spec 11.2.2); and deflate's best compression ratio (RFC 1951)
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
_DEFLATE_MAX_RATIO = 1032
# DNGs and NEFs hold a handful of IFDs; more means a loop we have not caught or garbage.
_MAX_TIFF_IFDS = 256

# RawOptions.highlight_mode names to rawpy.HighlightMode members (LibRaw's -H 0, 1, 2, 5).
_HIGHLIGHT_MODES = {"clip": "Clip", "ignore": "Ignore", "blend": "Blend", "reconstruct": "ReconstructDefault"}
_WHITE_BALANCES = ("camera", "auto", "daylight")


@dataclass(frozen=True)
class RawOptions:
    """How LibRaw develops a camera RAW file.

    ``linear``: gamma 1 and no auto-brightening, so pixel values stay proportional to scene radiance (for HDR
    and exposure-aware training); otherwise the sRGB-like gamma (2.222, 4.5) and LibRaw's auto-brightening.
    ``highlight_mode``: what to do with clipped highlights, one of ``clip``, ``ignore``, ``blend``,
    ``reconstruct``. ``white_balance``: ``camera`` (as shot), ``auto`` (gray world over the image) or
    ``daylight`` (the camera's daylight multipliers, the same for every photo of a capture).
    """

    linear: bool = False
    highlight_mode: str = "clip"
    white_balance: str = "camera"

    def __post_init__(self) -> None:
        if self.highlight_mode not in _HIGHLIGHT_MODES:
            raise ValueError(
                f"highlight_mode must be one of {', '.join(_HIGHLIGHT_MODES)}, got {self.highlight_mode!r}"
            )
        if self.white_balance not in _WHITE_BALANCES:
            raise ValueError(
                f"white_balance must be one of {', '.join(_WHITE_BALANCES)}, got {self.white_balance!r}"
            )


@dataclass(frozen=True)
class SizeLimits:
    """Photos ``read_photo`` refuses from their header, before decoding a pixel.

    ``min_side``: the shorter side must be at least this (a thumbnail or a 1x1 placeholder gives SfM nothing).
    ``max_pixels``: at most this many pixels, so a small file that claims a huge image (a decompression bomb)
    cannot take gigabytes of memory; 0 means no limit. Pillow warns above 89.5 MP and refuses above 179 MP;
    photos from today's cameras and phones reach 200 MP, so the limit is the caller's to choose.
    """

    min_side: int = 0
    max_pixels: int = 0


class PhotoSizeError(BadPhotoError):
    """A photo outside ``SizeLimits``: ``too`` is ``"small"`` or ``"large"``, ``size`` its (width, height)."""

    def __init__(self, path: Path, size: tuple[int, int], too: Literal["small", "large"], advice: str = "") -> None:
        self.size, self.too = size, too
        width, height = size
        if too == "small":
            problem = f"is only {width}x{height} pixels"
        else:
            problem = f"is {width}x{height} pixels ({width * height / 1e6:.0f} megapixels)"
        super().__init__(path, problem, advice)


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

    data = source if isinstance(source, bytes) else None
    try:
        if data is None:
            with open(source, "rb") as f:
                head = f.read(8)
        container = sniff_container(data if data is not None else head)
        plugin = {"jpeg": JpegImagePlugin.JpegImageFile, "png": PngImagePlugin.PngImageFile,
                  "tiff": TiffImagePlugin.TiffImageFile}.get(container or "")
        if plugin is None:
            return None
        with plugin(io.BytesIO(data) if data is not None else str(source)) as image:
            width, height = image.size
            mode = image.mode
            channels = len(image.getbands())
    except Exception:  # Pillow raises SyntaxError, OSError, ValueError, struct.error... on headers it cannot read
        return None
    return PhotoHeader(width, height, channels, 2 if "16" in mode or mode in ("I", "F") else 1)


def check_size(path: Path, size: tuple[int, int], limits: SizeLimits) -> None:
    """Raise ``PhotoSizeError`` when a photo of ``size`` (width, height) is outside ``limits``."""
    width, height = size
    if limits.min_side and min(width, height) < limits.min_side:
        raise PhotoSizeError(path, size, "small")
    if limits.max_pixels and width * height > limits.max_pixels:
        raise PhotoSizeError(path, size, "large")


@dataclass
class DecodedPhoto:
    """One decoded photo.

    ``pixels``: (H, W, 3) RGB or (H, W, 4) RGBA, uint8 (``bit_depth`` 8) or uint16 (``bit_depth`` 16), already
    upright: the EXIF orientation is applied for JPEG/PNG/TIFF, and LibRaw applies a RAW's own flip.
    ``exif`` is the metadata as stored in the file (its ``orientation`` says what was applied, not what is left
    to do). ``linear`` is True only for RAW developed with ``RawOptions(linear=True)``. ``source_size`` is
    (width, height) of ``pixels``, i.e. after orientation.
    """

    pixels: np.ndarray
    bit_depth: int
    has_alpha: bool
    exif: ExifSummary
    is_raw: bool
    linear: bool
    source_size: tuple[int, int]


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
    if kind not in _CONTAINER_NAMES:
        raise ValueError(f"kind must be one of {', '.join(_CONTAINER_NAMES)}, got {kind!r}")
    if not data:
        raise BadPhotoError(path, "is empty (0 bytes)", _RECOPY_ADVICE)
    container = sniff_container(data)
    if container is None:
        if kind == "raw":
            return
        raise BadPhotoError(
            path,
            f"is not a valid {_CONTAINER_NAMES[kind]} file",
            "its content is not a JPEG, PNG or TIFF image; re-export it or remove it from the photo folder",
        )
    if container == "jpeg":
        _check_jpeg(path, data)
    elif container == "png":
        _check_png(path, data)
    else:
        _check_tiff(path, data)


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


def read_photo(path: Path, raw: RawOptions = RawOptions(), limits: SizeLimits = SizeLimits()) -> DecodedPhoto:
    """Read, check and decode one photo into upright RGB(A) pixels (see ``DecodedPhoto``).

    JPEG, PNG and TIFF are decoded by OpenCV without its own orientation handling, and the EXIF orientation
    is applied here; camera RAW is developed by LibRaw (rawpy) as 16-bit sRGB following ``raw``.
    Raises ``BadPhotoError`` for unsupported, unreadable, empty, truncated or undecodable files, and
    ``PhotoSizeError`` for a photo outside ``limits``, from its header, before decoding it.
    """
    path = Path(path)
    kind = photo_kind(path)
    if kind is None:
        raise BadPhotoError(path, "is not a supported photo format", unsupported_advice(path))
    try:
        data = path.read_bytes()
    except OSError as err:
        raise BadPhotoError(
            path, f"cannot be read ({err.strerror or err})", "check that it exists and that you may read it"
        ) from err
    check_integrity(path, data, kind)
    exif = read_exif(data)
    if kind == "raw":
        return _develop_raw(path, data, exif, raw, limits)
    header = read_header(data)
    if header is not None:
        check_size(path, (header.width, header.height), limits)
    return _decode_image(path, data, exif)


def _decode_image(path: Path, data: bytes, exif: ExifSummary) -> DecodedPhoto:
    """Decode a JPEG, PNG or TIFF with OpenCV and make it upright RGB(A)."""
    container = sniff_container(data) or "jpeg"
    if container == "tiff" and exif.orientation != 1:
        # OpenCV's TIFF decoder applies the Orientation tag itself, even with IMREAD_UNCHANGED (its JPEG and
        # PNG decoders do not), and how much of it has changed between versions. Decoding a copy that says
        # "as stored" keeps one rule for every container: OpenCV decodes, we orient.
        data = _tiff_with_stored_orientation(data)
    container_name = _CONTAINER_NAMES[container]
    try:
        # IMREAD_UNCHANGED keeps 16-bit depth and alpha, and (unlike IMREAD_COLOR) leaves orientation to us.
        stored = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as err:
        raise BadPhotoError(
            path, f"cannot be decoded (corrupt or not really a {container_name}: {err.msg})", _RECOPY_ADVICE
        ) from err
    if stored is None or stored.size == 0:
        raise BadPhotoError(path, f"cannot be decoded (corrupt or not really a {container_name})", _RECOPY_ADVICE)
    pixels = _to_rgb(path, stored)
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


def _to_rgb(path: Path, stored: np.ndarray) -> np.ndarray:
    """OpenCV's (H, W), (H, W, 2/3/4) BGR(A) array as (H, W, 3) RGB or (H, W, 4) RGBA, uint8 or uint16.

    Float samples (HDR / scientific TIFF) are clipped to [0, 1] and stored as uint16, so every consumer deals
    with two dtypes only.
    """
    if stored.dtype.kind == "f":
        stored = np.round(np.clip(np.nan_to_num(stored, nan=0.0), 0.0, 1.0) * 65535.0).astype(np.uint16)
    elif stored.dtype not in (np.uint8, np.uint16):
        raise BadPhotoError(
            path,
            f"has an unsupported sample format ({stored.dtype})",
            "export it as an 8- or 16-bit unsigned integer or a float image",
        )
    if stored.ndim == 2:
        stored = stored[:, :, np.newaxis]
    channels = stored.shape[2]
    if channels == 1:
        return np.ascontiguousarray(np.repeat(stored, 3, axis=2))
    if channels == 2:
        gray, alpha = stored[:, :, :1], stored[:, :, 1:]
        return np.ascontiguousarray(np.concatenate([gray, gray, gray, alpha], axis=2))
    if channels == 3:
        return np.ascontiguousarray(stored[:, :, ::-1])
    if channels == 4:
        return np.ascontiguousarray(stored[:, :, [2, 1, 0, 3]])
    raise BadPhotoError(path, f"has {channels} channels", "export it as an RGB or RGBA image (3 or 4 channels)")


def _develop_raw(path: Path, data: bytes, exif: ExifSummary, options: RawOptions, limits: SizeLimits) -> DecodedPhoto:
    """Develop a camera RAW with LibRaw into (H, W, 3) uint16 sRGB; LibRaw applies the RAW's own flip."""
    # rawpy loads LibRaw (a large native library); only pay for it when a RAW file shows up.
    import rawpy

    try:
        with rawpy.imread(io.BytesIO(data)) as raw_image:
            check_size(path, (raw_image.sizes.width, raw_image.sizes.height), limits)
            pixels = raw_image.postprocess(**_postprocess_args(rawpy, options))
    except (rawpy.LibRawError, rawpy.NotSupportedError) as err:
        raise BadPhotoError(
            path,
            f"cannot be decoded by LibRaw ({type(err).__name__}: {_libraw_message(err)})",
            "check that it opens in the camera maker's software; if it does, convert it to DNG "
            "(Adobe DNG Converter) or export a 16-bit TIFF",
        ) from err
    if pixels.ndim == 2:
        # Monochrome sensors come out with one channel.
        pixels = np.repeat(pixels[:, :, np.newaxis], 3, axis=2)
    pixels = np.ascontiguousarray(pixels, dtype=np.uint16)
    return DecodedPhoto(
        pixels=pixels,
        bit_depth=16,
        has_alpha=False,
        exif=exif,
        is_raw=True,
        linear=options.linear,
        source_size=(pixels.shape[1], pixels.shape[0]),
    )


def _postprocess_args(rawpy: Any, options: RawOptions) -> dict[str, Any]:
    """Keyword arguments of ``rawpy.RawPy.postprocess`` for ``options`` (rawpy passed in: it is imported late)."""
    args: dict[str, Any] = {
        "output_bps": 16,
        "output_color": rawpy.ColorSpace.sRGB,
        "highlight_mode": getattr(rawpy.HighlightMode, _HIGHLIGHT_MODES[options.highlight_mode]),
        # Neither flag set means LibRaw's daylight multipliers.
        "use_camera_wb": options.white_balance == "camera",
        "use_auto_wb": options.white_balance == "auto",
    }
    if options.linear:
        args["gamma"] = (1.0, 1.0)
        args["no_auto_bright"] = True
    return args


def _libraw_message(err: Exception) -> str:
    """LibRaw's error text (rawpy passes it as bytes)."""
    message = err.args[0] if err.args else ""
    if isinstance(message, bytes):
        message = message.decode("utf-8", errors="replace")
    return str(message) or "no details"


def _truncated(path: Path, detail: str) -> BadPhotoError:
    return BadPhotoError(path, f"is truncated ({detail})", _RECOPY_ADVICE)


def _check_jpeg(path: Path, data: bytes) -> None:
    """Walk the JPEG segments by their lengths and require an end-of-image marker after the last scan.

    Segments (APPn with EXIF and its thumbnail, DQT, DHT, SOF, ...) are skipped by length, so the EOI of an
    embedded thumbnail is never mistaken for ours. After each start-of-scan the entropy-coded data runs to the
    next real marker; progressive JPEGs have several scans, each walked in turn.
    """
    position = 2
    seen_scan = False
    while True:
        if position + 2 > len(data):
            raise _truncated(path, "JPEG ends before its end-of-image marker")
        if data[position] != 0xFF:
            # Stray bytes between segments: libjpeg skips to the next marker with a warning; so do we.
            position = data.find(b"\xff", position)
            if position < 0:
                raise _truncated(path, "JPEG ends before its end-of-image marker")
            continue
        marker = data[position + 1]
        if marker == 0xFF:
            position += 1
            continue
        if marker == _JPEG_EOI:
            if not seen_scan:
                raise BadPhotoError(
                    path, "is not a valid JPEG file (it ends before any image data)", _RECOPY_ADVICE
                )
            return
        if marker in _JPEG_STANDALONE_MARKERS or marker == 0x00:
            position += 2
            continue
        if position + 4 > len(data):
            raise _truncated(path, "JPEG ends before its end-of-image marker")
        (length,) = struct.unpack_from(">H", data, position + 2)
        if length < 2:
            raise BadPhotoError(
                path, f"is not a valid JPEG file (corrupt segment at byte {position})", _RECOPY_ADVICE
            )
        position += 2 + length
        if position > len(data):
            raise _truncated(path, "JPEG ends before its end-of-image marker")
        if marker == _JPEG_SOS:
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
                path, f"is not a valid PNG file (corrupt chunk at byte {position})", _RECOPY_ADVICE
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
            _RECOPY_ADVICE,
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
                raise BadPhotoError(path, "is not a valid TIFF file (corrupt first directory)", _RECOPY_ADVICE)
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
