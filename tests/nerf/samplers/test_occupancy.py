"""Empty-space skipping: the occupancy grid's update rule, marching, early termination, the sample budget, and
agreement of marched rendering with the paper's dense sampling on a sphere of known geometry, all rendered
through ``RadianceModel.render``."""

from __future__ import annotations

import math

import pytest
import torch

from nerfpipe.nerf.fields.analytic import SphereField

from nerfpipe.nerf.samplers.march import at_samples, march, visible, within_budget
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.samplers.configs import MarchingConfig
from nerfpipe.nerf.samplers.occupancy import OccupancyGrid
from nerfpipe.nerf.spaces.ray_space import BoxSpace
from nerfpipe.nerf.spaces.rays import RayBatch, intersect_box
from nerfpipe.nerf.render.volume import RaySamples
from nerfpipe.nerf.samplers.configs import HierarchicalConfig
from nerfpipe.nerf.samplers.hierarchical import HierarchicalSampler
from nerfpipe.nerf.samplers.marching import MarchingSampler

BOX = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))


SPACE = BoxSpace(BOX)


def rays_at(points: torch.Tensor, target: torch.Tensor) -> RayBatch:
    """Rays from ``points`` towards ``target``, clipped to BOX, unit directions."""
    d = torch.nn.functional.normalize(target - points, dim=-1)
    lo, hi = torch.tensor(BOX[0]), torch.tensor(BOX[1])
    enter, exit_ = intersect_box(points, d, lo, hi)
    near = enter.clamp_min(0.0)
    far = torch.maximum(exit_, near)
    return RayBatch(points, d, d, near, far)


def marching(field, grid: OccupancyGrid, config: MarchingConfig) -> RadianceModel:
    return RadianceModel(field, None, MarchingSampler(grid, config), SPACE, None)


def of_ray(samples: RaySamples, r: int) -> RaySamples:
    return samples.select(samples.ray == r)


def camera_rays(n: int = 400, seed: int = 0, spread: float = 1.6) -> RayBatch:
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


def test_march_through_an_occupied_grid_tiles_near_to_far_in_equal_steps() -> None:
    grid = OccupancyGrid(*BOX, resolution=4)
    rays = rays_at(torch.tensor([[0.0, 0.0, 3.0], [0.3, -0.2, 3.0]]), torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    s = march(rays, SPACE, grid, steps=64, randomized=False)
    dt = grid.diagonal / 64  # unit directions: one step of diagonal / steps in t
    assert bool((s.ray[1:] >= s.ray[:-1]).all())  # packed ray after ray
    for r in range(2):
        near, far = float(rays.near[r]), float(rays.far[r])
        mine = of_ray(s, r)
        n = len(mine)
        assert n == math.ceil((far - near) / dt)
        t = mine.t
        assert torch.allclose(t[1:-1] - t[:-2], torch.full((n - 2,), dt), atol=1e-5)
        assert float(t[-1]) == pytest.approx((float(mine.starts[-1]) + far) / 2, abs=1e-5)  # the cut last step
        assert float(t[0]) == pytest.approx(near + 0.5 * dt, abs=1e-5)
        lengths = mine.ends - mine.starts
        assert float(lengths.sum()) == pytest.approx(far - near, abs=1e-4)  # the intervals tile the ray
        assert torch.allclose(mine.starts[1:], mine.ends[:-1], atol=1e-6)
        # spans count whole steps: step k of 64 spans [k, k + 1] / 64
        torch.testing.assert_close(mine.spans[0] * 64, torch.arange(n, dtype=torch.float32))


def test_march_skips_empty_cells_and_rays_that_miss() -> None:
    sphere = SphereField(radius=0.4)
    grid = OccupancyGrid(*BOX, resolution=16)
    grid.update(sphere.query_density, grid.diagonal / 128, 0.01, all_cells=True, generator=torch.Generator().manual_seed(0))
    rays = rays_at(torch.tensor([[0.0, 0.0, 3.0], [0.9, 0.9, 3.0]]), torch.tensor([[0.0, 0.0, 0.0], [0.9, 0.9, 0.0]]))
    s = march(rays, SPACE, grid, steps=128, randomized=False)
    points = rays.points(s.ray, s.t)
    # every kept sample is within a cell diagonal of the sphere; the ray through the corner keeps nothing
    cell = grid.diagonal / 16
    assert float(points.norm(dim=-1).max()) <= 0.4 + cell
    counts = s.counts()
    assert 0 < int(counts[0]) < 40 and int(counts[1]) == 0


def test_marched_rendering_matches_dense_sampling_with_fewer_samples() -> None:
    sphere = SphereField(radius=0.5, density=50.0)
    grid = OccupancyGrid(*BOX, resolution=32)
    config = MarchingConfig(steps=1024, early_stop=0.0)
    generator = torch.Generator().manual_seed(0)
    for _ in range(8):  # one random point per cell and update: cells the sphere barely enters need a few
        grid.update(sphere.query_density, grid.diagonal / config.steps, config.occupancy_threshold, all_cells=True,
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
    rays = camera_rays()
    white = torch.ones(3)
    marched = marching(sphere, grid, config).render_rays(rays, background=white)
    dense = RadianceModel(sphere, None, HierarchicalSampler(HierarchicalConfig(n_coarse=1024, n_fine=0)), SPACE, None).render_rays(
        rays, background=white)
    assert torch.allclose(marched["acc"], dense["acc"], atol=0.02)
    assert torch.allclose(marched["rgb"], dense["rgb"], atol=0.02)
    hit = dense["acc"] > 0.99
    assert torch.allclose(marched["depth"][hit], dense["depth"][hit], atol=0.01)
    assert float(marched["samples"]) < 1024 / 3


def test_early_termination_drops_only_what_is_hidden() -> None:
    sphere = SphereField(radius=0.5, density=200.0)
    grid = OccupancyGrid(*BOX, resolution=32)
    rays = camera_rays(200, spread=0.6)  # every ray hits the sphere
    white = torch.ones(3)
    full = marching(sphere, grid, MarchingConfig(steps=256, early_stop=0.0)).render(rays, background=white)
    early = marching(sphere, grid, MarchingConfig(steps=256, early_stop=1e-3)).render(rays, background=white)
    assert early.evaluated < full.evaluated / 3  # an opaque sphere: most samples lie behind its surface
    # what is dropped weighs at most the transmittance left
    assert float((full.acc - early.acc).abs().max()) <= 1e-3
    assert float((full.rgb - early.rgb).abs().max()) <= 2e-3
    # each ray keeps a prefix of its samples, every one of them reached with transmittance above 1e-3, and
    # the window that looks at a few samples at a time keeps exactly what one pass over all of them does
    samples = march(rays, SPACE, grid, 256, randomized=False)
    kept = visible(rays, SPACE, samples, at_samples(rays, SPACE, sphere.density_features), 1e-3)
    counts = kept.counts()
    assert all(torch.equal(of_ray(kept, r).t, of_ray(samples, r).t[:int(counts[r])]) for r in range(len(rays)))
    windowed = visible(rays, SPACE, samples, at_samples(rays, SPACE, sphere.density_features), 1e-3, window=16)
    assert torch.equal(windowed.t, kept.t) and torch.equal(windowed.ray, kept.ray)
    sigmas = sphere.query_density(rays.points(kept.ray, kept.t))
    tau = sigmas * (kept.ends - kept.starts)
    assert bool((torch.exp(-kept.exclusive_sums(tau)) > 1e-3).all())
    assert torch.equal(kept.counts(), torch.bincount(kept.ray, minlength=len(rays)))
    assert early.evaluated == len(windowed)


def test_within_budget_counts_the_leading_rays_that_fit() -> None:
    ray = torch.tensor([0, 0, 0, 2, 2, 2, 2, 2, 3, 3])  # counts 3, 0, 5, 2
    samples = RaySamples(ray, torch.zeros(10), torch.zeros(10), torch.zeros(10), 4)
    assert within_budget(samples, 10) == 4
    assert within_budget(samples, 9) == 3  # 3 + 0 + 5 = 8 fit, + 2 does not
    assert within_budget(samples, 7) == 2
    assert within_budget(samples, 1) == 1  # always at least one ray, however long
    assert within_budget(samples, 0) == 4  # no budget: every ray


def test_a_sample_budget_renders_a_prefix_of_the_rays_unchanged() -> None:
    sphere = SphereField(radius=0.5, density=200.0)
    grid = OccupancyGrid(*BOX, resolution=16)  # every cell occupied: a fresh grid
    rays = camera_rays(300, spread=1.2)
    model = marching(sphere, grid, MarchingConfig(steps=128, early_stop=1e-3))
    whole = model.render(rays, train=True, generator=torch.Generator().manual_seed(0), background=torch.ones(3))
    budget = whole.evaluated // 5
    part = model.render(rays, train=True, generator=torch.Generator().manual_seed(0), background=torch.ones(3),
                        max_samples=budget)
    kept = len(part)
    assert 0 < kept < 300 and part.evaluated <= budget
    torch.testing.assert_close(part.rgb, whole.rgb[:kept])
    torch.testing.assert_close(part.depth, whole.depth[:kept])
    # the next ray would not have fitted
    counts = whole.samples.counts()
    assert int(counts[:kept].sum()) == part.evaluated and int(counts[:kept + 1].sum()) > budget


def test_randomized_marching_jitters_each_ray_within_one_step() -> None:
    grid = OccupancyGrid(*BOX, resolution=4)
    rays = camera_rays(50)
    s = march(rays, SPACE, grid, 64, randomized=True, generator=torch.Generator().manual_seed(1))
    dt = grid.diagonal / 64
    first_of_ray = torch.cat([torch.ones(1, dtype=torch.bool), s.ray[1:] != s.ray[:-1]])  # packed ray after ray
    first = s.t[first_of_ray] - rays.near
    assert bool(((first >= 0) & (first < dt + 1e-6)).all()) and float(first.std()) > dt / 10
    assert bool((s.starts >= rays.near[s.ray] - 1e-6).all()) and bool((s.ends <= rays.far[s.ray] + 1e-6).all())
    assert bool(((s.t >= s.starts) & (s.t <= s.ends)).all())


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
    from nerfpipe.nerf.fields.configs import GridConfig
    from nerfpipe.nerf.fields.grid import GridField
    torch.manual_seed(0)
    field = GridField(*BOX, GridConfig(levels=2, min_resolution=4, max_resolution=8))
    grid = OccupancyGrid(*BOX, resolution=8)
    grid.update(SphereField(radius=0.6).query_density, grid.diagonal / 64, 0.01, all_cells=True)
    model = RadianceModel(field, None, MarchingSampler(grid, MarchingConfig(occupancy_resolution=8, steps=64)), SPACE,
                          (1.0, 1.0, 1.0), {})
    model.save(tmp_path)
    loaded = RadianceModel.load(tmp_path)
    assert isinstance(loaded.coarse, GridField) and loaded.sampler.config == MarchingConfig(occupancy_resolution=8, steps=64)
    assert torch.equal(loaded.sampler.grid.occupied, grid.occupied) and 0 < loaded.sampler.grid.occupancy() < 1
    rays = camera_rays(64)
    a, b = model.render_rays(rays), loaded.render_rays(rays)
    for key in ("rgb", "depth", "acc"):
        torch.testing.assert_close(a[key], b[key])
    assert 0 < float(a["samples"]) < 64


def test_cells_no_camera_sees_are_empty_for_good() -> None:
    from nerfpipe.nerf.samplers.occupancy import cells_seen

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


class CountingSphere(SphereField):
    """A sphere that counts the points whose density it was asked for, in either half or whole."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.densities = 0

    def forward(self, points, viewdirs=None, density_noise=0.0):
        self.densities += len(points)
        return super().forward(points, viewdirs, density_noise)

    def density_features(self, points):
        self.densities += len(points)
        return super().forward(points)[1], points

    def colour(self, points, viewdirs):
        return super().forward(points)[0]


def test_rendering_without_gradients_evaluates_each_density_once_and_renders_the_same() -> None:
    """The visibility pass's densities (``RaySamples.known``) are reused when nothing needs gradients, so each
    visited sample's density is computed once; with gradients the kept samples are evaluated again (the pass
    itself has none), and both give the same picture."""
    grid = OccupancyGrid(*BOX, resolution=16)
    rays = camera_rays(100, spread=1.2)
    sphere = CountingSphere(radius=0.5, density=200.0)
    model = marching(sphere, grid, MarchingConfig(steps=128, early_stop=1e-3))
    with torch.no_grad():
        fast = model.render(rays, background=torch.ones(3))
    once = sphere.densities
    sphere.densities = 0
    slow = model.render(rays, background=torch.ones(3))
    assert sphere.densities == once + slow.evaluated  # the kept samples again, with gradients
    assert 0 < fast.evaluated < once  # the pass looked at more samples than the rays kept
    for key in ("rgb", "depth", "acc"):
        torch.testing.assert_close(getattr(fast, key), getattr(slow, key))


class Contracted(BoxSpace):
    """The box space, named as contracted space is: where training may skip the visibility pass."""

    kind = "contracted"


def test_training_skips_the_visibility_pass_where_it_would_keep_nearly_every_sample() -> None:
    """In contracted space, in thin fog (optical depth at most 0.5 across the sphere) the pass keeps every marched
    sample: measured once, training then evaluates the marched samples directly, the same ones, each density once.
    Against an opaque sphere it drops most of them and keeps running; in a box (an object's space) it always runs.
    A grid refresh makes the next step measure again."""
    grid = OccupancyGrid(*BOX, resolution=16)
    rays = camera_rays(100, spread=0.6)
    fog = CountingSphere(radius=0.5, density=0.5)
    model = RadianceModel(fog, None, MarchingSampler(grid, MarchingConfig(steps=128, early_stop=1e-3)), Contracted(BOX), None)
    sampler = model.sampler
    measured = model.render(rays, train=True, generator=torch.Generator().manual_seed(1))
    assert sampler.visible_share == 1.0 and not sampler.measure
    fog.densities = 0
    skipped = model.render(rays, train=True, generator=torch.Generator().manual_seed(1))
    assert fog.densities == skipped.evaluated == measured.evaluated  # no pass: the field saw each sample once
    torch.testing.assert_close(skipped.rgb, measured.rgb)
    sampler.update(17, fog.query_density, torch.Generator().manual_seed(0))
    assert not sampler.measure  # no refresh at step 17
    sampler.update(32, fog.query_density, torch.Generator().manual_seed(0))
    fog.densities = 0
    again = model.render(rays, train=True, generator=torch.Generator().manual_seed(1))
    assert fog.densities > again.evaluated and not sampler.measure  # measured again after the refresh

    boxed = marching(fog, OccupancyGrid(*BOX, resolution=16), MarchingConfig(steps=128, early_stop=1e-3))
    boxed.render(rays, train=True, generator=torch.Generator().manual_seed(1))
    fog.densities = 0
    out = boxed.render(rays, train=True, generator=torch.Generator().manual_seed(1))
    assert fog.densities > out.evaluated and boxed.sampler.visible_share == -1.0  # a box: the pass ran, unmeasured

    wall = CountingSphere(radius=0.5, density=200.0)
    model = RadianceModel(wall, None, MarchingSampler(OccupancyGrid(*BOX, resolution=16),
                                                      MarchingConfig(steps=128, early_stop=1e-3)), Contracted(BOX), None)
    model.render(rays, train=True, generator=torch.Generator().manual_seed(1))
    assert model.sampler.visible_share < MarchingSampler.SKIP_VISIBILITY_ABOVE
    wall.densities = 0
    out = model.render(rays, train=True, generator=torch.Generator().manual_seed(1))
    assert wall.densities > out.evaluated  # the pass ran: it looked at the samples behind the surface too
    with torch.no_grad():  # rendering always runs it (its densities are reused)
        fog.densities = 0
        marching(fog, grid, sampler.config).render(rays)
        assert fog.densities > 0


def test_the_measured_share_is_saved_so_a_resumed_training_skips_as_it_would_have() -> None:
    sampler = MarchingSampler(OccupancyGrid(*BOX, resolution=8), MarchingConfig(occupancy_resolution=8))
    sampler.visible_share, sampler.measure = 0.93, False
    state = sampler.state_dict()
    resumed = MarchingSampler(OccupancyGrid(*BOX, resolution=8), MarchingConfig(occupancy_resolution=8))
    resumed.load_state_dict(state)
    assert resumed.visible_share == pytest.approx(0.93) and not resumed.measure
    older = {k: v for k, v in state.items() if k != "visible_share"}  # a model saved before the share was kept
    resumed.load_state_dict(older)
    assert resumed.visible_share == -1.0 and resumed.measure
    resumed.reset()
    assert resumed.measure
