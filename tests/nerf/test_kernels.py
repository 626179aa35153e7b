"""Rendering's compiled functions (``nerfpipe.nerf.kernels``): a model renders the same compiled as eagerly, in
every ray space and grid field kind; each function compiles once a process, whichever model of that shape it is
given; nothing compiles where gradients are on, for the MLP field, or with ``NERFPIPE_COMPILE=off``; a compiler that
fails leaves eager rendering, said once; inductor's C++ on this CPU renders what the eager model does, finite at
extreme inputs. These are how a CUDA device renders; on the CPU, the dense grid's models render in one native loop a
ray instead (``nerfpipe.nerf.fused``, tests/nerf/test_fused.py), which every test here switches off."""

from __future__ import annotations

import logging

import pytest
import torch

import nerfpipe.nerf.kernels as kernels
import nerfpipe.nerf.model as model_module
from nerfpipe.nerf.compiling import VARIABLE, choice
from nerfpipe.nerf.kernels import COMPILED, for_rendering
from nerfpipe.nerf.policy import build_model
from nerfpipe.nerf.samplers.march import occupied_candidates
from nerfpipe.nerf.spaces.rays import pixel_centers
from nerfpipe.pipeline.errors import ParamError
from tests.nerf.scenes import bounds_of, scene_of, world_of_one_camera
from tests.nerf.test_cuda import params_of, view_rays

CPU = torch.device("cpu")
SPACES = {"contracted": ("inward360", "none"), "box": ("inward360", "white"), "ndc": ("forward", "none")}


@pytest.fixture(autouse=True)
def through_torch(monkeypatch):
    """Rendering through torch's operators, compiled or not, as on a CUDA device: not the CPU's native loop."""
    monkeypatch.setattr(model_module, "marched_grid", lambda model: None)


@pytest.fixture
def traced(monkeypatch):
    """Compiling on: each graph traced and run without code generation, and counted (the list holds one entry a
    graph traced); the process's compiled functions and dynamo's caches fresh before and after."""
    graphs: list[int] = []

    def backend(gm, example_inputs):
        graphs.append(len(gm.graph.nodes))
        return gm.forward

    monkeypatch.setenv(VARIABLE, "auto")
    monkeypatch.setattr(kernels, "BACKEND", backend)
    COMPILED.reset()
    torch._dynamo.reset()
    yield graphs
    COMPILED.reset()
    torch._dynamo.reset()


def model_of(space: str = "contracted", kind: str = "grid", seed: int = 0):
    """An untrained model (a random field: fog everywhere, so every ray has many samples) of ``kind`` in ``space``."""
    torch.manual_seed(seed)
    layout, background = SPACES[space]
    sizes = {} if kind == "mlp" else {"field.max_resolution": 64, "field.levels": 2, "field.min_resolution": 16}
    params = params_of({"field.kind": kind, **sizes})
    return build_model(params, scene_of(layout, background), world_of_one_camera(), bounds_of((1.0, 5.0)), CPU,
                       ["a.png"])[0]


def rays_of(model):
    """A view through the field: from 3 units away at the box (``view_rays``), or NDC's own camera's (a.png)."""
    if model.ray_space.kind != "ndc":
        return view_rays(model)
    uv = pixel_centers(40, 30)
    n = len(uv)
    return model.ray_space.rays(uv, torch.tensor([50.0, 50.0, 20.0, 15.0]).expand(n, 4), torch.eye(4),
                                torch.full((n,), 1.0), torch.full((n,), 5.0))


def rendered(model, mode: str, monkeypatch) -> dict[str, torch.Tensor]:
    monkeypatch.setenv(VARIABLE, mode)
    return model.render_rays(rays_of(model), chunk=200)


def test_the_switch_is_read_from_the_environment_and_a_wrong_value_is_a_user_error(monkeypatch) -> None:
    monkeypatch.delenv(VARIABLE, raising=False)
    assert choice() == "auto"
    monkeypatch.setenv(VARIABLE, " OFF ")
    assert choice() == "off" and not kernels.enabled(CPU)
    monkeypatch.setenv(VARIABLE, "native")  # the native C kernels alone: rendering stays eager
    assert choice() == "native" and not kernels.enabled(CPU)
    monkeypatch.setenv(VARIABLE, "fast")
    with pytest.raises(ParamError, match="NERFPIPE_COMPILE=fast: must be one of auto, native, off"):
        choice()
    monkeypatch.setenv(VARIABLE, "auto")
    monkeypatch.setattr(kernels, "BACKEND", "inductor")
    monkeypatch.setattr(kernels, "cpp_compiler", lambda: None)  # a machine without g++: eager, and no warning
    assert not kernels.enabled(CPU) and kernels.enabled(torch.device("cuda"))
    assert kernels.run(lambda x: x + 1, 10_000, CPU, torch.zeros(3)).tolist() == [1.0, 1.0, 1.0]


@pytest.mark.parametrize("kind", ["grid", "hash", "planes"])
@pytest.mark.parametrize("space", list(SPACES))
def test_a_model_renders_the_same_compiled_as_eagerly(space, kind, traced, monkeypatch) -> None:
    model = model_of(space, kind)
    eager = rendered(model, "off", monkeypatch)
    assert not traced
    compiled = rendered(model, "auto", monkeypatch)
    assert traced and COMPILED.working is True
    assert float(eager["samples"]) > 4  # fog: many samples a ray, so the compiled functions did the work
    for key in ("rgb", "depth", "acc"):
        torch.testing.assert_close(compiled[key], eager[key], atol=1e-5, rtol=1e-5)


def test_each_function_compiles_once_for_every_model_of_its_shape(traced, monkeypatch) -> None:
    model = model_of(seed=0)
    monkeypatch.setenv(VARIABLE, "auto")
    model.render_rays(rays_of(model), chunk=100_000)  # the whole view in one chunk: its rays are not a view
    first = len(traced)
    assert first >= 3  # the march's candidates, the density along the rays, the colour
    other = model_of(seed=1)  # another stage loads its own model: same kind and shape, other values
    rendered(other, "auto", monkeypatch)
    assert len(traced) == first
    rays = rays_of(other)
    for chunk in (137, 4096):  # other chunks: other counts of rays, samples and steps, views at other offsets
        other.render_rays(rays.slice(5, len(rays) - 3), chunk=chunk)
    assert len(traced) == first
    with torch.no_grad():
        x = torch.rand(1000, 3) * 4 - 2
        torch.testing.assert_close(for_rendering(other.coarse).query_density(x), other.coarse.query_density(x))


def test_nothing_compiles_with_gradients_on_for_the_mlp_field_or_for_a_few_points(traced, monkeypatch) -> None:
    model = model_of()
    rays = view_rays(model)
    out = model.render(rays, train=True, generator=torch.Generator().manual_seed(0))  # training: gradients on
    out.rgb.sum().backward()
    assert model.coarse.table.grad is not None
    with torch.no_grad():
        for_rendering(model.coarse).query_density(torch.rand(kernels.FEWEST_ROWS - 1, 3))
    # the occupancy refresh and the visibility pass (no gradients) may compile; the training pass itself never
    traced_before = len(traced)
    with torch.enable_grad():
        for_rendering(model.coarse).query_density(torch.rand(5000, 3))
    assert len(traced) == traced_before
    mlp = model_of(kind="mlp")
    traced.clear()
    with torch.no_grad():
        for_rendering(mlp.coarse).query_density(torch.rand(5000, 3))
    assert not traced


def test_a_compiler_that_fails_leaves_eager_rendering_said_once(monkeypatch, caplog) -> None:
    calls = []

    def broken(gm, example_inputs):
        calls.append(1)
        raise RuntimeError("no C++ compiler\nmore detail")

    monkeypatch.setenv(VARIABLE, "auto")
    monkeypatch.setattr(kernels, "BACKEND", broken)
    COMPILED.reset()
    torch._dynamo.reset()
    try:
        model = model_of()
        eager = rendered(model, "off", monkeypatch)
        with caplog.at_level(logging.WARNING, logger="nerfpipe.nerf.kernels"):
            out = rendered(model, "auto", monkeypatch)
            again = rendered(model, "auto", monkeypatch)
        warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert len(warnings) == 1 and "no C++ compiler" in warnings[0] and "more detail" not in warnings[0]
        assert len(calls) == 1 and COMPILED.working is False
        torch.testing.assert_close(out["rgb"], eager["rgb"])
        torch.testing.assert_close(again["depth"], eager["depth"])
    finally:
        COMPILED.reset()
        torch._dynamo.reset()


def test_the_marchs_candidates_compiled_are_the_eager_ones(traced) -> None:
    model = model_of()
    grid, space = model.sampler.grid, model.ray_space
    grid.occupied.copy_(torch.rand(grid.occupied.shape, generator=torch.Generator().manual_seed(2)) < 0.3)
    rays = view_rays(model)
    starts, ends = space.steps(rays.origins, rays.directions, rays.near, rays.far, grid.diagonal / 64, 257)
    u = torch.rand(len(rays), 1)
    inputs = (space, grid, rays.origins, rays.directions, rays.far, starts, ends, u)
    with torch.no_grad():
        keep, t = kernels.run(occupied_candidates, starts.numel(), CPU, *inputs)
    assert traced
    eager_keep, eager_t = occupied_candidates(*inputs)
    assert 0 < int(keep.sum()) < keep.numel()
    assert torch.equal(keep, eager_keep) and torch.equal(t, eager_t)


@pytest.mark.skipif(kernels.cpp_compiler() is None, reason="inductor's CPU code needs a C++ compiler")
def test_inductor_on_the_cpu_renders_what_the_eager_model_does_finite_at_extreme_inputs(monkeypatch) -> None:
    """The real compiler (C++ loops), once: the render to float32 rounding, and the field's density and colour
    finite and equal to the eager ones at the box's faces, far outside it and at infinity."""
    monkeypatch.setattr(kernels, "BACKEND", "inductor")
    COMPILED.reset()
    torch._dynamo.reset()
    try:
        model = model_of("contracted", "hash")
        eager = rendered(model, "off", monkeypatch)
        compiled = rendered(model, "auto", monkeypatch)
        assert COMPILED.working is True
        for key in ("rgb", "depth", "acc"):
            torch.testing.assert_close(compiled[key], eager[key], atol=1e-4, rtol=1e-4)
        edges = torch.tensor([[-2.0, -2.0, -2.0], [2.0, 2.0, 2.0], [1e30, -1e30, 0.0], [float("inf"), 0.0, 0.0]])
        x = torch.cat([edges, torch.rand(1000, 3) * 4 - 2])
        d = torch.nn.functional.normalize(torch.randn(len(x), 3), dim=-1)
        with torch.no_grad():
            rgb, sigma = for_rendering(model.coarse)(x, d)
            want_rgb, want_sigma = model.coarse(x, d)
        assert bool(torch.isfinite(rgb).all()) and bool(torch.isfinite(sigma).all())
        torch.testing.assert_close(rgb, want_rgb, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(sigma, want_sigma, atol=1e-5, rtol=1e-4)
    finally:
        COMPILED.reset()
        torch._dynamo.reset()


def test_a_training_step_renders_eagerly_and_after_step_compiles(traced, monkeypatch, tmp_path) -> None:
    """The trainer's steps (march, visibility pass, occupancy refresh) run in ``eager()``: compiling there would take
    seconds from a time budget of training. What ``after_step`` renders (the floors' timing) compiles."""
    from nerfpipe.nerf.train.trainer import Trainer
    from tests.nerf.test_cuda import one_view_pixels

    params = params_of({"steps": 40, "optim.batch_rays": 64, "optim.batch_samples": 4096, "field.max_resolution": 64})
    model = build_model(params, scene_of("inward360"), world_of_one_camera(), bounds_of(), CPU, ["a.png"])[0]
    trainer = Trainer(model, one_view_pixels(CPU), params, tmp_path, CPU)
    rendered_after: list[int] = []

    def after_step(t) -> bool:
        if t.step == 20:
            rendered_after.append(len(traced))  # 20 steps: nothing compiled
            with torch.no_grad():
                model.render_rays(view_rays(model), chunk=200)
            rendered_after.append(len(traced))
        return False

    trainer.run(after_step=after_step)
    assert trainer.step == 40
    assert rendered_after[0] == 0 and rendered_after[1] >= 3  # compiled off the training clock
    assert len(traced) == rendered_after[1]  # and never inside a step, before or after
    assert not kernels._EAGER[0]


def test_the_switch_is_read_without_torch() -> None:
    """The command line checks ``NERFPIPE_COMPILE`` before anything runs; a run that stops before training (a no-op
    rerun of ingest: 0.3 s) must not pay for importing torch to do so."""
    import subprocess
    import sys

    code = "import sys; from nerfpipe.nerf.compiling import choice; choice(); print('torch' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and result.stdout.strip() == "False", result.stderr
