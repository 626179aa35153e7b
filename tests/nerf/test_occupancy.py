"""Empty-space skipping: the occupancy grid's update rule, marching, packing, early termination, and
agreement of marched rendering with the paper's dense sampling on a sphere of known geometry."""

from __future__ import annotations

import math

import pytest
import torch

from nerfpipe.nerf.analytic import SphereField
from nerfpipe.nerf.marching import (
    PackedSamples,
    march,
    pack_left,
    rays_within,
    render_marched,
    render_marched_segments,
    transmittance_before,
    visible,
)
from nerfpipe.nerf.occupancy import MarchingConfig, OccupancyGrid
from nerfpipe.nerf.rays import intersect_box
from nerfpipe.nerf.renderer import RayBatch, SamplingConfig, render_chunked
from nerfpipe.nerf.samplers import MarchingSampler

BOX = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))


def rays_at(points: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Rays from ``points`` towards ``target``, clipped to BOX: origins, unit directions, near, far."""
    d = torch.nn.functional.normalize(target - points, dim=-1)
    lo, hi = torch.tensor(BOX[0]), torch.tensor(BOX[1])
    enter, exit_ = intersect_box(points, d, lo, hi)
    near = enter.clamp_min(0.0)
    far = torch.maximum(exit_, near)
    return points, d, near, far


def camera_rays(n: int = 400, seed: int = 0, spread: float = 1.6) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    origins = torch.tensor([0.0, 0.0, 3.0]).expand(n, 3).clone()
    targets = (torch.rand((n, 3), generator=g) - 0.5) * torch.tensor([spread, spread, 0.0])
    return rays_at(origins, targets)


def test_update_keeps_a_decaying_maximum_and_thresholds_optical_depth() -> None:
    grid = OccupancyGrid(*BOX, resolution=2)
    assert grid.occupancy() == 1.0  # nothing is skipped before the first update

    def density(points: torch.Tensor) -> torch.Tensor:
        # cell (i, j, k) of a 2^3 grid is flat index 4 i + 2 j + k, i = 1 where x > 0: each cell's value of ``table``
        index = ((points > 0).long() * torch.tensor([4, 2, 1])).sum(-1)
        return table[index]

    table = torch.tensor([100.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 50.0])
    grid.update(density, step_size=0.01, threshold=0.01, all_cells=True)
    assert grid.density.tolist() == [100.0, 0, 0, 0, 0, 0, 0, 50.0]
    # mean optical depth per step (150 / 8 * 0.01 = 0.1875) is above the threshold 0.01: the threshold holds
    assert grid.occupied.tolist() == [True, False, False, False, False, False, False, True]
    table = torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 60.0])
    grid.update(density, step_size=0.01, threshold=0.01, all_cells=True)
    assert grid.density[0] == pytest.approx(95.0) and grid.density[7] == pytest.approx(60.0)  # max(0.95 old, new)
    # a grid of tiny densities marks the cells above their mean, not nothing
    table = torch.tensor([1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 2e-3])
    faint = OccupancyGrid(*BOX, resolution=2)
    faint.update(density, step_size=0.01, threshold=0.01, all_cells=True)
    assert faint.occupied.tolist() == [False] * 7 + [True]
    # one faint density everywhere (a new field, which bf16 rounds to a single value) keeps every cell occupied,
    # where "above the mean" would have emptied the grid and stopped training (it did under bf16 autocast)
    table = torch.full((8,), 1e-3)
    even = OccupancyGrid(*BOX, resolution=2)
    even.update(density, step_size=0.01, threshold=0.01, all_cells=True)
    assert even.occupancy() == 1.0


def test_partial_updates_leave_unvisited_cells_occupied_until_seen() -> None:
    grid = OccupancyGrid(*BOX, resolution=8)
    grid.update(lambda p: torch.zeros(len(p)), 0.01, 0.01, all_cells=False, generator=torch.Generator().manual_seed(0))
    seen = grid.density >= 0
    assert 0 < int(seen.sum()) < 8**3
    assert bool(grid.occupied[~seen].all()) and not bool(grid.occupied[seen].any())


def test_pack_left_keeps_order_and_pads_with_far() -> None:
    valid = torch.tensor([[False, True, False, True], [False, False, False, False], [True, True, True, False]])
    t = torch.tensor([[0.1, 0.2, 0.3, 0.4], [0.1, 0.2, 0.3, 0.4], [0.5, 0.6, 0.7, 0.8]])
    packed_valid, (packed,) = pack_left(valid, t, fill=torch.tensor([[9.0], [8.0], [7.0]]))
    assert packed_valid.tolist() == [[True, True, False], [False, False, False], [True, True, True]]
    torch.testing.assert_close(packed, torch.tensor([[0.2, 0.4, 9.0], [8.0, 8.0, 8.0], [0.5, 0.6, 0.7]]))


def test_march_through_an_occupied_grid_tiles_near_to_far_in_equal_steps() -> None:
    grid = OccupancyGrid(*BOX, resolution=4)
    o, d, near, far = rays_at(torch.tensor([[0.0, 0.0, 3.0], [0.3, -0.2, 3.0]]), torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    s = march(o, d, near, far, grid, steps=64, randomized=False)
    dt = grid.diagonal / 64  # unit directions: one step of diagonal / steps in t
    for r in range(2):
        n = int(s.count[r])
        assert n == math.ceil(float((far[r] - near[r]) / dt))
        t = s.t[r, :n]
        assert torch.allclose(t[1:-1] - t[:-2], torch.full((n - 2,), dt), atol=1e-5)
        assert float(t[-1]) == pytest.approx(float(s.starts[r, n - 1] + far[r]) / 2, abs=1e-5)  # the cut last step
        assert float(t[0]) == pytest.approx(float(near[r]) + 0.5 * dt, abs=1e-5)
        lengths = (s.ends[r, :n] - s.starts[r, :n])
        assert float(lengths.sum()) == pytest.approx(float(far[r] - near[r]), abs=1e-4)  # the intervals tile the ray
        assert torch.allclose(s.starts[r, 1:n], s.ends[r, :n - 1], atol=1e-6)
        assert bool((s.t[r, n:] == far[r]).all()) and bool((s.ends[r, n:] == s.starts[r, n:]).all())


def test_march_skips_empty_cells_and_rays_that_miss() -> None:
    sphere = SphereField(radius=0.4)
    grid = OccupancyGrid(*BOX, resolution=16)
    grid.update(sphere.query_density, grid.diagonal / 128, 0.01, all_cells=True, generator=torch.Generator().manual_seed(0))
    o, d, near, far = rays_at(torch.tensor([[0.0, 0.0, 3.0], [0.9, 0.9, 3.0]]), torch.tensor([[0.0, 0.0, 0.0], [0.9, 0.9, 0.0]]))
    s = march(o, d, near, far, grid, steps=128, randomized=False)
    n = int(s.count[0])
    points = o[0] + s.t[0, :n, None] * d[0]
    # every kept sample is within a cell diagonal of the sphere; the ray through the corner keeps nothing
    cell = grid.diagonal / 16
    assert float(points.norm(dim=-1).max()) <= 0.4 + cell
    assert 0 < n < 40 and int(s.count[1]) == 0


def test_marched_rendering_matches_dense_sampling_with_fewer_samples() -> None:
    sphere = SphereField(radius=0.5, density=50.0)
    grid = OccupancyGrid(*BOX, resolution=32)
    config = MarchingConfig(steps=1024, early_stop=0.0)
    generator = torch.Generator().manual_seed(0)
    for _ in range(8):  # one random point per cell and update: cells the sphere barely enters need a few
        grid.update(sphere.query_density, grid.diagonal / config.steps, config.threshold, all_cells=True,
                    generator=generator)
    assert 0.05 < grid.occupancy() < 0.2  # the sphere fills 6.5 % of the box
    # exactly the cells the sphere enters (the nearest point of the cell to the centre is inside): what the
    # updates approach; a cell it barely enters may still be missed by 8 random points
    cell = 2.0 / 32
    lower = grid.cell_points(torch.arange(32**3), jitter=False) - cell / 2
    nearest = torch.clamp(torch.zeros(3), lower, lower + cell)
    exact = nearest.norm(dim=-1) <= 0.5
    assert bool((grid.occupied <= exact).all())  # the updates never mark a cell the sphere misses
    assert float((exact & ~grid.occupied).sum()) < 0.15 * float(exact.sum())  # measured: 282 of 2752
    grid.occupied.copy_(exact)
    o, d, near, far = camera_rays()
    white = torch.ones(3)
    marched, evaluated = render_marched_segments(sphere, o, d, d, near, far, grid, config, white)
    dense = render_chunked(sphere, None, RayBatch(o, d, d, near, far), SamplingConfig(1024, 0), white)
    assert torch.allclose(marched["acc"], dense["acc"], atol=0.02)
    assert torch.allclose(marched["rgb"], dense["rgb"], atol=0.02)
    hit = dense["acc"] > 0.99
    assert torch.allclose(marched["depth"][hit], dense["depth"][hit], atol=0.01)
    assert evaluated / len(o) < 1024 / 3


def test_early_termination_drops_only_what_is_hidden() -> None:
    sphere = SphereField(radius=0.5, density=200.0)
    grid = OccupancyGrid(*BOX, resolution=32)
    o, d, near, far = camera_rays(200, spread=0.6)  # every ray hits the sphere
    everything = MarchingConfig(steps=256, early_stop=0.0)
    stopping = MarchingConfig(steps=256, early_stop=1e-3)
    full, n_full = render_marched_segments(sphere, o, d, d, near, far, grid, everything, torch.ones(3))
    early, n_early = render_marched_segments(sphere, o, d, d, near, far, grid, stopping, torch.ones(3))
    assert n_early < n_full / 3  # an opaque sphere: most samples lie behind its surface
    # what is dropped weighs at most the transmittance left, plus one segment's worth of background
    assert float((full["acc"] - early["acc"]).abs().max()) <= 1e-3
    assert float((full["rgb"] - early["rgb"]).abs().max()) <= 2e-3
    # the training path: one density pass without gradients keeps a prefix of each ray
    samples = march(o, d, near, far, grid, 256, randomized=False)
    kept = visible(sphere.query_density, o, d, samples, 1e-3)
    counts = kept.valid.sum(-1)
    assert bool((kept.valid == (torch.arange(kept.valid.shape[1]) < counts[:, None])).all())
    sigmas = sphere.query_density((o[:, None] + kept.t[..., None] * d[:, None]).reshape(-1, 3)).reshape(kept.t.shape)
    T = transmittance_before(torch.where(kept.valid, sigmas, torch.zeros_like(sigmas)), kept)
    assert bool((T[kept.valid] > 1e-3).all())
    trained, n_trained = render_marched(sphere, sphere.query_density, o, d, d, near, far, grid, stopping, torch.ones(3),
                                        randomized=False)
    assert n_trained == int(counts.sum())
    assert torch.allclose(trained.rgb, early["rgb"], atol=2e-3)


def test_rays_within_counts_the_leading_rays_that_fit() -> None:
    valid = torch.tensor([[True, True, True, False, False], [False] * 5, [True] * 5, [True, True, False, False, False]])
    samples = PackedSamples(torch.zeros(4, 5), torch.zeros(4, 5), torch.zeros(4, 5), valid)  # counts 3, 0, 5, 2
    assert rays_within(samples, 10) == 4
    assert rays_within(samples, 9) == 3  # 3 + 0 + 5 = 8 fit, + 2 does not
    assert rays_within(samples, 7) == 2
    assert rays_within(samples, 1) == 1  # always at least one ray, however long


def test_a_sample_budget_renders_a_prefix_of_the_rays_unchanged() -> None:
    sphere = SphereField(radius=0.5, density=200.0)
    grid = OccupancyGrid(*BOX, resolution=16)  # every cell occupied: a fresh grid
    o, d, near, far = camera_rays(300, spread=1.2)
    config = MarchingConfig(steps=128, early_stop=1e-3)
    whole, n_whole = render_marched(sphere, sphere.query_density, o, d, d, near, far, grid, config, torch.ones(3),
                                    randomized=False)
    budget = n_whole // 5
    part, n_part = render_marched(sphere, sphere.query_density, o, d, d, near, far, grid, config, torch.ones(3),
                                  randomized=False, max_samples=budget)
    kept = len(part.rgb)
    assert 0 < kept < 300 and n_part <= budget
    torch.testing.assert_close(part.rgb, whole.rgb[:kept])
    torch.testing.assert_close(part.depth, whole.depth[:kept])
    # the next ray would not have fitted
    counts = visible(sphere.query_density, o, d, march(o, d, near, far, grid, 128, randomized=False), 1e-3).count
    assert int(counts[:kept].sum()) == n_part and int(counts[:kept + 1].sum()) > budget


def test_randomized_marching_jitters_each_ray_within_one_step() -> None:
    grid = OccupancyGrid(*BOX, resolution=4)
    o, d, near, far = camera_rays(50)
    s = march(o, d, near, far, grid, 64, randomized=True, generator=torch.Generator().manual_seed(1))
    dt = grid.diagonal / 64
    first = s.t[:, 0] - near
    assert bool(((first >= 0) & (first < dt + 1e-6)).all()) and float(first.std()) > dt / 10
    assert bool((s.starts[s.valid] >= near.unsqueeze(-1).expand_as(s.t)[s.valid] - 1e-6).all())
    assert bool((s.ends[s.valid] <= far.unsqueeze(-1).expand_as(s.t)[s.valid] + 1e-6).all())


def test_bad_grids_and_settings_are_refused() -> None:
    with pytest.raises(ValueError):
        OccupancyGrid((0, 0, 0), (1, 0, 1))
    with pytest.raises(ValueError):
        OccupancyGrid(*BOX, resolution=0)
    with pytest.raises(ValueError):
        MarchingConfig(early_stop=1.0)
    with pytest.raises(ValueError):
        MarchingConfig(steps=0)


def test_a_marching_model_saves_and_loads_with_its_grid(tmp_path) -> None:
    from nerfpipe.nerf.grid_field import GridField, GridFieldConfig
    from nerfpipe.nerf.model import RadianceModel
    from nerfpipe.nerf.ray_space import RaySpace

    torch.manual_seed(0)
    field = GridField(*BOX, GridFieldConfig(levels=2, min_resolution=4, max_resolution=8))
    grid = OccupancyGrid(*BOX, resolution=8)
    grid.update(SphereField(radius=0.6).query_density, grid.diagonal / 64, 0.01, all_cells=True)
    model = RadianceModel(field, None, MarchingSampler(grid, MarchingConfig(steps=64)), RaySpace(box=BOX),
                          (1.0, 1.0, 1.0), {})
    model.save(tmp_path)
    loaded = RadianceModel.load(tmp_path)
    assert isinstance(loaded.coarse, GridField) and loaded.sampler.config == MarchingConfig(steps=64)
    assert torch.equal(loaded.sampler.grid.occupied, grid.occupied) and 0 < loaded.sampler.grid.occupancy() < 1
    o, d, near, far = camera_rays(64)
    rays = RayBatch(o, d, d, near, far)
    a, b = model.render_batch(rays), loaded.render_batch(rays)
    for key in ("rgb", "depth", "acc"):
        torch.testing.assert_close(a[key], b[key])
    assert 0 < float(a["samples"]) < 64


def test_cells_no_camera_sees_are_empty_for_good() -> None:
    from nerfpipe.nerf.occupancy import cells_seen

    grid = OccupancyGrid((-1.0,) * 3, (1.0,) * 3, 4)  # cell centres at +-0.25, +-0.75
    # one camera at the origin looking down +z (OpenCV), a 90 degree field of view: |x|, |y| <= z
    c2w = torch.eye(4)[None]
    intrinsics = torch.tensor([[10.0, 10.0, 10.0, 10.0]])
    seen = cells_seen(grid, lambda points: points, intrinsics, c2w)
    centres = grid.cell_points(torch.arange(64), jitter=False)
    expected = (centres[:, 2] > 0) & (centres[:, 0].abs() <= centres[:, 2]) & (centres[:, 1].abs() <= centres[:, 2])
    assert torch.equal(seen, expected) and int(seen.sum()) == 2 * 2 + 4 * 4  # z = 0.25: the 4 middle cells; z = 0.75: all 16
    grid.restrict_to(seen)
    assert torch.equal(grid.occupied, seen)
    grid.update(lambda points: torch.full((len(points),), 100.0), step_size=0.1, threshold=0.01, all_cells=True)
    assert torch.equal(grid.occupied, seen)  # dense everywhere, yet the unseen cells stay empty
    grid.reset()
    assert torch.equal(grid.occupied, seen)
