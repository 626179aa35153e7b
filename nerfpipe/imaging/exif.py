"""The EXIF fields nerfpipe uses, read with ExifRead, and the focal-length prior structure-from-motion starts from.

ExifRead parses the EXIF of JPEG, PNG, TIFF, HEIC and WebP files and of every TIFF-based camera RAW (DNG, NEF,
NRW, CR2, ARW, SR2, PEF, ORF, RW2, KDC, ...). Two common RAW containers are not TIFF, so the TIFF structures
inside them are handed to ExifRead: a Fujifilm RAF carries a full JPEG with the camera's EXIF (its offset is at
byte 84 of the RAF header), and a Canon CR3 (ISO base media, like MP4) keeps IFD0, the Exif IFD and the GPS IFD
as three TIFF structures in the ``CMT1``, ``CMT2`` and ``CMT4`` boxes of Canon's ``uuid`` box in ``moov``.

Photos come from anywhere, so metadata is best effort: a missing or garbled EXIF block gives an empty
``ExifSummary`` (orientation 1) or just the fields that are sane, never an exception. Tag numbers follow
CIPA DC-008 (EXIF 2.3) and TIFF/EP (ISO 12234-2).
"""

from __future__ import annotations

import io
import logging
import math
import struct
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from fractions import Fraction
from typing import Any

import exifread
from exifread.core.ifd_tag import IfdTag

# ExifRead reports every file without EXIF as a warning on its logger; for nerfpipe that is not news.
logging.getLogger("exifread").setLevel(logging.ERROR)

# IFD0 (TIFF) tags.
TAG_MAKE = 0x010F
TAG_MODEL = 0x0110
TAG_ORIENTATION = 0x0112
TAG_DNG_UNIQUE_CAMERA_MODEL = 0xC614
# Exif IFD tags. Several also appear in IFD0 of TIFF/EP-style RAWs (NEF, KDC, some DNG), which is searched second.
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

RAF_MAGIC = b"FUJIFILMCCD-RAW"
# Canon's box in a CR3's moov: 85c0b687-820f-11e0-8111-f4ce462b6a48.
CR3_CANON_UUID = bytes.fromhex("85c0b687820f11e08111f4ce462b6a48")
# Which IFD each CR3 metadata box holds, by the names ExifRead gives those IFDs in other files.
_CR3_BOXES = {b"CMT1": "Image", b"CMT2": "EXIF", b"CMT4": "GPS"}

# Millimetres per FocalPlaneResolutionUnit (EXIF: 2 inch, 3 cm; TIFF/EP adds 4 mm and 5 micrometre).
_FOCAL_PLANE_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}
# Beyond these a value is garbage, not optics: the longest 35 mm-equivalent zoom sold is ~3000 mm.
_MAX_FOCAL_35MM = 10_000.0
_MAX_FOCAL_MM = 5_000.0

# Tags by IFD: "Image" (IFD0), "Thumbnail" (IFD1), "IFD 2", ..., "EXIF", "GPS", as ExifRead names them.
Tags = dict[str, dict[int, IfdTag]]


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
    """The EXIF summary of a whole photo file: JPEG, PNG, TIFF, a TIFF-based RAW, RAF or CR3.

    Returns an empty summary for other containers and for missing or unreadable EXIF.
    """
    try:
        tags = read_tags(data)
    except Exception:  # noqa: BLE001 - a third-party parser on untrusted bytes; metadata must never cost a photo
        return ExifSummary()
    return summarize(tags)


def read_tags(data: bytes) -> Tags:
    """Every IFD's tags, by IFD name and tag number, with RAF and CR3 unwrapped first."""
    if data.startswith(RAF_MAGIC):
        if len(data) < 92:
            return {}
        jpeg_offset, jpeg_length = struct.unpack_from(">II", data, 84)
        return _exifread(data[jpeg_offset : jpeg_offset + jpeg_length])
    if data[4:12] == b"ftypcrx ":
        tags: Tags = {}
        for box, tiff in _cr3_metadata_boxes(data):
            # Each box is a TIFF of its own whose only IFD ExifRead calls "Image".
            tags[_CR3_BOXES[box]] = _exifread(tiff).get("Image", {})
        return tags
    return _exifread(data)


def summarize(tags: Tags) -> ExifSummary:
    """Pick the ``ExifSummary`` fields out of the IFDs.

    Photo tags are looked up in the Exif IFD first, then along the IFD0 chain: TIFF/EP-style RAWs (NEF, KDC,
    some DNG) write exposure and lens tags straight into IFD0. Orientation is taken from IFD0 only, since later
    IFDs describe thumbnails and previews.
    """
    chain = [tags[name] for name in tags if name == "Image" or name == "Thumbnail" or name.startswith("IFD ")]
    photo = [tags[name] for name in ("EXIF",) if name in tags] + chain
    ifd0 = tags.get("Image", {})

    orientation = _first_int([ifd0], TAG_ORIENTATION)
    iso = _first_int(photo, TAG_ISO)
    pixel_x_dimension = _first_int(photo, TAG_PIXEL_X_DIMENSION)
    return ExifSummary(
        make=_text(chain, TAG_MAKE),
        # DNGs from cinema cameras may carry only DNG UniqueCameraModel, which names the model just as well.
        model=_text(chain, TAG_MODEL) or _text(chain, TAG_DNG_UNIQUE_CAMERA_MODEL),
        orientation=orientation if orientation is not None and 1 <= orientation <= 8 else 1,
        focal_length_mm=_first_positive(photo, TAG_FOCAL_LENGTH),
        focal_length_35mm=_first_positive(photo, TAG_FOCAL_LENGTH_35MM),
        exposure_time_s=_first_positive(photo, TAG_EXPOSURE_TIME),
        f_number=_first_positive(photo, TAG_F_NUMBER),
        iso=iso if iso is not None and iso > 0 else None,
        datetime_original=_text(photo, TAG_DATETIME_ORIGINAL),
        focal_plane_x_resolution=_first_positive(photo, TAG_FOCAL_PLANE_X_RESOLUTION)
        or _first_positive(photo, TAG_TIFFEP_FOCAL_PLANE_X_RESOLUTION),
        focal_plane_resolution_unit=_first_int(photo, TAG_FOCAL_PLANE_RESOLUTION_UNIT)
        or _first_int(photo, TAG_TIFFEP_FOCAL_PLANE_RESOLUTION_UNIT),
        pixel_x_dimension=pixel_x_dimension if pixel_x_dimension is not None and pixel_x_dimension > 0 else None,
        gps=_gps(tags["GPS"]) if "GPS" in tags else None,
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


def _exifread(data: bytes) -> Tags:
    """ExifRead's tags of one file, grouped by IFD (maker notes, sub-IFDs and thumbnails are not read)."""
    flat = exifread.process_file(io.BytesIO(data), details=False, extract_thumbnail=False)
    grouped: Tags = {}
    for key, tag in flat.items():
        if not isinstance(tag, IfdTag):
            continue
        # Keys are "<IFD name> <tag name>"; the IFD name is one word, or "IFD <n>" for the third IFD on.
        words = key.split(" ")
        name = " ".join(words[:2]) if words[0] == "IFD" else words[0]
        grouped.setdefault(name, {})[tag.tag] = tag
    return grouped


def _boxes(data: bytes, start: int, end: int) -> Iterator[tuple[bytes, int, int]]:
    """(type, payload start, payload end) of each ISO base-media box in ``data[start:end]``."""
    position = start
    while position + 8 <= end:
        size, box_type = struct.unpack_from(">I4s", data, position)
        header = 8
        if size == 1 and position + 16 <= end:
            (size,) = struct.unpack_from(">Q", data, position + 8)
            header = 16
        elif size == 0:
            size = end - position
        if size < header or position + size > end:
            return
        yield box_type, position + header, position + size
        position += size


def _cr3_metadata_boxes(data: bytes) -> Iterator[tuple[bytes, bytes]]:
    """(box name, TIFF bytes) of the CMT1, CMT2 and CMT4 boxes in a CR3's Canon ``uuid`` box."""
    for box_type, start, end in _boxes(data, 0, len(data)):
        if box_type != b"moov":
            continue
        for child_type, child_start, child_end in _boxes(data, start, end):
            if child_type != b"uuid" or data[child_start : child_start + 16] != CR3_CANON_UUID:
                continue
            for meta_type, meta_start, meta_end in _boxes(data, child_start + 16, child_end):
                if meta_type in _CR3_BOXES:
                    yield meta_type, data[meta_start:meta_end]


def _numbers(tag: IfdTag) -> list[float]:
    """A tag's values as floats: rationals divided out (``nan`` for a zero denominator); [] for text."""
    if isinstance(tag.values, (str, bytes)):
        return []
    numbers = []
    for value in tag.values:
        # ExifRead gives FLOAT and DOUBLE values as one-element tuples.
        value = value[0] if isinstance(value, tuple) and value else value
        if isinstance(value, Fraction):
            numbers.append(value.numerator / value.denominator if value.denominator else math.nan)
        elif isinstance(value, (int, float)):
            numbers.append(float(value))
    return numbers


def _first_number(ifds: list[dict[int, IfdTag]], tag: int) -> float | None:
    """The first finite numeric value of ``tag`` in the first of ``ifds`` that has it."""
    for ifd in ifds:
        values = _numbers(ifd[tag]) if tag in ifd else []
        if values and math.isfinite(values[0]):
            return values[0]
    return None


def _first_positive(ifds: list[dict[int, IfdTag]], tag: int) -> float | None:
    """Like ``_first_number`` but only a positive value counts (focal lengths, exposure, f-number)."""
    value = _first_number(ifds, tag)
    return value if value is not None and value > 0.0 else None


def _first_int(ifds: list[dict[int, IfdTag]], tag: int) -> int | None:
    """``_first_number`` as an int (tags such as ISO are integers but may be stored as any numeric type)."""
    value = _first_number(ifds, tag)
    return int(value) if value is not None and abs(value) < 2**63 else None


def _text(ifds: list[dict[int, IfdTag]], tag: int) -> str | None:
    """The text of an ASCII tag, stripped; ``None`` if absent or empty.

    EXIF says ASCII, but phones write UTF-8, which ExifRead decodes; text that is not UTF-8 stays bytes and is
    decoded here with replacement characters.
    """
    for ifd in ifds:
        raw = ifd[tag].values if tag in ifd else None
        if isinstance(raw, bytes):
            raw = raw.split(b"\x00", 1)[0].decode("utf-8", errors="replace")
        if isinstance(raw, str) and raw.strip():
            return raw.strip()
    return None


def _degrees(gps: dict[int, IfdTag], value_tag: int, ref_tag: int, negative_ref: str) -> float | None:
    """A GPS latitude or longitude (degrees, minutes, seconds rationals) in signed decimal degrees."""
    values = _numbers(gps[value_tag]) if value_tag in gps else []
    if not values or not all(math.isfinite(v) for v in values[:3]):
        return None
    # Writers that only know whole degrees may store fewer than three values.
    degrees, minutes, seconds = (*values[:3], 0.0, 0.0)[:3]
    decimal = degrees + minutes / 60.0 + seconds / 3600.0
    ref = _text([gps], ref_tag)
    if ref is not None and ref[:1].upper() == negative_ref:
        decimal = -abs(decimal)
    return decimal


def _gps(gps: dict[int, IfdTag]) -> tuple[float, float, float | None] | None:
    """(latitude, longitude, altitude) from the GPS IFD, or ``None`` without a valid position."""
    latitude = _degrees(gps, TAG_GPS_LATITUDE, TAG_GPS_LATITUDE_REF, "S")
    longitude = _degrees(gps, TAG_GPS_LONGITUDE, TAG_GPS_LONGITUDE_REF, "W")
    if latitude is None or longitude is None or abs(latitude) > 90.0 or abs(longitude) > 180.0:
        return None
    altitude = _first_number([gps], TAG_GPS_ALTITUDE)
    # GPSAltitudeRef is a BYTE: 0 above sea level, 1 below.
    if altitude is not None and _first_number([gps], TAG_GPS_ALTITUDE_REF) == 1:
        altitude = -abs(altitude)
    return latitude, longitude, altitude
