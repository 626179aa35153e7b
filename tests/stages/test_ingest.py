"""The ingest stage on real photos: sizes, resampling, alpha, bit depth, RAW, and what images.json says."""

from __future__ import annotations

import json
import shutil
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
import pytest

from nerfpipe import Pipeline
from nerfpipe.pipeline import InputError
from nerfpipe.pipeline.hashing import sha256_file
from nerfpipe.poses.layout import discover_photos
from nerfpipe.stages import IngestStage
from nerfpipe.stages.ingest import target_size, to_bit_depth
from tests.helpers import TEMPLE, shared
from tests.imaging import photos


def ingest(folder: Path, tmp_path: Path, **overrides) -> tuple[Path, dict]:
    outcome = Pipeline([IngestStage()], folder, tmp_path / "run", overrides={"ingest": overrides}).run()[0]
    return outcome.path, json.loads((outcome.path / "images.json").read_text())


def read_png(path: Path) -> np.ndarray:
    return cv2.imdecode(np.fromfile(path, np.uint8), cv2.IMREAD_UNCHANGED)


def test_target_size_fits_the_longest_side_and_never_upscales():
    assert target_size(640, 480, 1600) == (640, 480)
    assert target_size(640, 480, 320) == (320, 240)
    assert target_size(480, 640, 320) == (240, 320)
    assert target_size(4128, 2176, 1000) == (1000, 527)  # 2176 * 1000/4128 = 527.1
    assert target_size(5000, 3, 100) == (100, 1)  # never 0 pixels
    assert target_size(640, 480, 0) == (640, 480)


def test_bit_depth_conversion_round_trips():
    values = np.arange(256, dtype=np.uint8)
    wide = to_bit_depth(values, 16)
    assert wide.dtype == np.uint16 and wide[255] == 65535 and wide[1] == 257
    assert np.array_equal(to_bit_depth(wide, 8), values)
    assert to_bit_depth(np.array([32895, 32896], np.uint16), 8).tolist() == [128, 128]  # 32896/257 = 128.0


def test_discover_ignores_sidecars_and_falls_back_to_images_subfolder(tmp_path):
    assert [p.name for p in discover_photos(TEMPLE)] == [f"templeSR{i:04d}.png" for i in range(1, 17)]
    cup = shared("llff_cup_kwrous")  # poses_bounds.npy at the top, photos in images/
    photos = discover_photos(cup)
    assert len(photos) == 77 and all(p.parent.name == "images" for p in photos)
    with pytest.raises(InputError, match="no photos found among its 2 files"):
        discover_photos(_only_text(tmp_path))


def _only_text(tmp_path: Path) -> Path:
    folder = tmp_path / "text"
    folder.mkdir()
    (folder / "a.txt").write_text("x")
    (folder / "b.md").write_text("y")
    return folder


def test_temple_images_json_and_pixels(tmp_path):
    out, meta = ingest(TEMPLE, tmp_path)
    assert len(meta["images"]) == 16 and meta["skipped"] == []
    first = meta["images"][0]
    assert first["name"] == "templeSR0001.png" and first["source"] == "templeSR0001.png"
    assert (first["width"], first["height"], first["scale"]) == (640, 480, 1.0)
    assert first["bit_depth"] == 8 and not first["has_alpha"] and not first["raw"]
    assert first["source_sha256"] == sha256_file(TEMPLE / "templeSR0001.png")
    assert first["focal_prior"] is None  # Middlebury PNGs carry no EXIF
    # no resize: the pixels are the source's, exactly
    source = cv2.imread(str(TEMPLE / "templeSR0001.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(read_png(out / "images" / "templeSR0001.png"), source)


def test_downscaling_uses_area_resampling(tmp_path):
    out, meta = ingest(TEMPLE, tmp_path, max_size=320)
    assert {(i["width"], i["height"]) for i in meta["images"]} == {(320, 240)}
    assert meta["images"][0]["scale"] == 0.5
    source = cv2.imread(str(TEMPLE / "templeSR0005.png"), cv2.IMREAD_UNCHANGED)
    expected = cv2.resize(source, (320, 240), interpolation=cv2.INTER_AREA)
    assert np.array_equal(read_png(out / "images" / "templeSR0005.png"), expected)
    # area resampling of an exact 2x reduction is the 2x2 block mean
    block = source[:2, :2].reshape(-1, 3).astype(float).mean(0)
    assert np.allclose(read_png(out / "images" / "templeSR0005.png")[0, 0], block, atol=0.5)


def test_alpha_is_kept_as_channel_or_mask(tmp_path):
    folder = tmp_path / "lego"
    folder.mkdir()
    for i in range(3):
        shutil.copy(shared("nerf_synthetic_lego_400", "train", f"r_{i}.png"), folder)
    source = cv2.imread(str(folder / "r_0.png"), cv2.IMREAD_UNCHANGED)
    assert source.shape == (400, 400, 4)

    out, meta = ingest(folder, tmp_path / "a")
    assert all(i["has_alpha"] and i["mask"] is None for i in meta["images"])
    assert np.array_equal(read_png(out / "images" / "r_0.png"), source)

    out, meta = ingest(folder, tmp_path / "b", alpha="mask")
    assert meta["images"][0]["mask"] == "masks/r_0.png"
    assert np.array_equal(read_png(out / "masks" / "r_0.png"), source[..., 3])
    assert np.array_equal(read_png(out / "images" / "r_0.png"), source[..., :3])


def test_sixteen_bit_output_of_an_eight_bit_photo(tmp_path):
    out, meta = ingest(TEMPLE, tmp_path, bit_depth="16", max_size=0)
    image = read_png(out / "images" / "templeSR0002.png")
    source = cv2.imread(str(TEMPLE / "templeSR0002.png"), cv2.IMREAD_UNCHANGED)
    assert image.dtype == np.uint16 and meta["images"][1]["bit_depth"] == 16
    assert np.array_equal(image, source.astype(np.uint16) * 257)


@pytest.fixture(scope="module")
def raw_capture(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("raw")
    for name in ("blackmagic.dng", "kodak_dc50.kdc"):
        shutil.copy(shared("raw_samples", name), folder)
    return folder


def test_raw_files_become_16_bit_pngs(raw_capture, tmp_path):
    out, meta = ingest(raw_capture, tmp_path, max_size=1032)
    by_source = {i["source"]: i for i in meta["images"]}
    dng, kdc = by_source["blackmagic.dng"], by_source["kodak_dc50.kdc"]
    assert dng["raw"] and kdc["raw"] and dng["format"] == kdc["format"] == "raw"
    assert dng["bit_depth"] == kdc["bit_depth"] == 16 and not dng["linear"]
    # the DNG is 4128x2176; ingest fits its long side into 1032 px: 1032 x 544
    assert (dng["width"], dng["height"]) == (1032, 544)
    image = read_png(out / "images" / "blackmagic.png")
    assert image.dtype == np.uint16 and image.shape == (544, 1032, 3)
    assert image.max() > 20000 and image.min() < 5000 and len(np.unique(image)) > 5000
    small = read_png(out / "images" / "kodak_dc50.png")
    assert small.dtype == np.uint16 and small.shape[2] == 3


def test_linear_raw_output_is_darker_than_gamma_encoded(raw_capture, tmp_path):
    folder = tmp_path / "one"
    folder.mkdir()
    shutil.copy(raw_capture / "kodak_dc50.kdc", folder)
    out_gamma, _ = ingest(folder, tmp_path / "g")
    out_linear, meta = ingest(folder, tmp_path / "l", raw_linear=True)
    assert meta["images"][0]["linear"]
    gamma = read_png(out_gamma / "images" / "kodak_dc50.png").astype(float)
    linear = read_png(out_linear / "images" / "kodak_dc50.png").astype(float)
    assert linear.mean() < 0.8 * gamma.mean()


def test_exif_orientation_is_applied_and_the_focal_prior_follows_the_output_size(tmp_path):
    # an asymmetric 60x40 landscape picture; orientation 6 means "rotate 90 clockwise to view upright"
    stored = np.zeros((40, 60, 3), np.uint8)
    stored[:10, :10] = (0, 0, 255)  # red (BGR) top-left as stored
    stored[-10:, -10:] = (255, 0, 0)  # blue bottom-right
    exif = photos.exif({0x010F: "Acme", 0x0110: "Cam 1", 0x0112: 6}, {0xA405: 28, 0x829A: Fraction(1, 250)})
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "rotated.jpg").write_bytes(photos.jpeg(stored[:, :, ::-1], exif, quality=100))

    out, meta = ingest(folder, tmp_path, max_size=30)
    record = meta["images"][0]
    assert (record["source_width"], record["source_height"]) == (40, 60)  # upright is portrait
    assert (record["width"], record["height"]) == (20, 30)
    assert record["exif"]["orientation"] == 6 and record["exif"]["make"] == "Acme"
    assert record["exif"]["model"] == "Cam 1" and record["exif"]["exposure_time_s"] == pytest.approx(1 / 250)
    # COLMAP's rule: focal_px = f35 / 35 * longest side = 28 / 35 * 30 = 24 px at the output size
    assert record["focal_prior"] == {"focal_px": pytest.approx(24.0), "source": "exif_35mm"}

    upright = read_png(out / "images" / "rotated.png")
    expected = cv2.resize(
        cv2.imdecode(np.fromfile(folder / "rotated.jpg", np.uint8), cv2.IMREAD_COLOR), (20, 30),
        interpolation=cv2.INTER_AREA,
    )  # OpenCV's IMREAD_COLOR applies EXIF orientation itself: an independent reference
    assert np.array_equal(upright, expected)
    # rotated 90 clockwise, the stored top-left red corner is now top-right
    assert upright[0, -1, 2] > 200 and upright[0, -1, 0] < 50
