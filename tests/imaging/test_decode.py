"""Photo decoding: orientation, integrity checks, bit depth and alpha, odd paths, real camera RAW files."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nerfpipe.imaging.photo import DecodedPhoto, PhotoSizeError, RawOptions, SizeLimits
from nerfpipe.imaging.decode import (
    IMAGE_EXTENSIONS,
    RAW_EXTENSIONS,
    SIDECAR_EXTENSIONS,
    PhotoHeader,
    apply_orientation,
    photo_kind,
    read_header,
    read_photo,
    unsupported_advice,
)
from nerfpipe.imaging.integrity import check_integrity
from nerfpipe.pipeline.errors import BadPhotoError
from tests.helpers import TEMPLE
from tests.imaging import photos

TEMPLE_PNG = TEMPLE / "templeSR0001.png"


def corner_image() -> np.ndarray:
    """48 x 32 BGR image with a distinct colour in three corners, so every flip and rotation is visible."""
    image = np.full((32, 48, 3), 128, np.uint8)
    image[:8, :8] = (0, 0, 255)  # top-left red
    image[:8, -8:] = (0, 255, 0)  # top-right green
    image[-8:, :8] = (255, 0, 0)  # bottom-left blue
    return image


def noisy_image(height: int = 96, width: int = 128, seed: int = 0) -> np.ndarray:
    """Random BGR pixels: they compress badly, so the JPEG entropy-coded data is long and easy to cut into."""
    return np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)


def write(folder: Path, name: str, data: bytes) -> Path:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def png_bytes(image: np.ndarray) -> bytes:
    ok, encoded = cv2.imencode(".png", image)
    assert ok
    return encoded.tobytes()


def assert_bad_photo(path: Path, *fragments: str) -> BadPhotoError:
    """read_photo must raise BadPhotoError naming the file and containing each fragment."""
    with pytest.raises(BadPhotoError) as caught:
        read_photo(path)
    message = str(caught.value)
    assert path.name in message
    for fragment in fragments:
        assert fragment in message
    return caught.value


# --- extensions --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "kind"),
    [
        ("a.jpg", "jpeg"),
        ("A.JPEG", "jpeg"),
        ("scan.PNG", "png"),
        ("x.Tif", "tiff"),
        ("x.tiff", "tiff"),
        ("DSC_0001.NEF", "raw"),
        ("frame.dng", "raw"),
        ("IMG_0001.CR3", "raw"),
        ("IMG_0001.HEIC", None),
        ("notes.txt", None),
        ("README", None),
    ],
)
def test_photo_kind(name: str, kind: str | None) -> None:
    assert photo_kind(Path(name)) == kind


def test_extension_sets_are_disjoint_and_complete() -> None:
    assert not IMAGE_EXTENSIONS & RAW_EXTENSIONS
    assert not (IMAGE_EXTENSIONS | RAW_EXTENSIONS) & SIDECAR_EXTENSIONS
    assert {photo_kind(f"x{ext}") for ext in RAW_EXTENSIONS} == {"raw"}
    assert {photo_kind(f"x{ext.upper()}") for ext in IMAGE_EXTENSIONS} == {"jpeg", "png", "tiff"}
    assert len(RAW_EXTENSIONS) == 42 and {".kdc", ".dng", ".x3f", ".gpr"} <= RAW_EXTENSIONS
    assert {".xmp", ".aae", ".thm", ".json"} <= SIDECAR_EXTENSIONS


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("IMG_1.HEIC", "HEIC is not supported; export the photos as JPEG"),
        ("IMG_1.heif", "HEIC is not supported; export the photos as JPEG"),
        ("walk.MP4", "pass the video on its own (nerfpipe run VIDEO)"),
        ("walk.mov", "a video among photos"),
        ("clip.avi", "a video among photos"),
        ("anim.gif", "convert it to PNG"),
        ("scan.bmp", "convert it to PNG"),
        ("web.webp", "convert it to PNG"),
        ("layers.psd", "move it out of the photo folder"),
    ],
)
def test_unsupported_advice(name: str, expected: str) -> None:
    assert expected in unsupported_advice(Path(name))


def test_unsupported_or_missing_files_raise(tmp_path: Path) -> None:
    heic = write(tmp_path, "IMG_0001.HEIC", b"\x00\x00\x00\x18ftypheic")
    assert_bad_photo(heic, "is not a supported photo format", "export the photos as JPEG")
    assert_bad_photo(tmp_path / "missing.jpg", "cannot be read")


# --- orientation -------------------------------------------------------------------------------------------

# apply_orientation on [[1, 2, 3], [4, 5, 6]], worked out by hand from the EXIF 2.3 table.
HAND_ORIENTED = {
    1: [[1, 2, 3], [4, 5, 6]],
    2: [[3, 2, 1], [6, 5, 4]],  # mirror left-right
    3: [[6, 5, 4], [3, 2, 1]],  # rotate 180
    4: [[4, 5, 6], [1, 2, 3]],  # mirror top-bottom
    5: [[1, 4], [2, 5], [3, 6]],  # transpose
    6: [[4, 1], [5, 2], [6, 3]],  # rotate 90 clockwise
    7: [[6, 3], [5, 2], [4, 1]],  # transverse
    8: [[3, 6], [2, 5], [1, 4]],  # rotate 90 counter-clockwise
}


@pytest.mark.parametrize("orientation", range(1, 9))
def test_apply_orientation_by_hand(orientation: int) -> None:
    stored = np.array([[1, 2, 3], [4, 5, 6]])
    upright = apply_orientation(stored, orientation)
    np.testing.assert_array_equal(upright, HAND_ORIENTED[orientation])
    assert upright.flags.c_contiguous
    # Channels ride along unchanged.
    with_channels = apply_orientation(np.stack([stored, -stored], axis=2), orientation)
    np.testing.assert_array_equal(with_channels[:, :, 1], -np.array(HAND_ORIENTED[orientation]))


@pytest.mark.parametrize("orientation", [0, 9, -1])
def test_apply_orientation_rejects_invalid_values(orientation: int) -> None:
    with pytest.raises(ValueError):
        apply_orientation(np.zeros((2, 3)), orientation)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_jpeg_orientation_matches_opencv(tmp_path: Path, orientation: int) -> None:
    data = photos.jpeg(corner_image()[:, :, ::-1], photos.orientation(orientation), quality=100)
    photo = read_photo(write(tmp_path, "oriented.jpg", data))

    # OpenCV applies EXIF orientation itself for IMREAD_COLOR: an independent implementation.
    reference = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
    expected_shape = (48, 32, 3) if orientation >= 5 else (32, 48, 3)
    assert photo.pixels.shape == reference.shape == expected_shape
    np.testing.assert_array_equal(photo.pixels, reference)
    assert photo.exif.orientation == orientation
    assert photo.source_size == (expected_shape[1], expected_shape[0])
    assert (photo.bit_depth, photo.has_alpha, photo.is_raw, photo.linear) == (8, False, False, False)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_png_and_tiff_orientation_is_applied_once(tmp_path: Path, orientation: int) -> None:
    stored_rgb = corner_image()[:, :, ::-1].copy()
    expected = apply_orientation(stored_rgb, orientation)

    png = photos.png(stored_rgb, photos.orientation(orientation))
    np.testing.assert_array_equal(read_photo(write(tmp_path, "o.png", png)).pixels, expected)

    # OpenCV's TIFF decoder orients by itself even with IMREAD_UNCHANGED; read_photo must not do it twice.
    tiff = photos.tiff(stored_rgb, photos.orientation(orientation))
    np.testing.assert_array_equal(read_photo(write(tmp_path, "o.tif", tiff)).pixels, expected)
    reference = cv2.imdecode(np.frombuffer(tiff, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
    np.testing.assert_array_equal(reference, expected)


# --- integrity ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["empty.jpg", "empty.png", "empty.tif", "empty.dng", "empty.cr3"])
def test_empty_files(tmp_path: Path, name: str) -> None:
    assert_bad_photo(write(tmp_path, name, b""), "is empty (0 bytes)", "copy it again")


def jpeg_scan_starts(data: bytes) -> list[int]:
    """Positions of the start-of-scan markers of an OpenCV JPEG (no EXIF, so no false hits in APP data)."""
    return [index for index in range(len(data) - 1) if data[index : index + 2] == b"\xff\xda"]


def test_truncated_jpegs(tmp_path: Path) -> None:
    data = cv2.imencode(".jpg", noisy_image(), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    read_photo(write(tmp_path, "whole.jpg", data))
    (scan_start,) = jpeg_scan_starts(data)
    cuts = {
        "in the header": 20,
        "right after the scan header": scan_start + 14,
        "in the entropy data": (scan_start + len(data)) // 2,
        "before the EOI": len(data) - 2,
        "inside the EOI": len(data) - 1,
    }
    for where, cut in cuts.items():
        path = write(tmp_path, f"cut {where}.jpg", data[:cut])
        assert_bad_photo(path, "is truncated (JPEG ends before its end-of-image marker)")


def test_truncated_progressive_jpeg(tmp_path: Path) -> None:
    data = photos.jpeg(noisy_image(), quality=90, progressive=True)
    photo = read_photo(write(tmp_path, "progressive.jpg", data))
    assert photo.pixels.shape == (96, 128, 3)
    scans = jpeg_scan_starts(data)
    assert len(scans) > 2
    # Cut between scans: every segment up to there is whole, only the later scans and the EOI are missing.
    for index, scan in enumerate(scans[1:], start=1):
        assert_bad_photo(write(tmp_path, f"progressive cut {index}.jpg", data[:scan]), "is truncated")


def test_exif_thumbnail_eoi_does_not_hide_truncation(tmp_path: Path) -> None:
    # A whole JPEG inside the EXIF (here as a maker note, as cameras store previews), end-of-image and all.
    thumbnail = photos.jpeg(noisy_image(16, 24, seed=1), quality=80)
    data = photos.jpeg(noisy_image(), photos.exif({0x010F: "Canon"}, {0x927C: thumbnail}), quality=95)
    assert data.index(thumbnail) < data.index(b"\xff\xda")
    assert read_photo(write(tmp_path, "with thumbnail.jpg", data)).exif.make == "Canon"

    cut = data[: len(data) * 3 // 4]
    # A naive "does it contain FFD9" check is fooled by the thumbnail's own end-of-image marker.
    assert b"\xff\xd9" in cut
    assert_bad_photo(write(tmp_path, "thumbnail cut.jpg", cut), "is truncated")


def test_truncated_pngs(tmp_path: Path) -> None:
    data = png_bytes(noisy_image())
    read_photo(write(tmp_path, "whole.png", data))
    idat = data.index(b"IDAT") - 4
    for where, cut in {"in IDAT": idat + 100, "before IEND": len(data) - 12, "in IEND": len(data) - 3}.items():
        assert_bad_photo(write(tmp_path, f"cut {where}.png", data[:cut]), "is truncated", "PNG")


def test_truncated_tiffs(tmp_path: Path) -> None:
    # OpenCV writes the strips first and the directory last: a cut removes the directory.
    data = cv2.imencode(".tiff", noisy_image())[1].tobytes()
    read_photo(write(tmp_path, "whole.tif", data))
    for fraction in (0.5, 0.9):
        cut = data[: int(len(data) * fraction)]
        assert_bad_photo(write(tmp_path, f"cut {fraction}.tif", cut), "is truncated")
    assert_bad_photo(write(tmp_path, "cut last byte.tif", data[:-1]), "is truncated")

    # Directory first, strip after (as in DNG): the directory survives, the strip runs past the end.
    directory_first = photos.tiff(noisy_image())
    assert struct.unpack_from("<I", directory_first, 4)[0] == 8  # Pillow writes the directory first
    read_photo(write(tmp_path, "directory first.tif", directory_first))
    cut = directory_first[: len(directory_first) - 100]
    assert_bad_photo(write(tmp_path, "strip cut.tif", cut), "is truncated (image data runs to byte")


@pytest.mark.parametrize(
    ("name", "container"), [("noise.jpg", "JPEG"), ("noise.png", "PNG"), ("noise.tif", "TIFF")]
)
def test_random_bytes_are_not_a_valid_file(tmp_path: Path, name: str, container: str) -> None:
    data = np.random.default_rng(3).integers(0, 256, 5000, dtype=np.uint8).tobytes()
    assert_bad_photo(write(tmp_path, name, data), f"is not a valid {container} file")


def test_random_bytes_as_raw_are_refused_by_libraw(tmp_path: Path) -> None:
    data = b"\x00\x00\x00\x18ftypcrx " + np.random.default_rng(4).integers(0, 256, 5000, dtype=np.uint8).tobytes()
    path = write(tmp_path, "IMG_0001.CR3", data)
    # Not TIFF-based, so the integrity check leaves it to LibRaw, whose refusal becomes a BadPhotoError.
    check_integrity(path, data, "raw")
    assert_bad_photo(path, "cannot be decoded by LibRaw", "convert it to DNG")


def test_jpeg_structure_that_libjpeg_cannot_decode(tmp_path: Path) -> None:
    data = bytearray(cv2.imencode(".jpg", noisy_image())[1].tobytes())
    # Turn baseline SOF0 into SOF5 (differential, hierarchical), which libjpeg does not implement.
    sof = data.index(b"\xff\xc0")
    data[sof + 1] = 0xC5
    assert_bad_photo(write(tmp_path, "hierarchical.jpg", bytes(data)), "cannot be decoded", "not really a JPEG")


def test_container_is_taken_from_magic_bytes(tmp_path: Path) -> None:
    image = corner_image()
    # A PNG saved as .jpg (and a JPEG saved as .png) is what it is, not what its name says.
    png_as_jpg = read_photo(write(tmp_path, "actually png.jpg", png_bytes(image)))
    np.testing.assert_array_equal(png_as_jpg.pixels, image[:, :, ::-1])
    jpeg = photos.jpeg(image)
    jpeg_as_png = read_photo(write(tmp_path, "actually jpeg.png", jpeg))
    np.testing.assert_array_equal(jpeg_as_png.pixels, cv2.imdecode(np.frombuffer(jpeg, np.uint8), 1)[:, :, ::-1])
    # ... and a cut PNG named .jpg is reported as the truncated PNG it is.
    assert_bad_photo(write(tmp_path, "cut png.jpg", png_bytes(image)[:-20]), "PNG", "is truncated")


def test_check_integrity_rejects_an_unknown_kind(tmp_path: Path) -> None:
    with pytest.raises(ValueError):
        check_integrity(tmp_path / "x.gif", b"GIF89a", "gif")


@settings(max_examples=150, deadline=None)
@given(
    head=st.sampled_from([b"\xff\xd8\xff", b"\x89PNG\r\n\x1a\n", b"II*\x00", b"MM\x00*"]),
    rest=st.binary(max_size=300),
    kind=st.sampled_from(["jpeg", "png", "tiff", "raw"]),
)
def test_integrity_check_only_ever_raises_bad_photo(head: bytes, rest: bytes, kind: str) -> None:
    try:
        check_integrity(Path("fuzz.bin"), head + rest, kind)
    except BadPhotoError as err:
        assert "fuzz.bin" in str(err)


# --- pixel formats -----------------------------------------------------------------------------------------


def test_sixteen_bit_png_keeps_its_values(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    bgr16 = rng.integers(0, 65536, (20, 30, 3), dtype=np.uint16)
    photo = read_photo(write(tmp_path, "deep.png", png_bytes(bgr16)))
    assert (photo.pixels.dtype, photo.bit_depth) == (np.uint16, 16)
    np.testing.assert_array_equal(photo.pixels, bgr16[:, :, ::-1])

    gray16 = rng.integers(0, 65536, (20, 30), dtype=np.uint16)
    gray = read_photo(write(tmp_path, "deep gray.png", png_bytes(gray16)))
    assert gray.pixels.shape == (20, 30, 3) and gray.bit_depth == 16
    for channel in range(3):
        np.testing.assert_array_equal(gray.pixels[:, :, channel], gray16)


def test_float_tiff_becomes_clipped_uint16(tmp_path: Path) -> None:
    values = np.array([[-0.5, 0.0, 0.25], [0.5, 1.0, 1.5]], np.float32)
    bgr = np.stack([values, values * 0.5, np.full_like(values, np.nan)], axis=2)
    photo = read_photo(write(tmp_path, "hdr.tif", cv2.imencode(".tiff", bgr)[1].tobytes()))
    assert (photo.pixels.dtype, photo.bit_depth) == (np.uint16, 16)
    # Red is OpenCV's channel 2 (NaN -> 0); blue is channel 0, clipped to [0, 1] and scaled by 65535.
    np.testing.assert_array_equal(photo.pixels[:, :, 0], 0)
    np.testing.assert_array_equal(photo.pixels[:, :, 2], [[0, 0, 16384], [32768, 65535, 65535]])
    np.testing.assert_array_equal(photo.pixels[:, :, 1], [[0, 0, 8192], [16384, 32768, 49151]])


def test_grayscale_jpeg_gives_three_equal_channels(tmp_path: Path) -> None:
    gray = noisy_image()[:, :, 0]
    data = cv2.imencode(".jpg", gray)[1].tobytes()
    photo = read_photo(write(tmp_path, "gray.jpg", data))
    assert photo.pixels.shape == (96, 128, 3) and photo.bit_depth == 8
    reference = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    for channel in range(3):
        np.testing.assert_array_equal(photo.pixels[:, :, channel], reference)


def test_alpha_is_kept(tmp_path: Path) -> None:
    rng = np.random.default_rng(6)
    bgra = rng.integers(0, 256, (12, 10, 4), dtype=np.uint8)
    photo = read_photo(write(tmp_path, "cutout.png", png_bytes(bgra)))
    assert photo.has_alpha and photo.pixels.shape == (12, 10, 4)
    np.testing.assert_array_equal(photo.pixels, bgra[:, :, [2, 1, 0, 3]])

    # Even a fully opaque alpha channel is kept.
    opaque = bgra.copy()
    opaque[:, :, 3] = 255
    assert read_photo(write(tmp_path, "opaque.png", png_bytes(opaque))).has_alpha

    gray_alpha = rng.integers(0, 256, (5, 7, 2), dtype=np.uint8)
    photo = read_photo(write(tmp_path, "gray alpha.png", photos.png(gray_alpha)))
    assert photo.has_alpha and photo.pixels.shape == (5, 7, 4)
    np.testing.assert_array_equal(photo.pixels[:, :, 0], gray_alpha[:, :, 0])
    np.testing.assert_array_equal(photo.pixels[:, :, 2], gray_alpha[:, :, 0])
    np.testing.assert_array_equal(photo.pixels[:, :, 3], gray_alpha[:, :, 1])


# --- paths and side effects --------------------------------------------------------------------------------


def test_paths_with_spaces_and_non_ascii(tmp_path: Path, raw_samples: Path) -> None:
    image = corner_image()
    photo = read_photo(write(tmp_path / "my photos", "tëmple 01.png", png_bytes(image)))
    np.testing.assert_array_equal(photo.pixels, image[:, :, ::-1])
    jpeg = read_photo(write(tmp_path / "照片 dir", "東京 2.JPG", cv2.imencode(".jpg", image)[1].tobytes()))
    assert jpeg.pixels.shape == (32, 48, 3)
    raw = write(tmp_path / "my photos", "pröbe raw é.KDC", (raw_samples / "kodak_dc50.kdc").read_bytes())
    assert read_photo(raw).pixels.shape == (512, 768, 3)


def test_input_files_are_not_modified(tmp_path: Path, raw_samples: Path) -> None:
    jpeg = write(tmp_path, "keep.jpg", photos.jpeg(corner_image(), photos.orientation(6)))
    tiff = write(tmp_path, "keep.tif", photos.tiff(corner_image(), photos.orientation(3)))
    raw = write(tmp_path, "keep.kdc", (raw_samples / "kodak_dc50.kdc").read_bytes())
    for path in (jpeg, tiff, raw):
        # Read-only too: reading must not need write access.
        os.utime(path, ns=(1_600_000_000_000_000_000, 1_600_000_000_000_000_000))
        path.chmod(0o444)
        before = (path.read_bytes(), path.stat().st_mtime_ns)
        read_photo(path)
        assert (path.read_bytes(), path.stat().st_mtime_ns) == before


def test_module_import_does_not_load_rawpy() -> None:
    code = "import sys, nerfpipe.imaging; assert 'rawpy' not in sys.modules, 'rawpy imported eagerly'"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr


# --- camera RAW --------------------------------------------------------------------------------------------


def test_raw_options_are_validated() -> None:
    with pytest.raises(ValueError, match="highlight_mode"):
        RawOptions(highlight_mode="recover")
    with pytest.raises(ValueError, match="white_balance"):
        RawOptions(white_balance="tungsten")


@pytest.fixture(scope="module")
def dng_developed(raw_samples: Path) -> tuple[DecodedPhoto, DecodedPhoto]:
    """blackmagic.dng developed once with gamma and once linear (about 1.5 s together)."""
    path = raw_samples / "blackmagic.dng"
    return read_photo(path), read_photo(path, RawOptions(linear=True))


def test_dng_decodes(dng_developed: tuple[DecodedPhoto, DecodedPhoto]) -> None:
    gamma, linear = dng_developed
    for photo in (gamma, linear):
        # LibRaw outputs the whole 4128 x 2176 sensor area; it does not apply the DNG DefaultCrop
        # (origin 16, 8; size 4096 x 2160, the camera's 4K DCI frame).
        assert photo.pixels.shape == (2176, 4128, 3)
        assert photo.pixels.dtype == np.uint16
        assert (photo.bit_depth, photo.is_raw, photo.has_alpha) == (16, True, False)
        assert photo.source_size == (4128, 2176)
        assert photo.exif.model == "Blackmagic Pocket Cinema Camera 4K"
        # Observed with LibRaw 0.22.2: both reach 65535 (clipped highlights) and go down to 0.
        assert photo.pixels.max() == 65535
        assert photo.pixels.min() == 0
        assert photo.pixels.std() > 2000
    assert (gamma.linear, linear.linear) == (False, True)
    # Observed means: 28277 with gamma 2.222 + auto-brightening, 8338 linear. Linear is far darker.
    assert linear.pixels.mean() < 0.5 * gamma.pixels.mean()
    assert 20000 < gamma.pixels.mean() < 36000
    assert 5000 < linear.pixels.mean() < 12000


def test_truncated_dng(tmp_path: Path, raw_samples: Path) -> None:
    data = (raw_samples / "blackmagic.dng").read_bytes()
    # The IFD is at the start, the four compressed tiles after it; 60% keeps the IFD and cuts the tiles.
    cut = write(tmp_path, "frame cut.dng", data[: len(data) * 6 // 10])
    assert_bad_photo(cut, "is truncated (image data runs to byte 3359558 but the file has 2015769 bytes)")


def test_kdc_decodes_with_every_highlight_mode(raw_samples: Path) -> None:
    path = raw_samples / "kodak_dc50.kdc"
    means = {}
    for mode in ("clip", "ignore", "blend", "reconstruct"):
        photo = read_photo(path, RawOptions(highlight_mode=mode))
        # LibRaw decodes the DC50 at 768 x 512 (the KDC's TIFF SubIFD says 756 x 504 for the same data).
        assert photo.pixels.shape == (512, 768, 3) and photo.pixels.dtype == np.uint16
        assert photo.pixels.max() == 65535 and photo.pixels.std() > 2000
        means[mode] = photo.pixels.mean()
    # The option reaches LibRaw: observed means 38644 (clip, blend) and 23873 (ignore, reconstruct),
    # the latter lower because unclipped highlights make auto-brightening scale the image down.
    assert means["ignore"] < 0.8 * means["clip"]


def test_kdc_white_balance_and_linear(raw_samples: Path) -> None:
    path = raw_samples / "kodak_dc50.kdc"
    camera = read_photo(path).pixels.astype(np.float64)
    auto = read_photo(path, RawOptions(white_balance="auto")).pixels.astype(np.float64)
    # Gray-world auto white balance pulls the channel means together (observed 41018/38982/35932 as shot,
    # 40802/40693/39909 auto).
    camera_spread = np.ptp(camera.reshape(-1, 3).mean(axis=0))
    auto_spread = np.ptp(auto.reshape(-1, 3).mean(axis=0))
    assert auto_spread < 0.5 * camera_spread
    linear = read_photo(path, RawOptions(linear=True))
    assert linear.linear and linear.pixels.mean() < 0.5 * camera.mean()  # observed 10940 vs 38644


def test_tiff_raw_exif_is_recorded(raw_samples: Path) -> None:
    photo = read_photo(raw_samples / "kodak_dc50.kdc")
    assert photo.exif.make == "Eastman Kodak Company"
    assert photo.exif.exposure_time_s == pytest.approx(0.00435)


# -- sizes from the header, before decoding ----------------------------------------------------------


def test_read_header_gives_the_stored_size_without_decoding(tmp_path: Path) -> None:
    temple = read_header(TEMPLE_PNG)
    assert temple == PhotoHeader(640, 480, 3, 1)
    assert read_header(TEMPLE_PNG.read_bytes()) == temple
    cv2.imwrite(str(tmp_path / "grey16.png"), np.zeros((30, 50), np.uint16))
    cv2.imwrite(str(tmp_path / "rgba.tif"), np.zeros((7, 9, 4), np.uint8))
    cv2.imwrite(str(tmp_path / "photo.jpg"), np.zeros((120, 160, 3), np.uint8))
    assert read_header(tmp_path / "grey16.png") == PhotoHeader(50, 30, 1, 2)
    assert read_header(tmp_path / "rgba.tif") == PhotoHeader(9, 7, 4, 1)
    assert read_header(tmp_path / "photo.jpg").pixels == 160 * 120
    (tmp_path / "junk.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(10))
    assert read_header(tmp_path / "junk.png") is None  # the decoder says what is wrong with it


def test_size_limits_refuse_before_decoding(tmp_path: Path) -> None:
    with pytest.raises(PhotoSizeError, match="is only 640x480 pixels") as small:
        read_photo(TEMPLE_PNG, limits=SizeLimits(min_side=481))
    assert small.value.too == "small" and small.value.size == (640, 480)
    with pytest.raises(PhotoSizeError, match=r"is 640x480 pixels \(0 megapixels\)") as large:
        read_photo(TEMPLE_PNG, limits=SizeLimits(max_pixels=640 * 480 - 1))
    assert large.value.too == "large"
    assert read_photo(TEMPLE_PNG, limits=SizeLimits(min_side=480, max_pixels=640 * 480)).source_size == (640, 480)


def test_png_data_too_short_for_its_header_is_refused_and_the_densest_real_png_is_not(tmp_path: Path) -> None:
    black = np.zeros((3000, 4000, 3), np.uint8)  # compresses as far as deflate goes: ~1030 to 1
    ok, data = cv2.imencode(".png", black, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    (tmp_path / "black.png").write_bytes(data.tobytes())
    assert read_photo(tmp_path / "black.png").source_size == (4000, 3000)
    (tmp_path / "short.png").write_bytes(_png_without_idat(data.tobytes()))
    with pytest.raises(BadPhotoError, match="its 0 bytes of image data cannot hold the 4000x3000 image"):
        read_photo(tmp_path / "short.png")


def _png_without_idat(data: bytes) -> bytes:
    """``data``'s chunks with its IDAT chunks left out (each chunk: length, type, body, CRC)."""
    out, position = bytearray(data[:8]), 8
    while position < len(data):
        (length,) = struct.unpack_from(">I", data, position)
        if data[position + 4:position + 8] != b"IDAT":
            out += data[position:position + 12 + length]
        position += 12 + length
    return bytes(out)
