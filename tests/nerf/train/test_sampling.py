"""The error map's draws: each index is a pixel of the tile drawn, tiles are drawn in proportion to their
error mixed with uniform draws, the loss weights keep the expectation of any per-pixel quantity its mean over
every pixel, and a training resumed from a checkpoint draws what the uninterrupted one drew."""

from __future__ import annotations

import pytest
import torch

from nerfpipe.nerf.spaces.rays import pixel_centers
from nerfpipe.nerf.train.sampling import ErrorMap, image_sizes
from nerfpipe.nerf.train.trainer import Trainer
from tests.nerf.settings import train_settings
from tests.nerf.train.test_trainer import marching_model, pixels_of_one_view

SIZES = torch.tensor([[5, 3], [4, 4]])  # two photos, width x height: 15 + 16 pixels


def pixels(sizes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Image index (P,) and pixel centres (P, 2) of photos stored as ``ImageLoader.pixel_set`` stores them."""
    uv = [pixel_centers(int(w), int(h)) for w, h in sizes]
    image = torch.cat([torch.full((len(c),), i) for i, c in enumerate(uv)])
    return image, torch.cat(uv)


def test_tiles_cover_each_photo_once_with_smaller_tiles_at_its_edges() -> None:
    errors = ErrorMap(SIZES, tile=2)
    # 5 x 3 -> 3 x 2 tiles, 4 x 4 -> 2 x 2
    assert len(errors) == 6 + 4
    assert errors.cols.tolist() == [2, 2, 1, 2, 2, 1, 2, 2, 2, 2]
    assert errors.rows.tolist() == [2, 2, 2, 1, 1, 1, 2, 2, 2, 2]
    assert float(errors.pixels.sum()) == errors.total == 31


def test_image_sizes_are_read_off_the_pixel_centres() -> None:
    image, uv = pixels(SIZES)
    assert image_sizes(image, uv, 2).tolist() == SIZES.tolist()


def test_every_drawn_index_is_a_pixel_of_its_tile() -> None:
    image, uv = pixels(SIZES)
    errors = ErrorMap(SIZES, tile=2)
    errors.error[:] = torch.rand(len(errors), generator=torch.Generator().manual_seed(1))
    index, tiles, _ = errors.draw(4000, torch.Generator().manual_seed(0))
    column, row = (uv[index, 0] - 0.5).long(), (uv[index, 1] - 0.5).long()
    tile_image = torch.tensor([0] * 6 + [1] * 4)
    assert torch.equal(image[index], tile_image[tiles])
    assert torch.equal(column // 2, errors.x0[tiles] // 2) and torch.equal(row // 2, errors.y0[tiles] // 2)
    assert set(index.tolist()) == set(range(31))  # every pixel, edge tiles' included, is reachable


def test_without_errors_the_draws_are_uniform_and_unweighted() -> None:
    errors = ErrorMap(SIZES, tile=2)
    p = errors.probabilities()
    torch.testing.assert_close(p, errors.pixels / 31.0)
    _, _, weight = errors.draw(100, torch.Generator().manual_seed(0))
    torch.testing.assert_close(weight, torch.ones(100))


def test_half_the_draws_follow_the_error_and_the_weights_keep_the_mean_unbiased() -> None:
    errors = ErrorMap(SIZES, tile=2)
    errors.error[:] = torch.tensor([0.0, 1.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 2.0, -1.0])  # the last never drawn
    p = errors.probabilities()
    # the tile never drawn counts at the largest error known, 3; pixel-weighted errors: 4*1 + 2*3 + 4*2 + 4*3 = 30
    assert float(p[1]) == pytest.approx(0.5 * 4 / 31 + 0.5 * 4 / 30)
    assert float(p[4]) == pytest.approx(0.5 * 2 / 31 + 0.5 * 6 / 30)
    assert float(p[0]) == pytest.approx(0.5 * 4 / 31)
    assert float(p.sum()) == pytest.approx(1.0)
    # E[w f(pixel)] over the draws is the mean of f over all 31 pixels, exactly, for any f
    f = torch.arange(31, dtype=torch.float64) ** 2
    index, tiles, weight = errors.draw(400_000, torch.Generator().manual_seed(0))
    assert float((weight.double() * f[index]).mean()) == pytest.approx(float(f.mean()), rel=0.01)
    # and the tiles come up as often as their probability says
    frequency = torch.bincount(tiles, minlength=len(errors)).double() / len(tiles)
    torch.testing.assert_close(frequency, p, atol=3e-3, rtol=0)


def test_a_tiles_first_measurement_is_taken_whole_and_later_ones_halfway() -> None:
    errors = ErrorMap(SIZES, tile=2)
    errors.record(torch.tensor([3, 3, 7]), torch.tensor([0.2, 0.4, 0.1]))
    assert errors.error[3].item() == pytest.approx(0.3) and errors.error[7].item() == pytest.approx(0.1)
    errors.record(torch.tensor([3]), torch.tensor([0.1]))
    assert errors.error[3].item() == pytest.approx(0.2)
    untouched = torch.ones(len(errors), dtype=torch.bool)
    untouched[[3, 7]] = False
    assert bool((errors.error[untouched] == -1).all())


def test_a_map_of_other_photos_is_refused() -> None:
    errors = ErrorMap(SIZES, tile=2)
    with pytest.raises(ValueError, match="does not fit"):
        errors.load_state_dict({"error": torch.zeros(3)})
    with pytest.raises(ValueError, match="positive"):
        ErrorMap(torch.tensor([[0, 4]]))


def test_a_resumed_training_draws_and_ends_as_the_uninterrupted_one(tmp_path) -> None:
    config = train_settings(steps=6, batch_rays=64, batch_samples=0, lr=1e-3, lr_final=1e-4, pixels="error",
                            checkpoint_every=3, keep_checkpoints=5)
    view = pixels_of_one_view(size=20)
    view.rgb = torch.rand(view.rgb.shape, generator=torch.Generator().manual_seed(2))  # errors that differ by tile
    for name in ("straight", "killed"):
        (tmp_path / name).mkdir()
    straight = Trainer(marching_model(), view, config, tmp_path / "straight", torch.device("cpu"))
    straight.run()
    assert bool((straight.error_map.error >= 0).any())  # the map was measured

    first = Trainer(marching_model(), view, config, tmp_path / "killed", torch.device("cpu"))
    first.run(after_step=lambda t: t.step == 3)
    resumed = Trainer(marching_model(), view, config, tmp_path / "killed", torch.device("cpu"))
    assert resumed.resume() == 3
    torch.testing.assert_close(resumed.error_map.error, first.error_map.error)
    resumed.run()
    torch.testing.assert_close(resumed.error_map.error, straight.error_map.error, rtol=0, atol=0)
    for a, b in zip(resumed.model.coarse.parameters(), straight.model.coarse.parameters()):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-6)


def test_extreme_errors_keep_the_weights_finite_and_at_most_twice_a_uniform_rays() -> None:
    errors = ErrorMap(SIZES, tile=2)
    errors.error[:] = torch.tensor([1e30, 0.0, 1e-30, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    p = errors.probabilities()
    assert bool(torch.isfinite(p).all()) and float(p.sum()) == pytest.approx(1.0)
    _, tiles, weight = errors.draw(10_000, torch.Generator().manual_seed(0))
    # a tile keeps at least UNIFORM_SHARE of its uniform probability, so no ray weighs more than 1 / UNIFORM_SHARE
    assert bool(torch.isfinite(weight).all()) and float(weight.max()) <= 2.0 + 1e-6
    assert float((tiles == 0).double().mean()) == pytest.approx(0.5 + 0.5 * 4 / 31, abs=0.02)
    errors.error.zero_()  # a perfect fit: nothing to weigh by, the draws uniform again
    torch.testing.assert_close(errors.probabilities(), errors.pixels / 31.0)
