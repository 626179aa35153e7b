"""EXIF reading: every field from Pillow-written files in every container, garbage tolerance, real RAW
metadata, the focal prior."""

from __future__ import annotations

import json
import math
import struct
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nerfpipe.imaging.exif import (
    ExifSummary,
    focal_prior_px,
    read_exif,
    read_tags,
    summarize,
)
from tests.imaging import photos

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
IMAGE = np.full((16, 24, 3), 90, np.uint8)


def full_exif(byte_order: str = "<", south_west: bool = False) -> tuple[dict, dict, dict]:
    """IFD0, Exif IFD and GPS IFD tags with every field ExifSummary reads, values checked by hand below."""
    ifd0 = {0x010F: "NIKON CORPORATION", 0x0110: "NIKON D750", 0x0112: 6}
    photo = {
        0x829A: Fraction(1, 125),  # 1/125 s
        0x829D: Fraction(28, 10),  # f/2.8
        0x8827: 400,
        0x9003: "2024:05:17 10:11:12",
        0x920A: Fraction(245, 10),  # 24.5 mm
        0xA002: 6016,
        0xA20E: Fraction(601600, 359),  # 6016 px over a 3.59 cm wide sensor, in px per cm
        0xA210: 3,
        0xA405: 24,
    }
    gps = {
        0x0001: "S" if south_west else "N",
        0x0002: (Fraction(48), Fraction(51), Fraction(295, 10)),  # 48 deg 51' 29.5"
        0x0003: "W" if south_west else "E",
        0x0004: (Fraction(2), Fraction(17), Fraction(402, 10)),  # 2 deg 17' 40.2"
        0x0005: b"\x01" if south_west else b"\x00",
        0x0006: Fraction(355, 10),  # 35.5 m
    }
    return ifd0, photo, gps


def full_jpeg(byte_order: str = "<", south_west: bool = False) -> bytes:
    return photos.jpeg(IMAGE, photos.exif(*full_exif(byte_order, south_west), byte_order=byte_order))


def assert_full(summary: ExifSummary) -> None:
    assert summary.make == "NIKON CORPORATION"
    assert summary.model == "NIKON D750"
    assert summary.orientation == 6
    assert summary.exposure_time_s == pytest.approx(1 / 125)
    assert summary.f_number == pytest.approx(2.8)
    assert summary.iso == 400
    assert summary.datetime_original == "2024:05:17 10:11:12"
    assert summary.focal_length_mm == pytest.approx(24.5)
    assert summary.focal_length_35mm == pytest.approx(24.0)
    assert summary.pixel_x_dimension == 6016
    assert summary.focal_plane_x_resolution == pytest.approx(6016 / 3.59)
    assert summary.focal_plane_resolution_unit == 3
    assert summary.gps is not None
    latitude, longitude, altitude = summary.gps
    assert latitude == pytest.approx(48 + 51 / 60 + 29.5 / 3600)  # 48.858194
    assert longitude == pytest.approx(2 + 17 / 60 + 40.2 / 3600)  # 2.294500
    assert altitude == pytest.approx(35.5)


def assert_sane(summary: ExifSummary) -> None:
    """What every summary must satisfy, however garbled the file: the fuzz tests' invariant."""
    assert 1 <= summary.orientation <= 8
    for value in (summary.focal_length_mm, summary.focal_length_35mm, summary.exposure_time_s, summary.f_number,
                  summary.focal_plane_x_resolution):
        assert value is None or (math.isfinite(value) and value > 0)
    assert summary.iso is None or summary.iso > 0
    assert summary.pixel_x_dimension is None or summary.pixel_x_dimension > 0
    if summary.gps is not None:
        assert abs(summary.gps[0]) <= 90 and abs(summary.gps[1]) <= 180
    for text in (summary.make, summary.model, summary.datetime_original):
        assert text is None or (isinstance(text, str) and text == text.strip() and text)
    json.dumps(summary.to_json())


@pytest.mark.parametrize("byte_order", ["<", ">"])
def test_fields_round_trip(byte_order: str) -> None:
    data = full_jpeg(byte_order)
    # Pillow wrote the byte order asked for.
    assert data[data.index(b"Exif\x00\x00") + 6 :][:2] == (b"II" if byte_order == "<" else b"MM")
    assert_full(read_exif(data))


def test_gps_south_west_and_below_sea_level_are_negative() -> None:
    summary = read_exif(full_jpeg(south_west=True))
    assert summary.gps == pytest.approx((-48.858194, -2.2945, -35.5), abs=1e-6)


def test_to_json_is_plain_json_with_every_key() -> None:
    full = read_exif(full_jpeg()).to_json()
    assert json.loads(json.dumps(full)) == full
    assert isinstance(full["gps"], list) and len(full["gps"]) == 3
    empty = ExifSummary().to_json()
    assert set(empty) == set(full)
    assert empty["orientation"] == 1 and empty["gps"] is None and empty["make"] is None


def test_jpeg_png_raf_and_cr3_give_the_same_summary() -> None:
    ifd0, photo, gps = full_exif()
    data = photos.exif(ifd0, photo, gps)
    jpeg = photos.jpeg(IMAGE, data)
    assert_full(read_exif(jpeg))
    assert_full(read_exif(photos.png(IMAGE, data)))
    # A Fujifilm RAF: the EXIF is that of the JPEG it embeds.
    assert_full(read_exif(photos.raf(jpeg)))
    # A Canon CR3: IFD0, the Exif IFD and the GPS IFD in three boxes, each a TIFF of its own.
    cr3 = photos.cr3(photos.exif(ifd0), photos.exif(photo), photos.exif(gps))
    assert_full(read_exif(cr3))


def test_exif_in_tiff_based_raw_files() -> None:
    # DNG, NEF, CR2 and ARW are TIFF files: their IFD0 holds Make and Model (and, in TIFF/EP files, the
    # exposure and lens tags too). Pillow writes IFD0 tags into a TIFF's own directory.
    tags = {0x010F: "FUJIFILM", 0x0112: 3, 0x920A: Fraction(35)}
    data = photos.tiff(IMAGE, photos.exif(tags))
    summary = read_exif(data)
    assert (summary.make, summary.orientation, summary.focal_length_mm) == ("FUJIFILM", 3, 35.0)
    # A CR2 differs from a plain TIFF only by "CR" and a version after the header's first IFD offset.
    assert read_exif(data[:8] + b"CR\x02\x00" + data[12:]).make == "FUJIFILM"


@pytest.mark.parametrize("value", [0, 9, 255, 65535])
def test_invalid_orientation_reads_as_1(value: int) -> None:
    assert read_exif(photos.jpeg(IMAGE, photos.orientation(value))).orientation == 1


def test_files_without_exif_give_an_empty_summary() -> None:
    for data in (b"", b"\xff\xd8", photos.jpeg(IMAGE), photos.png(IMAGE), b"GIF89a" + bytes(100),
                 b"FUJIFILMCCD-RAW ", photos.raf(b"not a jpeg"), photos.cr3(photos.exif())[:40]):
        assert read_exif(data) == ExifSummary()


def _ifd0_next_pointer(tiff: bytes) -> int:
    """Where IFD0's next-IFD offset lies in a little-endian TIFF whose IFD0 is at byte 8."""
    (count,) = struct.unpack_from("<H", tiff, 8)
    return 8 + 2 + 12 * count


def _entry(tiff: bytes, tag: int) -> int:
    """Where the IFD0 entry of ``tag`` lies in a little-endian TIFF whose IFD0 is at byte 8."""
    (count,) = struct.unpack_from("<H", tiff, 8)
    for position in range(10, 10 + 12 * count, 12):
        if struct.unpack_from("<H", tiff, position)[0] == tag:
            return position
    raise AssertionError(f"tag 0x{tag:04X} is not in IFD0")


def test_ifd_cycles_terminate() -> None:
    tiff = bytearray(photos.tiff_structure(photos.exif({0x010F: "Sony", 0x0110: "ILCE-7M3"})))
    # IFD0's next-IFD pointer now points back at IFD0.
    struct.pack_into("<I", tiff, _ifd0_next_pointer(bytes(tiff)), 8)
    summary = read_exif(bytes(tiff))
    assert (summary.make, summary.model) == ("Sony", "ILCE-7M3")


def test_exif_pointer_to_itself_and_absurd_counts() -> None:
    # The Exif IFD pointer points at IFD0 itself: read once, no recursion.
    looped = bytearray(photos.tiff_structure(photos.exif({0x010F: "Apple"}, {0x8827: 100})))
    pointer = _entry(bytes(looped), 0x8769)
    struct.pack_into("<I", looped, pointer + 8, 8)
    summary = read_exif(bytes(looped))
    assert (summary.make, summary.iso) == ("Apple", None)
    # An IFD claiming 60,000 entries in a 30-byte buffer.
    assert read_exif(b"II*\x00\x08\x00\x00\x00" + struct.pack("<H", 60000) + bytes(20)) == ExifSummary()
    # A Make tag whose value offset lies far past the end of the buffer; the Model tag is still read.
    tiff = bytearray(photos.tiff_structure(photos.exif({0x010F: "Panasonic-long-name", 0x0110: "DC-GH6"})))
    struct.pack_into("<I", tiff, _entry(bytes(tiff), 0x010F) + 8, 0x7FFFFFF0)
    summary = read_exif(bytes(tiff))
    assert (summary.make, summary.model) == (None, "DC-GH6")


def test_tags_are_grouped_by_ifd() -> None:
    tags = read_tags(full_jpeg())
    assert {"Image", "EXIF", "GPS"} <= set(tags)
    assert 0x010F in tags["Image"] and 0x829A in tags["EXIF"] and 0x0002 in tags["GPS"]
    assert summarize(tags) == read_exif(full_jpeg())


@FUZZ
@given(payload=st.binary(max_size=400))
def test_random_bytes_after_exif_header_give_a_sane_summary(payload: bytes) -> None:
    plain = photos.jpeg(np.zeros((8, 8, 3), np.uint8))
    segment = b"\xff\xe1" + struct.pack(">H", len(payload) + 8) + b"Exif\x00\x00" + payload
    assert_sane(read_exif(plain[:2] + segment + plain[2:]))


@FUZZ
@given(magic=st.sampled_from([b"II*\x00", b"MM\x00*"]), rest=st.binary(max_size=400))
def test_random_tiff_headers_give_a_sane_summary(magic: bytes, rest: bytes) -> None:
    assert_sane(read_exif(magic + rest))


@FUZZ
@given(data=st.data())
def test_corrupted_valid_exif_gives_a_sane_summary(data: st.DataObject) -> None:
    # Structure-aware fuzzing: overwrite a few bytes of real EXIF (offsets, counts, types) or cut it short.
    byte_order = data.draw(st.sampled_from(["<", ">"]))
    blob = bytearray(photos.tiff_structure(photos.exif(*full_exif(byte_order), byte_order=byte_order)))
    for _ in range(data.draw(st.integers(1, 8))):
        position = data.draw(st.integers(0, len(blob) - 1))
        blob[position] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(blob)))
    assert_sane(read_exif(bytes(blob[:cut])))


def test_real_kdc_metadata(raw_samples: Path) -> None:
    # The Kodak DC50 KDC is TIFF/EP-style: exposure and lens tags sit in IFD0, there is no Exif IFD.
    summary = read_exif((raw_samples / "kodak_dc50.kdc").read_bytes())
    assert summary.make == "Eastman Kodak Company"
    assert summary.model == "Kodak Digital Science DC50 Zoom Camera"
    assert summary.orientation == 1
    assert summary.exposure_time_s == pytest.approx(0.00435)
    assert summary.f_number == pytest.approx(6.2)
    assert summary.focal_length_mm == pytest.approx(37.0)
    assert summary.focal_length_35mm is None and summary.iso is None and summary.gps is None


def test_real_dng_metadata(raw_samples: Path) -> None:
    # This CinemaDNG frame has no Make/Model and no Exif IFD; only DNG UniqueCameraModel names the camera.
    summary = read_exif((raw_samples / "blackmagic.dng").read_bytes())
    assert summary.make is None
    assert summary.model == "Blackmagic Pocket Cinema Camera 4K"
    assert summary.orientation == 1
    assert summary.exposure_time_s is None and summary.focal_length_mm is None and summary.iso is None


def test_focal_prior_from_35mm_equivalent() -> None:
    exif = ExifSummary(focal_length_35mm=28.0, focal_length_mm=4.2)
    # 28 / 35 * 4000 = 3200 px, whichever side is the long one; scales with the image.
    assert focal_prior_px(exif, 4000, 3000) == (pytest.approx(3200.0), "exif_35mm")
    assert focal_prior_px(exif, 3000, 4000) == (pytest.approx(3200.0), "exif_35mm")
    assert focal_prior_px(exif, 1000, 750) == (pytest.approx(800.0), "exif_35mm")


@pytest.mark.parametrize(
    ("unit", "resolution"),
    [(4, 625.0), (3, 6250.0), (2, 625.0 * 25.4)],  # 625 px/mm: 4000 px over a 6.4 mm wide sensor
)
def test_focal_prior_from_focal_plane_resolution(unit: int, resolution: float) -> None:
    exif = ExifSummary(
        focal_length_mm=4.5,
        focal_plane_x_resolution=resolution,
        focal_plane_resolution_unit=unit,
        pixel_x_dimension=4000,
    )
    # Full resolution: 4.5 mm * 625 px/mm = 2812.5 px. Downscaled to 1000 px wide: 2812.5 / 4 = 703.125 px.
    assert focal_prior_px(exif, 4000, 3000) == (pytest.approx(2812.5), "exif_focal_plane")
    assert focal_prior_px(exif, 1000, 750) == (pytest.approx(703.125), "exif_focal_plane")
    # Without PixelXDimension the image is taken to be at the sensor resolution.
    unscaled = ExifSummary(
        focal_length_mm=4.5, focal_plane_x_resolution=resolution, focal_plane_resolution_unit=unit
    )
    assert focal_prior_px(unscaled, 1000, 750) == (pytest.approx(2812.5), "exif_focal_plane")


def test_focal_prior_falls_through_and_rejects_nonsense() -> None:
    plane = {"focal_length_mm": 4.5, "focal_plane_x_resolution": 625.0, "focal_plane_resolution_unit": 4}
    # A zero or absurd 35 mm value is skipped in favour of the focal-plane route.
    for f35 in (0.0, -5.0, 1e6):
        assert focal_prior_px(ExifSummary(focal_length_35mm=f35, **plane), 4000, 3000)[1] == "exif_focal_plane"
    assert focal_prior_px(ExifSummary(), 4000, 3000) is None
    assert focal_prior_px(ExifSummary(focal_length_mm=4.5), 4000, 3000) is None
    # Unit 1 means "no unit" in TIFF: no physical size, no prior.
    assert focal_prior_px(ExifSummary(**{**plane, "focal_plane_resolution_unit": 1}), 4000, 3000) is None
    assert focal_prior_px(ExifSummary(**{**plane, "focal_length_mm": 1e5}), 4000, 3000) is None
    with pytest.raises(ValueError):
        focal_prior_px(ExifSummary(focal_length_35mm=28.0), 0, 3000)


def test_focal_prior_from_a_written_file() -> None:
    # End to end: 35 mm tag 24 on a 6016 x 4016 image -> 24 / 35 * 6016 = 4125.257 px.
    exif = read_exif(full_jpeg())
    focal, source = focal_prior_px(exif, 6016, 4016)
    assert (focal, source) == (pytest.approx(24 / 35 * 6016), "exif_35mm")
