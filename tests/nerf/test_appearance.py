"""Per-image exposure and white balance: the camera model, its gauge and the held-out fit."""

from __future__ import annotations

import torch

from nerfpipe.nerf.appearance import ExposureGains, apply_gains, fit_gains


def srgb_decode(x: float) -> float:
    return ((x + 0.055) / 1.055) ** 2.4 if x > 0.04045 else x / 12.92


def srgb_encode(x: float) -> float:
    return 1.055 * x ** (1 / 2.4) - 0.055 if x > 0.0031308 else 12.92 * x


def test_unit_gains_change_nothing() -> None:
    rgb = torch.rand(500, 3, generator=torch.Generator().manual_seed(0))
    for linear in (False, True):
        assert torch.allclose(apply_gains(rgb, torch.ones(3), linear), rgb, atol=1e-6)


def test_gains_multiply_linear_light_and_clip_at_white() -> None:
    rgb = torch.tensor([[0.5, 0.2, 0.9]])
    gains = torch.tensor([2.0, 0.5, 2.0])
    expected = [srgb_encode(min(1.0, g * srgb_decode(c))) for c, g in zip((0.5, 0.2, 0.9), (2.0, 0.5, 2.0))]
    assert abs(expected[2] - 1.0) < 1e-12  # 0.9 is 0.787 in linear light: doubled, it clips
    assert torch.allclose(apply_gains(rgb, gains, False), torch.tensor([expected]), atol=1e-5)
    assert torch.allclose(apply_gains(rgb, gains, True), torch.tensor([[1.0, 0.1, 1.0]]))


def test_gains_have_a_geometric_mean_of_one_and_start_from_the_known_stops() -> None:
    gains = ExposureGains(3, linear=False, stops=[1.0, 0.0, -0.4])
    assert torch.allclose(gains.gains().log2().mean(dim=0), torch.zeros(3), atol=1e-6)
    assert torch.allclose(gains.stops()[:, 0], torch.tensor([0.8, -0.2, -0.6]), atol=1e-6)
    fresh = ExposureGains(4, linear=False)
    rgb = torch.rand(8, 3)
    assert torch.equal(fresh(rgb, torch.arange(8) % 4), apply_gains(rgb, torch.ones(3), False))


def test_a_held_out_photos_gains_are_recovered_from_part_of_it() -> None:
    render = torch.rand(2000, 3, generator=torch.Generator().manual_seed(1)) * 0.8
    truth = torch.tensor([1.6, 1.1, 0.7])
    fitted = fit_gains(render, apply_gains(render, truth, False), linear=False)
    assert torch.allclose(fitted, truth, rtol=1e-3)
