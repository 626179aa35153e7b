"""Rendering in one native loop a ray (nerfpipe.nerf.fused, nerfpipe/nerf/native/render.c): torch's rendering of the
same model to float rounding, in contracted and box spaces, through occupied and empty cells, stopping early or not,
at the MLP widths the kernel specializes and at others; by hand for a constant field; the same bits on one thread as
on two; other models, and rays that are not finite, left to torch."""

from __future__ import annotations

import math

import pytest
import torch

from nerfpipe.nerf import model as model_module
from nerfpipe.nerf import native
from nerfpipe.nerf.fields.configs import GridConfig, HashConfig, PlanesConfig
from nerfpipe.nerf.fields.grid import GridField
from nerfpipe.nerf.fields.hash import HashGridField
from nerfpipe.nerf.fields.planes import PlaneField
from nerfpipe.nerf.fused import marched_grid
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.samplers.configs import MarchingConfig
from nerfpipe.nerf.samplers.marching import MarchingSampler
from nerfpipe.nerf.samplers.occupancy import OccupancyGrid
from nerfpipe.nerf.spaces.ray_space import BoxSpace, ContractedSpace
from nerfpipe.nerf.spaces.rays import RayBatch, intersect_box

pytestmark = pytest.mark.skipif(native.library() is None, reason="no native kernels on this machine")

UNIT = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))


def build(contracted: bool, seed: int = 0, early_stop: float = 1e-4, background=None, **config) -> RadianceModel:
    """A dense grid field (hashed with ``log2_table`` in ``config``) with features and MLP weights drawn at random
    (densities of about 0.1 to 100), half of an occupancy grid's cells occupied, over [-2, 2]^3 contracted or the
    unit box."""
    torch.manual_seed(seed)
    box = ((-2.0,) * 3, (2.0,) * 3) if contracted else UNIT
    settings = {"levels": 2, "min_resolution": 8, "max_resolution": 16, "hidden": 32, **config}
    field = (HashGridField(*box, HashConfig(**settings)) if "log2_table" in settings
             else GridField(*box, GridConfig(**settings)))
    with torch.no_grad():
        field.table.normal_(0.0, 1.0)
        field.density_net[2].bias[0] += 1.0 if contracted else 2.5  # the box's rays are shorter
    grid = OccupancyGrid(*box, 16)
    grid.occupied.copy_(torch.rand(16**3) < 0.5)
    sampler = MarchingSampler(grid, MarchingConfig(steps=64, early_stop=early_stop, occupancy_resolution=16))
    space = ContractedSpace(UNIT) if contracted else BoxSpace(UNIT)
    return RadianceModel(field, None, sampler, space, background)


def rays(contracted: bool, n: int = 300, seed: int = 1) -> RayBatch:
    """Rays from a ring 3 units out towards the middle, to far bounds up to 100 (contracted) or clipped to the box."""
    g = torch.Generator().manual_seed(seed)
    angle = torch.rand(n, generator=g) * 2 * math.pi
    origins = torch.stack([3.0 * torch.cos(angle), 3.0 * torch.sin(angle), torch.rand(n, generator=g) - 0.5], -1)
    directions = torch.nn.functional.normalize(torch.randn(n, 3, generator=g) * 0.3 - origins / 3.0, dim=-1)
    if contracted:
        near, far = torch.full((n,), 0.5), torch.logspace(0.5, 2, n)
    else:
        near, far = intersect_box(origins, directions, -torch.ones(3), torch.ones(3))
        near, far = near.clamp_min(0.0), far.clamp_min(near.clamp_min(0.0))
    return RayBatch(origins, directions, directions, near, far)


def both(model: RadianceModel, batch: RayBatch, monkeypatch) -> tuple[dict, dict]:
    fused = model.render_rays(batch)
    with monkeypatch.context() as patch:
        patch.setattr(model_module, "marched_grid", lambda m: None)
        reference = model.render_rays(batch)
    return fused, reference


@pytest.mark.parametrize("contracted", [True, False])
@pytest.mark.parametrize("config", [{}, {"hidden": 64, "dir_freqs": 2}, {"hidden": 24, "features": 3},
                                    {"view_dependence": False, "levels": 3, "max_resolution": 32},
                                    {"levels": 3, "max_resolution": 64, "log2_table": 12}])  # 16 and 64 hashed
def test_the_kernel_renders_what_torch_renders(contracted, config, monkeypatch) -> None:
    """Ray by ray, the same samples and the same results to float rounding; a step that lies on a cell's face to
    within rounding may fall on the other side of it here than in torch's march (whose sums may be fused or not,
    eagerly or compiled): such a ray differs by that one sample, and is rare."""
    model = build(contracted, **config)
    grid, batch = marched_grid(model), rays(contracted)
    assert grid is not None
    rgb, depth, acc, counts = native.render_marched(grid, batch.origins, batch.directions, batch.viewdirs, batch.near,
                                                    batch.far)
    with torch.no_grad():
        reference = model.render(batch)
    expected = reference.samples.counts()
    assert float(reference.acc.max()) > 0.99 and float(reference.acc.min()) < 0.95  # opaque and clearer rays both
    same = counts == expected
    assert int((~same).sum()) <= 3 and bool(((counts - expected).abs() <= 1).all())
    for got, want in ((rgb, reference.rgb), (depth, reference.depth), (acc, reference.acc)):
        torch.testing.assert_close(got[same], want[same], rtol=1e-5, atol=1e-6)
    fused, _ = both(model, batch, monkeypatch)  # what ``render_rays`` gives is the kernel's
    assert torch.equal(fused["rgb"], rgb) and torch.equal(fused["depth"], depth)
    assert float(fused["samples"]) == pytest.approx(float(counts.double().mean()))


def test_early_termination_counts_the_samples_torch_keeps(monkeypatch) -> None:
    """Opaque stretches: far fewer samples a ray reach than without the stop, the same count either way."""
    model = build(True, seed=3)
    with torch.no_grad():
        model.coarse.density_net[2].bias[0] += 3.0
    batch = rays(True, seed=4)
    stopped, reference = both(model, batch, monkeypatch)
    model.sampler.config = MarchingConfig(steps=64, early_stop=0.0, occupancy_resolution=16)
    unstopped, _ = both(model, batch, monkeypatch)
    assert float(stopped["samples"]) == pytest.approx(float(reference["samples"]), rel=1e-3)
    assert float(stopped["samples"]) < 0.5 * float(unstopped["samples"])
    torch.testing.assert_close(stopped["rgb"], unstopped["rgb"], atol=2e-4, rtol=0)  # what was left is < 1e-4 of it


@pytest.mark.parametrize("sigma", [0.5, 1e3])
def test_a_constant_field_by_hand(sigma) -> None:
    """Density sigma and colour sigmoid(0.5) everywhere in the unit box; a ray down the z axis from z = 3 crosses it
    over t in [2, 4]: opacity 1 - exp(-2 sigma), colour that times sigmoid(0.5), depth 2 + 2 (1/tau - 1/(e^tau - 1))
    with tau = 2 sigma (the mean stopping depth, ``interval_stop_depths``); at sigma = 1000 the first step (of 0.054)
    is opaque: one sample, early stop 1e-4."""
    model = build(False)
    model.sampler.grid.occupied.fill_(True)
    with torch.no_grad():
        field = model.coarse
        for layer in (field.density_net[0], field.density_net[2], *field.color_net[::2]):
            layer.weight.zero_()
            layer.bias.zero_()
        field.density_net[2].bias[0] = math.log(sigma)
        field.color_net[4].bias.fill_(0.5)
    z = torch.tensor([[0.0, 0.0, -1.0]])
    out = model.render_rays(RayBatch(torch.tensor([[0.0, 0.0, 3.0]]), z, z, torch.tensor([2.0]), torch.tensor([4.0])))
    tau = 2.0 * sigma
    acc = -math.expm1(-tau)
    colour = acc / (1.0 + math.exp(-0.5))
    depth = 2.0 + 2.0 * (1.0 / tau - 1.0 / math.expm1(tau)) if tau < 30 else 2.0 + 1.0 / sigma
    assert float(out["acc"]) == pytest.approx(acc, rel=1e-5)
    torch.testing.assert_close(out["rgb"], torch.full((1, 3), colour), rtol=1e-5, atol=0)
    assert float(out["depth"]) == pytest.approx(depth, rel=1e-4, abs=2e-3)
    steps = math.ceil(2.0 / (model.sampler.grid.diagonal / 64))
    assert float(out["samples"]) == (steps if sigma < 1 else 1)


def test_two_threads_give_one_thread_s_bits() -> None:
    model, batch = build(True), rays(True, n=2000)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = model.render_rays(batch)
        torch.set_num_threads(2)
        two = model.render_rays(batch)
    finally:
        torch.set_num_threads(threads)
    for key in one:
        assert torch.equal(one[key], two[key])


def test_what_the_kernel_does_not_know_is_left_to_torch() -> None:
    model = build(True)
    assert marched_grid(model) is not None
    planes = PlaneField((-2.0,) * 3, (2.0,) * 3, PlanesConfig(levels=2, min_resolution=8, max_resolution=32))
    assert marched_grid(RadianceModel(planes, None, model.sampler, model.ray_space, None)) is None
    assert marched_grid(RadianceModel(model.coarse, model.coarse, model.sampler, model.ray_space, None)) is None
    batch = rays(True, n=8)
    origins = batch.origins.clone()
    origins[3, 1] = float("nan")
    grid = marched_grid(model)
    assert native.render_marched(grid, origins, batch.directions, batch.viewdirs, batch.near, batch.far) is None
    assert native.render_marched(grid, batch.origins.double(), batch.directions, batch.viewdirs, batch.near,
                                 batch.far) is None


def test_the_background_goes_behind_as_torch_puts_it(monkeypatch) -> None:
    model = build(False, background=(0.2, 0.4, 1.0))
    fused, reference = both(model, rays(False), monkeypatch)
    torch.testing.assert_close(fused["rgb"], reference["rgb"], rtol=1e-4, atol=2e-5)
    assert float(fused["rgb"][:, 2].min()) > 0.2  # the blue behind shows through the clear rays


@pytest.mark.parametrize("contracted", [True, False])
def test_training_s_visibility_pass_keeps_what_torch_keeps(contracted) -> None:
    """Of a randomized march's samples, the same ones reached as ``visible`` finds from the field's density in torch,
    rays stopping early among them."""
    from nerfpipe.nerf.samplers.march import at_samples, march, visible

    model = build(contracted, seed=5)
    with torch.no_grad():
        model.coarse.density_net[2].bias[0] += 2.0
    batch = rays(contracted, n=400, seed=6)
    samples = march(batch, model.ray_space, model.sampler.grid, 64, True, torch.Generator().manual_seed(0))
    keep = native.reached_marched(marched_grid(model), batch.origins, batch.directions, samples.ray, samples.t,
                                  samples.starts, samples.ends)
    reference = visible(batch, model.ray_space, samples,
                        at_samples(batch, model.ray_space, model.coarse.density_features), 1e-4, 16)
    assert keep is not None and int(keep.sum()) < 0.8 * len(samples)  # rays stopped
    assert torch.equal(samples.ray[keep], reference.ray) and torch.equal(samples.t[keep], reference.t)


def test_a_training_step_marches_through_the_native_pass(monkeypatch) -> None:
    """A training step (gradients on) asks the native pass which samples its rays reach, and its loss's gradient
    reaches the table; rendering without gradients reuses torch's densities instead (``RaySamples.known``)."""
    calls = []
    reached = native.reached_marched
    monkeypatch.setattr(native, "reached_marched", lambda *args: calls.append(1) or reached(*args))
    model, batch = build(False, seed=7), rays(False, n=256, seed=8)
    out = model.render(batch, train=True, generator=torch.Generator().manual_seed(0))
    out.rgb.sum().backward()
    assert calls and model.coarse.table.grad is not None and bool(torch.isfinite(model.coarse.table.grad).all())
    with torch.no_grad():
        model.render(batch)
    assert len(calls) == 1


def test_no_samples_and_no_rays_are_nothing_to_do() -> None:
    """A training step whose rays marched no sample (empty tensors: their data pointers may be null), and a batch of no
    rays, come back empty, not read (a run with camera refinement at pose_lr 10 crashed here)."""
    grid, batch = marched_grid(build(True)), rays(True, n=8)
    none = torch.empty(0)
    keep = native.reached_marched(grid, batch.origins, batch.directions, torch.empty(0, dtype=torch.int64), none, none,
                                  none)
    assert keep is not None and keep.shape == (0,)
    rgb, depth, acc, counts = native.render_marched(grid, *(x[:0] for x in (batch.origins, batch.directions,
                                                                         batch.viewdirs, batch.near, batch.far)))
    assert rgb.shape == (0, 3) and depth.shape == acc.shape == counts.shape == (0,)
