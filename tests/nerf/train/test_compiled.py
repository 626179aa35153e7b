"""The fixed-shape training step (``nerfpipe.nerf.train.compiled``): padding renders and trains what the samples
do; the step traces to one graph that every later step reuses, whatever its rays' and samples' counts; inductor
compiles it on the CPU to the eager step's loss; a compiler that fails leaves the eager step, said once."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import pytest
import torch

import nerfpipe.nerf.train.compiled as compiled
from nerfpipe.nerf.policy import build_model
from nerfpipe.nerf.render.volume import RaySamples
from nerfpipe.nerf.train.compiled import compile_mode, pad_rays, pad_samples
from nerfpipe.nerf.train.loss import step_loss
from nerfpipe.nerf.train.trainer import Trainer
from tests.nerf.scenes import bounds_of, scene_of, world_of_one_camera
from tests.nerf.test_cuda import one_view_pixels, params_of

CPU = torch.device("cpu")
STEP = {"optim.batch_rays": 64, "optim.batch_samples": 4096, "field.max_resolution": 64}


def model_of(values: dict):
    """A contracted-space grid model marching its occupancy grid, with pose refinement (inward 360, no backdrop)."""
    torch.manual_seed(0)
    params = params_of({**STEP, **values})
    return build_model(params, scene_of("inward360"), world_of_one_camera(), bounds_of(), CPU, ["a.png"])[0], params


def training_rays(model):
    px = one_view_pixels(CPU)
    image = px.image
    return model.ray_space.rays(px.uv, px.intrinsics[image], px.c2w[image], px.near[image], px.far[image]), px.rgb


def test_padded_samples_render_and_train_what_the_samples_do() -> None:
    model, _ = model_of({})
    rays, target = training_rays(model)
    samples, _, _ = model.sample(rays, train=True, generator=torch.Generator().manual_seed(1))
    n, r = len(samples), len(rays)
    assert n > 100
    padded, full = pad_samples(samples, n + 100, r + 3), pad_rays(rays, r + 4)
    assert len(padded) == n + 100 and padded.n_rays == r + 4 and len(full) == r + 4
    assert bool((padded.ray[1:] >= padded.ray[:-1]).all())  # still packed ray after ray
    a, b = model.shade(rays, samples), model.shade(full, padded)
    for key in ("rgb", "acc", "depth"):
        torch.testing.assert_close(getattr(b, key)[:r], getattr(a, key), atol=1e-6, rtol=1e-5)
    assert bool((b.weights[n:] == 0).all()) and bool((b.acc[r:] == 0).all())

    tables = [p for f in model.fields() for p in f.parameters()] + list(model.refinement.parameters())
    share = torch.full((r,), 1.0 / r)
    plain = torch.autograd.grad(step_loss(a, target, share, None, 0.0)[0], tables, allow_unused=True)
    wide = torch.cat([share, torch.zeros(4)])
    padded_target = torch.cat([target, torch.rand(4, 3)])  # a padding ray's target counts for nothing
    grads = torch.autograd.grad(step_loss(b, padded_target, wide, None, 0.0)[0], tables, allow_unused=True)
    for g, h in zip(plain, grads):
        if g is not None:
            torch.testing.assert_close(h, g, atol=1e-7, rtol=1e-4)


def test_a_ray_with_more_samples_than_the_budget_keeps_its_leading_ones() -> None:
    t = torch.arange(10.0)
    samples = RaySamples(torch.zeros(10, dtype=torch.long), t, t, t + 1, 1)
    padded = pad_samples(samples, 4, 1)
    assert padded.t.tolist() == [0.0, 1.0, 2.0, 3.0] and padded.n_rays == 2


def test_auto_compiles_on_cuda_and_not_on_the_cpu() -> None:
    assert compile_mode("auto", torch.device("cpu")) == "off"
    assert compile_mode("auto", torch.device("cuda")) == "kernels"
    assert compile_mode("graphs", torch.device("cpu")) == "graphs"


def train(values: dict, tmp_path: Path, steps: int):
    model, params = model_of(values)
    trainer = Trainer(model, one_view_pixels(CPU), params, tmp_path, CPU)
    losses, rays = [], []
    for step in range(steps):
        losses.append(trainer.train_step(step)[0])
        rays.append(trainer.rays)
    return trainer, losses, rays


def test_the_step_traces_to_one_graph_that_later_steps_reuse(tmp_path: Path, monkeypatch) -> None:
    graphs = []

    def counting(graph, inputs):  # a backend that only counts what dynamo hands it
        graphs.append(graph)
        return graph.forward

    monkeypatch.setattr(compiled, "BACKEND", counting)
    trainer, losses, rays = train({"compile": "kernels"}, tmp_path / "static", 14)
    assert trainer.static is not None and len(graphs) == 1  # no graph break, no recompile
    assert len(set(rays)) > 3  # though the rays a step kept changed from step to step
    eager, eager_losses, _ = train({"compile": "off"}, tmp_path / "eager", 1)
    assert eager.static is None
    # the first batch's samples fit either budget: the same loss
    assert losses[0] == pytest.approx(eager_losses[0], rel=1e-5)
    assert losses[-1] < 0.5 * losses[0]


@pytest.mark.skipif(shutil.which("c++") is None and shutil.which("g++") is None, reason="inductor needs a C++ compiler")
def test_inductor_compiles_the_step_on_the_cpu_to_the_eager_loss(tmp_path: Path) -> None:
    trainer, losses, _ = train({"compile": "kernels"}, tmp_path / "static", 3)
    assert trainer.static.compiled is not trainer.static.loss  # compiled, not fallen back
    _, eager_losses, _ = train({"compile": "off"}, tmp_path / "eager", 1)
    assert losses[0] == pytest.approx(eager_losses[0], rel=1e-4)
    grads = [p.grad for f in trainer.model.fields() for p in f.parameters() if p.grad is not None]
    assert grads and all(bool(torch.isfinite(g).all()) for g in grads)


def test_a_compiler_that_fails_leaves_the_eager_step_and_says_so(tmp_path: Path, monkeypatch, caplog) -> None:
    def broken(graph, inputs):
        raise RuntimeError("no C++ compiler found")

    monkeypatch.setattr(compiled, "BACKEND", broken)
    with caplog.at_level(logging.WARNING, logger="nerfpipe.nerf.train.compiled"):
        trainer, losses, _ = train({"compile": "kernels"}, tmp_path / "static", 3)
    said = [r.getMessage() for r in caplog.records if "compiling the training step failed" in r.getMessage()]
    assert len(said) == 1 and "no C++ compiler found" in said[0]
    assert trainer.static.compiled == trainer.static.loss
    _, eager_losses, _ = train({"compile": "off"}, tmp_path / "eager", 1)
    assert losses[0] == pytest.approx(eager_losses[0], rel=1e-6)


def test_a_sampler_of_fixed_cost_a_ray_stays_eager(tmp_path: Path) -> None:
    model, params = model_of({"compile": "kernels", "sampler.kind": "hierarchical"})
    assert Trainer(model, one_view_pixels(CPU), params, tmp_path, CPU).static is None


def test_compiling_is_not_counted_as_training_time(tmp_path: Path, monkeypatch) -> None:
    now = [0.0]

    def slow(graph, inputs):  # a backend that takes 50 s of the trainer's clock to compile
        now[0] += 50.0
        return graph.forward

    monkeypatch.setattr(compiled, "BACKEND", slow)
    model, params = model_of({"compile": "kernels", "steps": 3})
    trainer = Trainer(model, one_view_pixels(CPU), params, tmp_path, CPU, clock=lambda: now[0])
    trainer.run()
    assert trainer.step == 3 and trainer.elapsed == 0.0 and trainer.static.compile_seconds == 0.0
