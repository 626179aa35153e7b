"""The CUDA path, on a machine with a CUDA device (skipped elsewhere: CI has none).

Each field and sampler renders on the GPU what it renders on the CPU from the same weights; training steps
there, with per-image exposure and pose refinement, stay finite and lower the loss, in float32 and under bf16
autocast; a model trained there loads on the CPU and renders the same; the grid fields' gradients stay finite
at extreme inputs on the GPU too.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from nerfpipe.nerf.policy import build_model

from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.spaces.rays import pixel_centers
from nerfpipe.nerf.registry import FIELDS, part_class
from nerfpipe.nerf.train.trainer import PixelSet, Trainer
from nerfpipe.pipeline.params import build_params
from nerfpipe.stages.train import PRESETS, TrainParams
from tests.helpers import look_at
from tests.nerf.scenes import bounds_of, scene_of, world_of_one_camera

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")

CPU, CUDA = torch.device("cpu"), torch.device("cuda")
SIZE = 24
EYE = np.array([0.3, -3.0, 0.8])


def params_of(values: dict) -> TrainParams:
    return build_params("train", TrainParams, PRESETS, None, values)


def view_rays(model: RadianceModel):
    """The rays of one SIZE x SIZE view from 3 units away, looking at the box's centre, on the model's device."""
    device = model.device
    uv = pixel_centers(SIZE, SIZE, device)
    n = len(uv)
    k = torch.tensor([SIZE / 1.2, SIZE / 1.2, SIZE / 2, SIZE / 2], device=device).expand(n, 4)
    pose = torch.tensor(look_at(EYE, np.zeros(3)), dtype=torch.float32, device=device)
    return model.ray_space.rays(uv, k, pose, torch.full((n,), 1.0, device=device), torch.full((n,), 5.0, device=device))


def twins(values: dict, layout: str = "inward360") -> tuple[RadianceModel, RadianceModel]:
    """The model ``values`` build, on the CPU and on the GPU, with the same weights."""
    params = params_of(values)
    cpu, _ = build_model(params, scene_of(layout), world_of_one_camera(), bounds_of(), CPU, ["a.png"])
    gpu, _ = build_model(params, scene_of(layout), world_of_one_camera(), bounds_of(), CUDA, ["a.png"])
    gpu.load_state({k: {n: t.to(CUDA) for n, t in v.items()} for k, v in cpu.state().items()})
    return cpu, gpu


@pytest.mark.parametrize("kind", list(FIELDS))
@pytest.mark.parametrize("sampler", ["marching", "hierarchical"])
@pytest.mark.parametrize("layout", ["inward360", "unbounded"])
def test_every_field_and_sampler_renders_on_the_gpu_what_it_renders_on_the_cpu(kind, sampler, layout) -> None:
    cpu, gpu = twins({"field.kind": kind, "sampler.kind": sampler, "field.max_resolution": 256}, layout)
    assert gpu.device.type == "cuda" and all(p.is_cuda for f in gpu.fields() for p in f.parameters())
    a, b = cpu.render_rays(view_rays(cpu), chunk=256), gpu.render_rays(view_rays(gpu), chunk=256)
    assert b["rgb"].is_cuda and float(b["acc"].max()) > 0.0  # something was rendered
    for key in ("rgb", "acc", "depth"):
        torch.testing.assert_close(b[key].cpu(), a[key], atol=2e-3, rtol=2e-3, msg=f"{key} of {kind} / {sampler}")


def one_view_pixels(device: torch.device) -> PixelSet:
    """A SIZE x SIZE view of a red disc on grey (world: one camera named a.png), every ray through the box."""
    uv = pixel_centers(SIZE, SIZE)
    inside = ((uv - SIZE / 2) ** 2).sum(-1) < (SIZE / 4) ** 2
    rgb = torch.where(inside[:, None], torch.tensor([0.9, 0.1, 0.1]), torch.tensor([0.5, 0.5, 0.5]))
    c2w = torch.tensor(look_at(EYE, np.zeros(3)), dtype=torch.float32)
    return PixelSet(rgb=rgb, image=torch.zeros(len(uv), dtype=torch.long), uv=uv,
                    intrinsics=torch.tensor([[SIZE / 1.2, SIZE / 1.2, SIZE / 2, SIZE / 2]]), c2w=c2w[None],
                    near=torch.tensor([1.0]), far=torch.tensor([5.0])).to(device)


@pytest.mark.parametrize("kind", list(FIELDS))
@pytest.mark.parametrize("autocast", ["none", "bf16"])
def test_training_on_the_gpu_lowers_the_loss_with_exposure_and_pose_refinement(kind, autocast, tmp_path: Path) -> None:
    params = params_of({"field.kind": kind, "steps": 60, "optim.batch_rays": 256, "autocast": autocast,
                        "per_image.appearance": "on", "per_image.refine_poses": "on", "field.max_resolution": 256,
                        "checkpoint_every": 30, "optim.lr": 1e-2 if kind != "mlp" else 3e-3, "optim.lr_final": 1e-3})
    model, _ = build_model(params, scene_of("inward360"), world_of_one_camera(), bounds_of(), CUDA, ["a.png"])
    assert model.appearance is not None and model.refinement is not None
    trainer = Trainer(model, one_view_pixels(CUDA), params, tmp_path, CUDA)
    losses = []
    for step in range(60):
        loss, _ = trainer.train_step(step)
        losses.append(loss)
    assert all(np.isfinite(losses))
    assert np.mean(losses[-10:]) < 0.7 * np.mean(losses[:5]), losses
    grads = [p.grad for p in model.coarse.parameters() if p.grad is not None]
    assert grads and all(torch.isfinite(g).all() for g in grads)
    assert model.refinement.tangent.is_cuda and torch.isfinite(model.refinement.tangent).all()


def test_a_model_trained_on_the_gpu_loads_on_the_cpu_and_renders_the_same(tmp_path: Path) -> None:
    params = params_of({"steps": 40, "optim.batch_rays": 256, "checkpoint_every": 20, "field.max_resolution": 128})
    model, _ = build_model(params, scene_of("inward360"), world_of_one_camera(), bounds_of(), CUDA, ["a.png"])
    trainer = Trainer(model, one_view_pixels(CUDA), params, tmp_path, CUDA)
    trainer.run()
    assert trainer.step == 40 and (tmp_path / "checkpoints").exists()
    model.save(tmp_path)
    back = RadianceModel.load(tmp_path, CPU)
    assert back.device.type == "cpu"
    a, b = model.render_rays(view_rays(model), 256), back.render_rays(view_rays(back), 256)
    torch.testing.assert_close(a["rgb"].cpu(), b["rgb"], atol=2e-3, rtol=2e-3)
    again = Trainer(build_model(params, scene_of("inward360"), world_of_one_camera(), bounds_of(), CUDA, ["a.png"])[0],
                    one_view_pixels(CUDA), params, tmp_path, CUDA)
    assert again.resume() == 40  # a GPU checkpoint resumes on the GPU


@pytest.mark.parametrize("kind", ["grid", "hash", "planes"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
def test_grid_fields_have_finite_gradients_at_extreme_inputs_on_the_gpu(kind, dtype) -> None:
    torch.manual_seed(0)
    built = build_model(params_of({"field.kind": kind, "field.max_resolution": 2048 if kind != "grid" else 128}),
                        scene_of("inward360"), world_of_one_camera(), bounds_of(), CPU)[0].coarse
    field = part_class(built.config).from_config(built.config, built.box()).to(CUDA)
    edges = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [1.0 - 1e-7, 0.0, -1.0], [1e30, -1e30, 0.0],
                          [float("inf"), 0.0, 0.0], [0.3, -0.2, 0.999999]])
    x = torch.cat([edges, torch.rand(1024, 3) * 2 - 1]).to(CUDA).requires_grad_(True)
    d = torch.nn.functional.normalize(torch.randn(len(x), 3, device=CUDA), dim=-1)
    with torch.autocast("cuda", dtype=dtype, enabled=dtype != torch.float32):
        rgb, sigma = field(x, d)
    assert torch.isfinite(rgb).all() and torch.isfinite(sigma).all()
    (rgb.float().sum() + sigma.float().sum()).backward()
    assert all(torch.isfinite(p.grad).all() for p in field.parameters() if p.grad is not None)
    assert torch.isfinite(x.grad[:3]).all() and torch.isfinite(x.grad[5:]).all()


@pytest.mark.parametrize("mode,autocast", [("auto", "none"), ("auto", "bf16"), ("graphs", "none")])
def test_the_compiled_step_on_the_gpu_computes_the_eager_loss_and_lowers_it(mode, autocast, tmp_path: Path) -> None:
    """auto compiles on CUDA (kernels); graphs replays them as CUDA graphs. Either trains as the eager step does:
    the first batch's loss alike, finite losses falling, finite gradients."""
    values = {"steps": 40, "optim.batch_rays": 256, "optim.batch_samples": 8192, "field.max_resolution": 256,
              "checkpoint_every": 40, "autocast": autocast}

    def run(choice: str) -> tuple[Trainer, list[float]]:
        torch.manual_seed(0)
        params = params_of({**values, "compile": choice})
        model, _ = build_model(params, scene_of("inward360"), world_of_one_camera(), bounds_of(), CUDA, ["a.png"])
        trainer = Trainer(model, one_view_pixels(CUDA), params, tmp_path / choice, CUDA)
        return trainer, [trainer.train_step(step)[0] for step in range(40)]

    trainer, losses = run(mode)
    assert trainer.static is not None and trainer.static.mode == ("kernels" if mode == "auto" else mode)
    assert trainer.static.compiled is not trainer.static.loss  # compiled, not fallen back to eager
    _, eager = run("off")
    assert losses[0] == pytest.approx(eager[0], rel=2e-2 if autocast == "bf16" else 1e-3)
    assert all(np.isfinite(losses)) and np.mean(losses[-10:]) < 0.7 * np.mean(losses[:5]), losses
    grads = [p.grad for p in trainer.model.coarse.parameters() if p.grad is not None]
    assert grads and all(torch.isfinite(g).all() for g in grads)
