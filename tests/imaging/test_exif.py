"""EXIF reading: fields from written blobs, every container, garbage tolerance, real RAW metadata, focal prior."""

from __future__ import annotations

import json
import struct
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nerfpipe.imaging.exif import ExifSummary, find_exif_tiff, focal_prior_px, read_exif, summarize_tiff
from nerfpipe.imaging.tiff import open_tiff

# Hypothesis + session fixtures: the fixture is built once and is read-only, so sharing it is safe.
FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def parse_unguarded(data: bytes) -> ExifSummary:
    """``read_exif`` without its last-resort ``except``, so a missed bounds check fails the fuzz tests."""
    tiff_bytes = find_exif_tiff(data)
    tiff = open_tiff(tiff_bytes) if tiff_bytes is not None else None
    summary = summarize_tiff(tiff) if tiff is not None else ExifSummary()
    assert read_exif(data) == summary
    return summary


def full_tiff(w: ModuleType, byte_order: str = "<", south_west: bool = False) -> bytes:
    """A blob with every field ExifSummary reads, values chosen to be checked by hand below."""
    return w.tiff_blob(
        ifd0={
            0x010F: (w.ASCII, "NIKON CORPORATION"),
            0x0110: (w.ASCII, "NIKON D750"),
            0x0112: (w.SHORT, (6,)),
        },
        exif={
            0x829A: (w.RATIONAL, ((1, 125),)),  # 1/125 s
            0x829D: (w.RATIONAL, ((28, 10),)),  # f/2.8
            0x8827: (w.SHORT, (400,)),
            0x9003: (w.ASCII, "2024:05:17 10:11:12"),
            0x920A: (w.RATIONAL, ((245, 10),)),  # 24.5 mm
            0xA002: (w.LONG, (6016,)),
            0xA20E: (w.RATIONAL, ((601600, 359),)),  # 6016 px over a 3.59 cm wide sensor, in px per cm
            0xA210: (w.SHORT, (3,)),
            0xA405: (w.SHORT, (24,)),
        },
        gps={
            0x0001: (w.ASCII, "S" if south_west else "N"),
            # 48 deg 51' 29.5"
            0x0002: (w.RATIONAL, ((48, 1), (51, 1), (295, 10))),
            0x0003: (w.ASCII, "W" if south_west else "E"),
            # 2 deg 17' 40.2"
            0x0004: (w.RATIONAL, ((2, 1), (17, 1), (402, 10))),
            0x0005: (w.BYTE, (1 if south_west else 0,)),
            0x0006: (w.RATIONAL, ((355, 10),)),  # 35.5 m
        },
        byte_order=byte_order,
    )


@pytest.mark.parametrize("byte_order", ["<", ">"])
def test_fields_round_trip(exif_writer: ModuleType, byte_order: str) -> None:
    summary = read_exif(full_tiff(exif_writer, byte_order))
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


def test_gps_south_west_and_below_sea_level_are_negative(exif_writer: ModuleType) -> None:
    summary = read_exif(full_tiff(exif_writer, south_west=True))
    assert summary.gps == pytest.approx((-48.858194, -2.2945, -35.5), abs=1e-6)


def test_to_json_is_plain_json_with_every_key(exif_writer: ModuleType) -> None:
    full = read_exif(full_tiff(exif_writer)).to_json()
    assert json.loads(json.dumps(full)) == full
    assert isinstance(full["gps"], list) and len(full["gps"]) == 3
    empty = ExifSummary().to_json()
    assert set(empty) == set(full)
    assert empty["orientation"] == 1 and empty["gps"] is None and empty["make"] is None


def test_jpeg_png_and_tiff_containers_give_the_same_summary(exif_writer: ModuleType) -> None:
    w = exif_writer
    tiff = full_tiff(w)
    image = np.full((16, 24, 3), 90, np.uint8)
    expected = read_exif(tiff)

    jpeg = w.jpeg_with_exif(image, tiff)
    ok, png = cv2.imencode(".png", image)
    assert ok
    png_standard = w.png_with_exif(png.tobytes(), tiff)
    # Some writers keep the JPEG-style "Exif\0\0" prefix inside eXIf.
    png_prefixed = w.png_with_exif(png.tobytes(), b"Exif\x00\x00" + tiff)

    assert read_exif(jpeg) == expected
    assert read_exif(png_standard) == expected
    assert read_exif(png_prefixed) == expected


def test_jpeg_exif_is_found_by_walking_markers_not_by_searching(exif_writer: ModuleType) -> None:
    w = exif_writer
    decoy = w.tiff_blob({0x010F: (w.ASCII, "DECOY"), 0x0112: (w.SHORT, (3,))})
    real = w.tiff_blob({0x010F: (w.ASCII, "Canon"), 0x0112: (w.SHORT, (8,))})
    # A comment (COM) segment whose text looks like EXIF, placed before the real APP1: a byte search for
    # "Exif\0\0" would find the decoy first.
    comment_payload = b"Exif\x00\x00" + decoy
    comment = b"\xff\xfe" + struct.pack(">H", len(comment_payload) + 2) + comment_payload
    plain = w.encode_jpeg(np.zeros((8, 8, 3), np.uint8))
    jpeg = w.splice_after_soi(w.splice_after_soi(plain, w.exif_app1(real)), comment)
    assert jpeg.find(b"DECOY") < jpeg.find(b"Canon")

    summary = read_exif(jpeg)
    assert (summary.make, summary.orientation) == ("Canon", 8)


def test_exif_in_a_tiff_file(exif_writer: ModuleType) -> None:
    w = exif_writer
    tiff = w.uncompressed_rgb_tiff(
        np.zeros((4, 6, 3), np.uint8), {0x010F: (w.ASCII, "FUJIFILM"), 0x0112: (w.SHORT, (3,))}
    )
    summary = read_exif(tiff)
    assert (summary.make, summary.orientation) == ("FUJIFILM", 3)


@pytest.mark.parametrize("value", [0, 9, 255, 65535])
def test_invalid_orientation_reads_as_1(exif_writer: ModuleType, value: int) -> None:
    assert read_exif(exif_writer.orientation_tiff(value)).orientation == 1


def test_files_without_exif_give_an_empty_summary(exif_writer: ModuleType) -> None:
    image = np.zeros((8, 8, 3), np.uint8)
    ok, png = cv2.imencode(".png", image)
    assert ok
    for data in (b"", b"\xff\xd8", exif_writer.encode_jpeg(image), png.tobytes(), b"GIF89a" + bytes(100)):
        assert read_exif(data) == ExifSummary()


def test_ifd_cycles_terminate(exif_writer: ModuleType) -> None:
    w = exif_writer
    blob = bytearray(w.tiff_blob({0x010F: (w.ASCII, "Sony"), 0x0110: (w.ASCII, "ILCE-7M3")}))
    # IFD0 holds 2 entries at offset 8; its next-IFD pointer (after 2 + 2*12 bytes) now points back at IFD0.
    struct.pack_into("<I", blob, 8 + 2 + 2 * 12, 8)
    summary = parse_unguarded(bytes(blob))
    assert (summary.make, summary.model) == ("Sony", "ILCE-7M3")


def test_exif_pointer_to_itself_and_absurd_counts(exif_writer: ModuleType) -> None:
    w = exif_writer
    # The Exif IFD pointer points at IFD0 itself: read once, no recursion.
    looped = w.tiff_blob({0x010F: (w.ASCII, "Apple"), 0x8769: (w.LONG, (8,))})
    assert read_exif(looped).make == "Apple"
    # An IFD claiming 60,000 entries in a 30-byte buffer.
    huge_count = b"II*\x00\x08\x00\x00\x00" + struct.pack("<H", 60000) + bytes(20)
    assert parse_unguarded(huge_count) == ExifSummary()
    # A Make tag whose value offset lies far past the end of the buffer.
    far = w.tiff_blob({0x010F: (w.ASCII, "Panasonic-long-name")})
    far = far[:10] + struct.pack("<HHII", 0x010F, 2, 20, 0x7FFFFFF0) + far[22:]
    assert parse_unguarded(far).make is None


@FUZZ
@given(payload=st.binary(max_size=400))
def test_random_bytes_after_exif_header_never_raise(exif_writer: ModuleType, payload: bytes) -> None:
    plain = exif_writer.encode_jpeg(np.zeros((8, 8, 3), np.uint8))
    segment = b"\xff\xe1" + struct.pack(">H", len(payload) + 8) + b"Exif\x00\x00" + payload
    summary = parse_unguarded(exif_writer.splice_after_soi(plain, segment))
    assert isinstance(summary, ExifSummary) and 1 <= summary.orientation <= 8


@FUZZ
@given(magic=st.sampled_from([b"II*\x00", b"MM\x00*"]), rest=st.binary(max_size=400))
def test_random_tiff_headers_never_raise(magic: bytes, rest: bytes) -> None:
    summary = parse_unguarded(magic + rest)
    assert isinstance(summary, ExifSummary) and 1 <= summary.orientation <= 8


@FUZZ
@given(data=st.data())
def test_corrupted_valid_blobs_never_raise(exif_writer: ModuleType, data: st.DataObject) -> None:
    # Structure-aware fuzzing: overwrite a few bytes of a real blob (offsets, counts, types) or cut it short.
    blob = bytearray(full_tiff(exif_writer, data.draw(st.sampled_from(["<", ">"]))))
    for _ in range(data.draw(st.integers(1, 8))):
        position = data.draw(st.integers(0, len(blob) - 1))
        blob[position] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(blob)))
    summary = parse_unguarded(bytes(blob[:cut]))
    assert isinstance(summary, ExifSummary) and 1 <= summary.orientation <= 8


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


def test_focal_prior_from_a_written_blob(exif_writer: ModuleType) -> None:
    # End to end: 35 mm tag 24 on a 6016 x 4016 image -> 24 / 35 * 6016 = 4125.257 px.
    exif = read_exif(full_tiff(exif_writer))
    focal, source = focal_prior_px(exif, 6016, 4016)
    assert (focal, source) == (pytest.approx(24 / 35 * 6016), "exif_35mm")
