"""A small, dependency-free EXIF reader, and the focal-length prior that structure-from-motion starts from.

EXIF is a TIFF structure (IFD0 with the camera make, model and orientation, pointing to an Exif IFD with the
exposure and lens data and to a GPS IFD). It lives in a JPEG APP1 segment after ``Exif\\0\\0``, in a PNG ``eXIf``
chunk, or is the file itself for TIFF photos and TIFF-based RAW (DNG, NEF, CR2, ARW, KDC, ...).

Photos come from anywhere, so metadata is best effort: a missing or garbled EXIF block gives an empty
``ExifSummary`` (orientation 1), never an exception. Reference: CIPA DC-008 (EXIF 2.3), TIFF 6.0.
"""

from __future__ import annotations

import math
import struct
from dataclasses import asdict, dataclass
from typing import Any

from nerfpipe.imaging.tiff import (
    Ifd,
    TiffView,
    entry_bytes,
    entry_ints,
    entry_numbers,
    ifd_chain,
    open_tiff,
    read_ifd,
)

# IFD0 (TIFF) tags.
TAG_MAKE = 0x010F
TAG_MODEL = 0x0110
TAG_ORIENTATION = 0x0112
TAG_EXIF_IFD = 0x8769
TAG_GPS_IFD = 0x8825
TAG_DNG_UNIQUE_CAMERA_MODEL = 0xC614
# Exif IFD tags. Several also appear in IFD0 of TIFF/EP-style RAWs (NEF, DNG), which is searched second.
TAG_EXPOSURE_TIME = 0x829A
TAG_F_NUMBER = 0x829D
TAG_ISO = 0x8827
TAG_DATETIME_ORIGINAL = 0x9003
TAG_FOCAL_LENGTH = 0x920A
TAG_PIXEL_X_DIMENSION = 0xA002
TAG_FOCAL_PLANE_X_RESOLUTION = 0xA20E
TAG_FOCAL_PLANE_RESOLUTION_UNIT = 0xA210
TAG_FOCAL_LENGTH_35MM = 0xA405
# TIFF/EP spellings of the focal-plane tags, used by some RAW formats instead of the EXIF ones.
TAG_TIFFEP_FOCAL_PLANE_X_RESOLUTION = 0x920E
TAG_TIFFEP_FOCAL_PLANE_RESOLUTION_UNIT = 0x9210
# GPS IFD tags.
TAG_GPS_LATITUDE_REF = 0x0001
TAG_GPS_LATITUDE = 0x0002
TAG_GPS_LONGITUDE_REF = 0x0003
TAG_GPS_LONGITUDE = 0x0004
TAG_GPS_ALTITUDE_REF = 0x0005
TAG_GPS_ALTITUDE = 0x0006

JPEG_SOI = b"\xff\xd8"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EXIF_HEADER = b"Exif\x00"

# Millimetres per FocalPlaneResolutionUnit (EXIF: 2 inch, 3 cm; TIFF/EP adds 4 mm and 5 micrometre).
_FOCAL_PLANE_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}
# Beyond these a value is garbage, not optics: the longest 35 mm-equivalent zoom sold is ~3000 mm.
_MAX_FOCAL_35MM = 10_000.0
_MAX_FOCAL_MM = 5_000.0


@dataclass(frozen=True)
class ExifSummary:
    """The EXIF fields nerfpipe uses. ``None`` means the tag is absent or unusable.

    ``orientation`` is the EXIF Orientation tag (1..8, 1 when absent or invalid). ``gps`` is
    (latitude, longitude) in signed degrees (south and west negative) and altitude in metres
    (negative below sea level, ``None`` when absent). ``focal_plane_*`` and ``pixel_x_dimension`` are the raw
    tags 0xA20E, 0xA210 and 0xA002, kept so the focal prior can be computed for any image size.
    """

    make: str | None = None
    model: str | None = None
    orientation: int = 1
    focal_length_mm: float | None = None
    focal_length_35mm: float | None = None
    exposure_time_s: float | None = None
    f_number: float | None = None
    iso: int | None = None
    datetime_original: str | None = None
    focal_plane_x_resolution: float | None = None
    focal_plane_resolution_unit: int | None = None
    pixel_x_dimension: int | None = None
    gps: tuple[float, float, float | None] | None = None

    def to_json(self) -> dict[str, Any]:
        """Plain JSON types (``gps`` as a list), with ``None`` kept so every key is always present."""
        fields = asdict(self)
        if self.gps is not None:
            fields["gps"] = list(self.gps)
        return fields


def read_exif(data: bytes) -> ExifSummary:
    """The EXIF summary of a whole image file (JPEG, PNG or TIFF / TIFF-based RAW, found by magic bytes).

    Returns an empty summary for other containers and for missing or garbled EXIF.
    """
    try:
        tiff_bytes = find_exif_tiff(data)
        tiff = open_tiff(tiff_bytes) if tiff_bytes is not None else None
        return summarize_tiff(tiff) if tiff is not None else ExifSummary()
    except (struct.error, ValueError, IndexError, OverflowError):
        # Defence in depth: every read is bounds-checked (and fuzzed in the tests), but metadata must never
        # cost the user a photo.
        return ExifSummary()


def find_exif_tiff(data: bytes) -> bytes | None:
    """The TIFF structure holding the EXIF of a JPEG, PNG or TIFF file, or ``None`` if there is none."""
    if data.startswith(JPEG_SOI):
        return jpeg_exif_tiff(data)
    if data.startswith(PNG_SIGNATURE):
        return png_exif_tiff(data)
    if open_tiff(data) is not None:
        return data
    return None


def jpeg_exif_tiff(data: bytes) -> bytes | None:
    """The TIFF inside the first ``Exif`` APP1 segment, found by walking the markers up to the first scan.

    Walking by segment lengths (rather than searching for ``Exif``) cannot be fooled by an ``Exif`` string in a
    comment or by the EXIF of an embedded thumbnail.
    """
    position = 2
    while position + 4 <= len(data):
        if data[position] != 0xFF:
            return None
        marker = data[position + 1]
        if marker == 0xFF:
            # Fill byte before a marker (ITU T.81 B.1.1.2).
            position += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):
            # Standalone markers (TEM, RST0-7) carry no length.
            position += 2
            continue
        if marker in (0xD9, 0xDA):
            # EXIF must precede the image data (end of image or start of scan).
            return None
        (length,) = struct.unpack_from(">H", data, position + 2)
        segment_end = position + 2 + length
        if length < 2 or segment_end > len(data):
            return None
        payload = data[position + 4 : segment_end]
        if marker == 0xE1 and payload.startswith(EXIF_HEADER):
            # "Exif\0" is followed by one pad byte (normally \0) and then the TIFF header.
            return payload[6:]
        position = segment_end
    return None


def png_exif_tiff(data: bytes) -> bytes | None:
    """The TIFF inside the PNG ``eXIf`` chunk (PNG 1.5 extensions), walking the chunks by their lengths."""
    position = len(PNG_SIGNATURE)
    while position + 8 <= len(data):
        length, chunk_type = struct.unpack_from(">I4s", data, position)
        chunk_end = position + 12 + length
        if chunk_end > len(data):
            return None
        if chunk_type == b"eXIf":
            payload = data[position + 8 : position + 8 + length]
            # Some writers keep the JPEG-style "Exif\0\0" prefix; the standard says the TIFF starts at once.
            return payload[6:] if payload.startswith(EXIF_HEADER) else payload
        if chunk_type == b"IEND":
            return None
        position = chunk_end
    return None


def summarize_tiff(tiff: TiffView) -> ExifSummary:
    """Pick the ``ExifSummary`` fields out of the IFD0 chain, the Exif IFD and the GPS IFD of a TIFF structure.

    Tags are looked up in the Exif IFD first, then along the IFD0 chain: TIFF/EP-style RAWs (NEF, KDC, some
    DNG) write exposure and lens tags straight into IFD0. Orientation is taken from IFD0 only, since later
    IFDs describe thumbnails and previews.
    """
    main_ifds = ifd_chain(tiff, tiff.first_ifd_offset)
    if not main_ifds:
        return ExifSummary()
    ifd0 = main_ifds[0]
    exif_ifd = _sub_ifd(tiff, main_ifds, TAG_EXIF_IFD)
    gps_ifd = _sub_ifd(tiff, main_ifds, TAG_GPS_IFD)
    photo_ifds = ([exif_ifd] if exif_ifd is not None else []) + main_ifds

    orientation = _first_int(tiff, [ifd0], TAG_ORIENTATION)
    iso = _first_int(tiff, photo_ifds, TAG_ISO)
    pixel_x_dimension = _first_int(tiff, photo_ifds, TAG_PIXEL_X_DIMENSION)
    focal_plane_x_resolution = _first_positive(tiff, photo_ifds, TAG_FOCAL_PLANE_X_RESOLUTION) or _first_positive(
        tiff, photo_ifds, TAG_TIFFEP_FOCAL_PLANE_X_RESOLUTION
    )
    focal_plane_resolution_unit = _first_int(tiff, photo_ifds, TAG_FOCAL_PLANE_RESOLUTION_UNIT) or _first_int(
        tiff, photo_ifds, TAG_TIFFEP_FOCAL_PLANE_RESOLUTION_UNIT
    )
    return ExifSummary(
        make=_ascii(tiff, main_ifds, TAG_MAKE),
        # DNGs from cinema cameras may carry only DNG UniqueCameraModel, which names the model just as well.
        model=_ascii(tiff, main_ifds, TAG_MODEL) or _ascii(tiff, main_ifds, TAG_DNG_UNIQUE_CAMERA_MODEL),
        orientation=orientation if orientation is not None and 1 <= orientation <= 8 else 1,
        focal_length_mm=_first_positive(tiff, photo_ifds, TAG_FOCAL_LENGTH),
        focal_length_35mm=_first_positive(tiff, photo_ifds, TAG_FOCAL_LENGTH_35MM),
        exposure_time_s=_first_positive(tiff, photo_ifds, TAG_EXPOSURE_TIME),
        f_number=_first_positive(tiff, photo_ifds, TAG_F_NUMBER),
        iso=iso if iso is not None and iso > 0 else None,
        datetime_original=_ascii(tiff, photo_ifds, TAG_DATETIME_ORIGINAL),
        focal_plane_x_resolution=focal_plane_x_resolution,
        focal_plane_resolution_unit=focal_plane_resolution_unit,
        pixel_x_dimension=pixel_x_dimension if pixel_x_dimension is not None and pixel_x_dimension > 0 else None,
        gps=_gps(tiff, gps_ifd) if gps_ifd is not None else None,
    )


def focal_prior_px(exif: ExifSummary, width: int, height: int) -> tuple[float, str] | None:
    """Focal length in pixels for an image of ``width`` x ``height`` (as oriented and scaled), and its source.

    Follows COLMAP 3.x ``Bitmap::ExifFocalLength`` (src/colmap/sensor/bitmap.cc, FreeImage era), without its
    sensor-width database:

    1. 35 mm equivalent: ``f_px = f35 / 35 * max(width, height)`` (a 35 mm frame is 36 mm wide; COLMAP uses
       35), source ``"exif_35mm"``.
    2. Focal length in mm times the focal-plane resolution: ``FocalPlaneXResolution / unit_mm`` pixels per mm
       of the full-resolution sensor image, rescaled by ``max(width, height) / PixelXDimension`` when
       PixelXDimension is known (so a downscaled image gets a proportionally smaller focal length),
       source ``"exif_focal_plane"``.

    Newer, OpenImageIO-based COLMAP uses the CIPA diagonal rule (``f35 / 43.27 * diagonal``) for step 1; the
    two agree within a few percent for 3:2 and 4:3 images. ``None`` when neither route has sane values.
    """
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    long_side = max(width, height)
    f35 = exif.focal_length_35mm
    if f35 is not None and 0.0 < f35 <= _MAX_FOCAL_35MM:
        return f35 / 35.0 * long_side, "exif_35mm"

    focal_mm = exif.focal_length_mm
    resolution = exif.focal_plane_x_resolution
    unit_mm = _FOCAL_PLANE_UNIT_MM.get(exif.focal_plane_resolution_unit or 0)
    if focal_mm is None or resolution is None or unit_mm is None:
        return None
    if not (0.0 < focal_mm <= _MAX_FOCAL_MM and resolution > 0.0):
        return None
    focal_px = focal_mm * resolution / unit_mm
    if exif.pixel_x_dimension:
        focal_px *= long_side / exif.pixel_x_dimension
    # A focal length over 100x the image size is a >0.6 degree field of view: a unit or tag error, not a lens.
    if not (math.isfinite(focal_px) and 0.0 < focal_px <= 100.0 * long_side):
        return None
    return focal_px, "exif_focal_plane"


def _sub_ifd(tiff: TiffView, parents: list[Ifd], pointer_tag: int) -> Ifd | None:
    """The IFD that ``pointer_tag`` (Exif or GPS IFD pointer) of the first parent having it points to."""
    for parent in parents:
        entry = parent.entries.get(pointer_tag)
        values = entry_ints(tiff, entry) if entry is not None else None
        if values:
            return read_ifd(tiff, values[0])
    return None


def _first_number(tiff: TiffView, ifds: list[Ifd], tag: int) -> float | None:
    """The first finite numeric value of ``tag`` in the first of ``ifds`` that has it."""
    for ifd in ifds:
        entry = ifd.entries.get(tag)
        values = entry_numbers(tiff, entry) if entry is not None else None
        if values and math.isfinite(values[0]):
            return float(values[0])
    return None


def _first_positive(tiff: TiffView, ifds: list[Ifd], tag: int) -> float | None:
    """Like ``_first_number`` but only a positive value counts (focal lengths, exposure, f-number)."""
    value = _first_number(tiff, ifds, tag)
    return value if value is not None and value > 0.0 else None


def _first_int(tiff: TiffView, ifds: list[Ifd], tag: int) -> int | None:
    """``_first_number`` as an int (tags such as ISO are integers but may be stored as any numeric type)."""
    value = _first_number(tiff, ifds, tag)
    return int(value) if value is not None and abs(value) < 2**63 else None


def _ascii(tiff: TiffView, ifds: list[Ifd], tag: int) -> str | None:
    """The text of an ASCII tag, cut at the first NUL and stripped; ``None`` if absent or empty.

    EXIF says ASCII, but phones write UTF-8, so it is decoded as UTF-8 with replacement characters.
    """
    for ifd in ifds:
        entry = ifd.entries.get(tag)
        raw = entry_bytes(tiff, entry) if entry is not None else None
        if raw is None:
            continue
        text = raw.split(b"\x00", 1)[0].decode("utf-8", errors="replace").strip()
        if text:
            return text
    return None


def _degrees(tiff: TiffView, gps_ifd: Ifd, value_tag: int, ref_tag: int, negative_ref: str) -> float | None:
    """A GPS latitude or longitude (degrees, minutes, seconds rationals) in signed decimal degrees."""
    entry = gps_ifd.entries.get(value_tag)
    values = entry_numbers(tiff, entry) if entry is not None else None
    if not values or not all(math.isfinite(v) for v in values[:3]):
        return None
    # Writers that only know whole degrees may store fewer than three values.
    degrees, minutes, seconds = (*values[:3], 0.0, 0.0)[:3]
    decimal = degrees + minutes / 60.0 + seconds / 3600.0
    ref = _ascii(tiff, [gps_ifd], ref_tag)
    if ref is not None and ref[:1].upper() == negative_ref:
        decimal = -abs(decimal)
    return decimal


def _gps(tiff: TiffView, gps_ifd: Ifd) -> tuple[float, float, float | None] | None:
    """(latitude, longitude, altitude) from the GPS IFD, or ``None`` without a valid position."""
    latitude = _degrees(tiff, gps_ifd, TAG_GPS_LATITUDE, TAG_GPS_LATITUDE_REF, "S")
    longitude = _degrees(tiff, gps_ifd, TAG_GPS_LONGITUDE, TAG_GPS_LONGITUDE_REF, "W")
    if latitude is None or longitude is None or abs(latitude) > 90.0 or abs(longitude) > 180.0:
        return None
    altitude = _first_number(tiff, [gps_ifd], TAG_GPS_ALTITUDE)
    # GPSAltitudeRef is a BYTE: 0 above sea level, 1 below.
    if altitude is not None and _first_number(tiff, [gps_ifd], TAG_GPS_ALTITUDE_REF) == 1:
        altitude = -abs(altitude)
    return latitude, longitude, altitude
