"""Held-out evaluation: PSNR and SSIM per view and averaged, the eval images, progress, no views."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from nerfpipe.imaging.png import read_png, srgb_encode, write_png
from nerfpipe.nerf.train import evaluation
from nerfpipe.nerf.train.evaluation import evaluate, evaluation_scale, protocol
from tests.nerf.scenes import loader_of


class HalfBright:
    """A stand-in model: renders every view as 0.5 everywhere."""

    def __init__(self, photometric: str = "srgb") -> None:
        self.info = {"photometric": photometric}
        self.appearance = None  # learned no per-image exposure
        self.calls = []

    def render_image(self, intrinsics, c2w, width, height, near, far, chunk):
        self.calls.append((intrinsics, width, height, near, far, chunk))
        return {"rgb": torch.full((height, width, 3), 0.5)}


def test_evaluate_scores_each_view_writes_its_images_and_reports_progress(image_folders, tmp_path) -> None:
    loader = loader_of(image_folders)
    frames = loader.world.frames[1:]  # grey at 128/255, then white
    model, advanced = HalfBright(), []
    result = evaluate(model, loader, frames, tmp_path / "eval", 64, lambda n=1, info=None: advanced.append((n, info)))
    grey_psnr = -10 * math.log10((128 / 255 - 0.5) ** 2)
    white_psnr = -10 * math.log10(0.25)  # 6.02 dB
    assert [v["name"] for v in result["views"]] == ["grey.png", "b.png"]
    assert [v["psnr"] for v in result["views"]] == pytest.approx([grey_psnr, white_psnr], abs=1e-3)
    assert result["psnr"] == pytest.approx((grey_psnr + white_psnr) / 2, abs=1e-3)
    assert 0 < result["ssim"] <= 1 and result["seconds"] >= 0
    assert [c[1:] for c in model.calls] == [(12, 8, 2.0, 6.0, 64), (12, 8, 3.0, 7.0, 64)]  # each view's size and near/far
    assert advanced == [(1, f"grey.png: {result['views'][0]['psnr']:.2f} dB"), (1, f"b.png: {white_psnr:.2f} dB")]
    assert sorted(p.name for p in (tmp_path / "eval").iterdir()) == ["b.gt.png", "b.render.png", "grey.gt.png",
                                                                      "grey.render.png"]
    assert (read_png(tmp_path / "eval" / "b.render.png") == 128).all()


def test_linear_raw_previews_are_srgb_encoded_and_no_views_give_no_score(image_folders, tmp_path) -> None:
    loader = loader_of(image_folders)
    evaluate(HalfBright("linear_raw"), loader, loader.world.frames[2:], tmp_path, 64)
    expected = np.round(srgb_encode(np.array(0.5)) * 255)
    assert (read_png(tmp_path / "b.render.png") == expected).all()
    assert evaluate(HalfBright(), loader, [], None, 64) == {"psnr": None, "ssim": None, "views": [], "seconds": 0.0,
                                                            "scale": 1.0, "protocol": protocol(loader)}


def test_the_protocol_says_what_renders_are_compared_with(image_folders) -> None:
    assert protocol(loader_of(image_folders)) == (
        "renders composited onto (0.00, 0.00, 1.00) against the photos composited onto it by their alpha")
    # a constant backdrop with its tolerance recorded: the photos masked as in training, and the photos as taken
    assert protocol(loader_of(image_folders, background="color", tolerance=0.1)) == (
        "renders composited onto the backdrop colour (0.00, 0.00, 1.00) against the photos composited onto it by "
        "their backdrop masks, as alpha captures are (psnr_photo: against the photos as taken)")
    # no tolerance (an older scene.json), no masks: the photos as taken
    assert protocol(loader_of(image_folders, background="color")) == "renders against the original photos"
    assert protocol(loader_of(image_folders, background="none")) == "renders against the original photos"


def test_against_a_backdrop_the_masked_photo_is_scored_and_the_photo_as_taken_beside_it(image_folders, tmp_path) -> None:
    # grey.png becomes a blue backdrop around a red block; its corner pixel is 20/255 off blue (within 0.1): the
    # mask makes it pure blue in the target, the photo keeps it
    pixels = np.zeros((8, 12, 3), np.uint8)
    pixels[..., 2] = 255
    pixels[0, 0] = (20, 0, 255)
    pixels[2:6, 3:8] = (255, 0, 0)
    write_png(image_folders["images"] / "grey.png", pixels)
    loader = loader_of(image_folders, background="color", tolerance=0.1)
    result = evaluate(HalfBright(), loader, [loader.world.frames[1]], tmp_path, 64)
    # against the masked photo every channel is 0 or 1, so 0.5 is off by 0.5 everywhere: 6.02 dB
    (view,) = result["views"]
    assert view["psnr"] == pytest.approx(-10 * math.log10(0.25), abs=1e-3)
    # the photo as taken: the corner's red channel is off by 0.5 - 20/255 instead
    mse = (95 * 0.25 + ((0.5 - 20 / 255) ** 2 + 0.25 + 0.25) / 3) / 96
    assert view["psnr_photo"] == pytest.approx(-10 * math.log10(mse), abs=1e-3)
    assert result["psnr_photo"] == view["psnr_photo"] and result["protocol"] == protocol(loader)
    assert read_png(tmp_path / "grey.gt.png")[0, 0].tolist() == [0, 0, 255]  # the target written is the masked one


def test_a_held_out_photos_exposure_is_fitted_on_its_left_half_and_scored_on_its_right() -> None:
    """A render that is the photo at another exposure (over a white stand-in background, which exposure does
    not touch) scores as the photo itself once the left half has fitted its gains; the right half is scored."""
    from nerfpipe.nerf.appearance import apply_gains
    from nerfpipe.nerf.train.evaluation import fit_left_score_right

    rng = np.random.default_rng(0)
    h, w = 24, 32
    light = torch.from_numpy(rng.uniform(0.05, 0.6, size=(h, w, 3)).astype(np.float32))
    acc = torch.from_numpy((rng.uniform(size=(h, w)) > 0.3).astype(np.float32))
    white = torch.ones(3)
    behind = (1 - acc).unsqueeze(-1) * white
    render = light * acc.unsqueeze(-1) + behind  # at the training photos' mean exposure
    photo = apply_gains((light * acc.unsqueeze(-1)).reshape(-1, 3), torch.tensor([1.5, 1.2, 0.8]), False).reshape(h, w, 3) + behind
    exposed, scored = fit_left_score_right(render, acc, white, photo.numpy(), linear=False)
    assert scored == slice(w // 2, None)
    torch.testing.assert_close(exposed, photo, atol=2e-4, rtol=0)


def test_a_smaller_scale_renders_and_scores_smaller_views(image_folders) -> None:
    loader = loader_of(image_folders)
    frames = loader.world.frames[1:]
    model = HalfBright()
    full = evaluate(model, loader, frames, None, 64)
    half = evaluate(model, loader, frames, None, 64, scale=0.5)
    # each view at 6x4 with the intrinsics halved; the uniform images average down to themselves
    assert [v["size"] for v in half["views"]] == [[6, 4], [6, 4]] and half["scale"] == 0.5
    assert [c[0] for c in model.calls[2:]] == [tuple(v / 2 for v in loader.intrinsics(f)) for f in frames]
    assert [c[1:3] for c in model.calls[2:]] == [(6, 4), (6, 4)]
    assert [v["psnr"] for v in half["views"]] == pytest.approx([v["psnr"] for v in full["views"]], abs=1e-3)


def test_the_automatic_scale_is_half_the_photos_side_whatever_the_time(image_folders, monkeypatch) -> None:
    """Every run of a capture is scored at the same size, however slow the machine: auto is half the side, and
    the predicted cost (for the log, and the job's line when it takes longer) follows from it."""
    loader = loader_of(image_folders)
    frames = loader.world.frames[1:]  # two 12x8 views: 192 pixels
    monkeypatch.setattr(evaluation, "seconds_per_ray", lambda *args, **kwargs: 0.01)  # 1.92 s at full size
    assert evaluation_scale("auto", None, loader, frames, 64) == pytest.approx((0.5, 0.48))
    monkeypatch.setattr(evaluation, "seconds_per_ray", lambda *args, **kwargs: 100.0)  # a very slow machine
    assert evaluation_scale("auto", None, loader, frames, 64) == pytest.approx((0.5, 4800.0))
    assert evaluation_scale("0.25", None, loader, frames, 64)[0] == 0.25  # a number is taken as it is
    assert evaluation_scale("auto", None, loader, [], 64) == (1.0, 0.0)
