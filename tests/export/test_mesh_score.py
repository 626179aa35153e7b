"""A textured mesh scored against held-out photos: the cube baked from its photos scores high against views
of it no photo was taken from, with its colours' ratio near 1; against photos twice as bright as the truth,
the ratio is a half and the PSNR falls; the photos of the selection are spread along the capture."""

from __future__ import annotations

import numpy as np
import pytest

from nerfpipe.export.mesh_score import HeldoutView, psnr, score_views
from nerfpipe.export.texture import Photo, bake, spread
from tests.export.test_texture import K, around, cube, truth


@pytest.fixture(scope="module")
def baked():
    photos = [Photo(truth(c2w)[0], K, c2w) for c2w in around(8, 1.5) + around(8, -1.5, 0.3)]
    return bake(cube(), photos, faces=2000, size=256)


def test_psnr_by_hand() -> None:
    a = np.zeros((2, 2, 3))
    assert psnr(a, a + 0.1) == pytest.approx(20.0)  # MSE 0.01
    assert psnr(a, a) == pytest.approx(100.0)  # identical: capped


def test_the_baked_cube_scores_high_on_new_views_and_its_colours_match(baked) -> None:
    views = [HeldoutView(truth(c2w)[0] / 255.0, K, c2w, field_psnr=30.0) for c2w in around(3, 0.5, 0.7)]
    scores = score_views(baked, views)
    assert scores["views"] == 3 and scores["field_psnr"] == 30.0
    assert scores["covered_psnr"] > 25.0 and scores["mesh_psnr"] > 25.0
    covered = float(np.mean([truth(v.c2w)[1].mean() for v in views]))
    assert scores["coverage"] == pytest.approx(covered, abs=0.02)  # the share of pixels the cube covers
    assert scores["colour_ratio"] == pytest.approx([1.0, 1.0, 1.0], abs=0.05)


def test_photos_brighter_than_the_texture_show_in_the_ratio(baked) -> None:
    views = [HeldoutView(np.clip(truth(c2w)[0] / 255.0 * 2.0, 0, 1), K, c2w, 30.0) for c2w in around(2, 0.0, 0.2)]
    dark = score_views(baked, views)
    bright = [HeldoutView(truth(c2w)[0] / 255.0, K, c2w, 30.0) for c2w in around(2, 0.0, 0.2)]
    assert dark["covered_psnr"] < score_views(baked, bright)["covered_psnr"] - 5.0
    # a doubled photo (clipped at 1) is up to twice the texture's colour: the ratio falls well below 1
    assert 0.45 < float(np.mean(dark["colour_ratio"])) < 0.8 and max(dark["colour_ratio"]) < 0.9
    assert score_views(baked, []) is None


def test_spread_takes_photos_evenly_along_the_capture() -> None:
    names = [f"{i:02d}.png" for i in range(10)]
    assert spread(names, 4) == ["00.png", "03.png", "06.png", "09.png"]
    assert spread(names, 0) == names and spread(names, 20) == names
