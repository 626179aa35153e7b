"""The train stage: held-out splits, what it writes, resuming a killed training, and the paper's switches."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.helpers import TEMPLE, shared
from nerfpipe.geometry.cameras import Camera, CameraSet, Frame
from nerfpipe.nerf.field import NerfField
from nerfpipe.pipeline import Pipeline, param_specs
from nerfpipe.pipeline.errors import ParamError
from nerfpipe.pipeline.params import build_params
from nerfpipe.stages import TrainParams, TrainStage, default_stages
from nerfpipe.stages.train import build_model, split_views

# a training small enough for a test: lego at 32 px, a 2x32 MLP, 16 + 16 samples
TINY = {
    "ingest": {"max_size": 32},
    "train": {"field": "mlp", "steps": 300, "batch_rays": 256, "n_coarse": 16, "n_fine": 16, "depth": 2, "width": 32, "view_width": 16,
              "checkpoint_every": 100, "eval_stride": 25, "lr": 5e-3, "keep_checkpoints": 0,
              "density_noise": 0.3},  # noise on, so resuming is shown to redraw the same noise too
}


def tiny_cli_args() -> list[str]:
    return [f"--set={stage}.{k}={v}" for stage, values in TINY.items() for k, v in values.items()]


def world_of(splits: list[str | None]) -> CameraSet:
    frames = [Frame(f"img{i:02d}.png", 1, np.eye(4), s) for i, s in enumerate(splits)]
    return CameraSet({}, frames)


def test_held_out_views_follow_the_split_else_every_eighth() -> None:
    with_val = world_of(["train"] * 6 + ["val"] * 4)
    views = split_views(with_val, TrainParams())
    assert [f.name for f in views.heldout] == [f"img{i:02d}.png" for i in range(6, 10)]
    assert len(views.train) == 6 and views.rule == "the capture's val split"

    test_beats_val = world_of(["train"] * 4 + ["val"] * 2 + ["test"] * 3)
    assert [f.split for f in split_views(test_beats_val, TrainParams()).heldout] == ["test"] * 3

    plain = world_of([None] * 17)
    views = split_views(plain, TrainParams())
    assert [f.name for f in views.heldout] == ["img00.png", "img08.png", "img16.png"]
    assert len(views.train) == 14 and not {f.name for f in views.train} & {f.name for f in views.heldout}

    subset = split_views(plain, TrainParams(train_images=4, eval_stride=2))
    assert [f.name for f in subset.train] == ["img01.png", "img05.png", "img11.png", "img15.png"]  # train[round(linspace(0, 13, 4))]
    assert [f.name for f in subset.heldout] == ["img00.png", "img16.png"]


def test_paper_preset_has_the_papers_values() -> None:
    params = build_params("train", TrainParams, TrainStage.presets, "paper", {})
    assert (params.steps, params.batch_rays, params.n_coarse, params.n_fine) == (200_000, 4096, 64, 128)
    assert (params.depth, params.width, params.view_width, params.skip_after) == (8, 256, 128, 5)
    assert (params.pos_freqs, params.dir_freqs, params.lr, params.lr_final, params.adam_eps) == (10, 4, 5e-4, 5e-5, 1e-7)
    assert params.fine_network and params.density_activation == "relu" and not params.include_input
    scene = scene_json("inward360")
    model, _ = build_model(params, scene, world_of([None]), {"scene_box": [[-1] * 3, [1] * 3], "to_sfm": np.eye(4).tolist(),
                                                               "frames": []}, torch.device("cpu"))
    linear = [m for m in model.coarse.modules() if isinstance(m, torch.nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linear] == (
        [(60, 256)] + [(256, 256)] * 4 + [(256 + 60, 256)] + [(256, 256)] * 2 + [(256, 1), (256, 256), (256 + 24, 128), (128, 3)]
    )
    assert model.fine is not None and model.sampling.n_fine == 128


def scene_json(layout: str, background: str = "none", color=None, photometric: str = "srgb") -> dict:
    return {"layout": {"value": layout}, "background": {"value": background}, "background_color": {"value": color},
            "photometric": {"value": photometric}}


@pytest.mark.parametrize(
    "overrides, first_in, view_in, n_fine, fine",
    [
        # the view layer sees the 128-d feature and gamma(d) (with d itself, include_input)
        ({}, 3 + 60, 128 + 3 + 24, 64, False),
        ({"positional_encoding": False}, 3, 128 + 3, 64, False),  # Table 2 row 2: raw x and d
        ({"view_dependence": False}, 63, 128, 64, False),  # row 3: colour from x alone
        ({"hierarchical": False, "fine_network": True}, 63, 155, 0, False),  # row 4: N_c samples, one network
        ({"pos_freqs": 5, "dir_freqs": 2}, 3 + 30, 128 + 3 + 12, 64, False),  # rows 7-8: L
        ({"fine_network": True}, 63, 155, 64, True),
    ],
)
def test_ablation_switches_build_the_tables_models(overrides, first_in, view_in, n_fine, fine) -> None:
    params = TrainParams(field="mlp", **overrides)
    bounds = {"scene_box": [[-1] * 3, [1] * 3], "to_sfm": np.eye(4).tolist(), "frames": []}
    model, _ = build_model(params, scene_json("inward360"), world_of([None]), bounds, torch.device("cpu"))
    assert model.coarse.trunk[0].in_features == first_in
    assert model.coarse.view.in_features == view_in
    assert model.sampling.n_fine == n_fine
    assert (model.fine is not None) == fine


def test_scene_decisions_choose_the_ray_space_and_background() -> None:
    bounds = {"scene_box": [[-1] * 3, [1] * 3], "to_sfm": np.eye(4).tolist(), "frames": [{"near": 2.0, "far": 9.0}]}
    world = CameraSet({1: Camera.pinhole(50, 50, 20, 15, 40, 30)},
                      [Frame("a.png", 1, np.eye(4))])
    cpu = torch.device("cpu")
    inward, said = build_model(TrainParams(), scene_json("inward360", "alpha", [1, 1, 1]), world, bounds, cpu)
    assert inward.ray_space.box == ((-1, -1, -1), (1, 1, 1)) and not inward.ray_space.ndc
    assert inward.background == (1.0, 1.0, 1.0) and not inward.sampling.lindisp
    assert any("clipped to the scene box" in line for line in said)
    forward, said = build_model(TrainParams(field="mlp"), scene_json("forward"), world, bounds, cpu)
    assert forward.ray_space.ndc and forward.ray_space.ndc_near == pytest.approx(0.75 * 2.0)
    assert forward.ray_space.ndc_focal == 50 and forward.ray_space.ndc_size == (40, 30) and forward.background is None
    assert any("noise of std 1" in line for line in said)  # the authors' regularizer for real forward scenes
    assert forward.occupancy is None  # the paper's sampler unless asked
    unbounded, _ = build_model(TrainParams(field="mlp"), scene_json("unbounded360"), world, bounds, cpu)
    assert unbounded.sampling.lindisp and unbounded.ray_space.box is None


def test_the_default_grid_field_marches_the_box_or_the_ndc_frustum() -> None:
    from nerfpipe.nerf.grid_field import GridField

    bounds = {"scene_box": [[-1] * 3, [1] * 3], "to_sfm": np.eye(4).tolist(), "frames": [{"near": 2.0, "far": 9.0}]}
    world = CameraSet({1: Camera.pinhole(50, 50, 20, 15, 40, 30)}, [Frame("a.png", 1, np.eye(4))])
    cpu = torch.device("cpu")
    inward, said = build_model(TrainParams(), scene_json("inward360", "alpha", [1, 1, 1]), world, bounds, cpu)
    assert isinstance(inward.coarse, GridField) and inward.fine is None
    assert inward.occupancy is not None and inward.occupancy.resolution == 64
    assert inward.occupancy.lo.tolist() == [-1] * 3 and inward.coarse.hi.tolist() == [1] * 3
    assert any("empty-space skipping" in line for line in said)
    forward, said = build_model(TrainParams(), scene_json("forward"), world, bounds, cpu)
    # NDC's [-1, 1]^2 x [-1, 1 - 2 near / far]: the frustum out to the farthest bound
    z_max = 1 - 2 * (0.75 * 2.0) / 9.0
    assert forward.occupancy.hi.tolist() == pytest.approx([1, 1, z_max]) and forward.occupancy.lo.tolist() == [-1] * 3
    assert not any("noise" in line for line in said)  # a regularizer of the MLP's raw density only
    unbounded, said = build_model(TrainParams(), scene_json("unbounded360"), world, bounds, cpu)
    assert isinstance(unbounded.coarse, NerfField) and unbounded.occupancy is None
    assert any("needs a bounded box" in line for line in said)
    mlp_grid, _ = build_model(TrainParams(field="mlp", occupancy="true"), scene_json("inward360"), world, bounds, cpu)
    assert isinstance(mlp_grid.coarse, NerfField) and mlp_grid.occupancy is not None


def test_bad_train_values_are_parameter_errors() -> None:
    for overrides in ({"density_noise": "loud"}, {"steps": "0"}, {"lr_final": "1"}, {"skip_after": "4", "depth": "4"},
                      {"early_stop": "1"}, {"grid_min_resolution": "128", "grid_max_resolution": "64"},
                      {"occupancy": "maybe"}, {"field": "hash"}, {"adam_beta2": "1"}, {"march_steps": "0"}):
        with pytest.raises(ParamError):
            build_params("train", TrainParams, TrainStage.presets, None, overrides)
    assert any(spec.name == "autocast" for spec in param_specs(TrainParams))


def lego_pipeline(run_dir: Path, **train: object) -> Pipeline:
    overrides = {"ingest": TINY["ingest"], "train": {**TINY["train"], **train}}
    return Pipeline(default_stages(), shared("nerf_synthetic_lego_400"), run_dir, None, overrides)


@pytest.mark.slow
def test_training_writes_model_metrics_and_held_out_renders(tmp_path: Path) -> None:
    outcome = lego_pipeline(tmp_path / "run").run(until="train")[-1]
    out = outcome.path
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == 300 and metrics["heldout_rule"] == "the capture's val split"
    assert [v["name"] for v in metrics["views"]] == ["val/r_0.png", "val/r_25.png", "val/r_50.png", "val/r_75.png"]
    for view in metrics["views"]:
        stem = view["name"][:-4].replace("/", "__")
        assert (out / "eval" / f"{stem}.render.png").is_file() and (out / "eval" / f"{stem}.gt.png").is_file()
    # clearly better than rendering the white background alone
    import cv2

    white = np.mean([
        -10 * np.log10(np.mean((cv2.imread(str(p))[..., ::-1] / 255.0 - 1.0) ** 2)) for p in (out / "eval").glob("*.gt.png")
    ])
    assert metrics["psnr"] > white + 3.0, (metrics["psnr"], white)
    assert 0.0 < metrics["ssim"] <= 1.0
    log = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == list(range(25, 301, 25))
    assert all(r["wall"] > 0 and np.isfinite(r["loss"]) for r in log)
    assert [r["wall"] for r in log] == sorted(r["wall"] for r in log)
    # checkpoints and the model load with weights_only=True, and the model renders
    for path in sorted((out / "checkpoints").glob("*.pt")):
        state = torch.load(path, weights_only=True)
        assert state["step"] in (100, 200, 300)
    assert torch.load(out / "model.pt", weights_only=True)["coarse"]
    from nerfpipe.nerf.model import RadianceModel

    model = RadianceModel.load(out)
    assert model.background == (1.0, 1.0, 1.0) and model.ray_space.box is not None


def test_resumed_training_matches_an_uninterrupted_one(tmp_path: Path) -> None:
    """SIGKILL mid-training; the rerun resumes from the last checkpoint and ends at the same weights."""
    lego = shared("nerf_synthetic_lego_400")
    run_dir = tmp_path / "killed"
    cmd = [sys.executable, "-m", "nerfpipe", "run", str(lego), "--out", str(run_dir), "--until", "train", *tiny_cli_args()]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    try:
        while time.time() < deadline and proc.poll() is None:
            if list(run_dir.glob(".work/train-*/checkpoints/step_0000100.pt")):
                break
            time.sleep(0.05)
        assert proc.poll() is None, "training ended before it could be killed: " + proc.stderr.read().decode()[-2000:]
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert not (run_dir / "stages" / "train").exists() or not list((run_dir / "stages" / "train").glob("*/manifest.json"))
    written = sorted(run_dir.glob(".work/train-*/checkpoints/step_*.pt"))
    last = max(int(p.stem.split("_")[1]) for p in written)
    assert last in (100, 200)

    resumed = lego_pipeline(run_dir).run(until="train")[-1]
    assert resumed.action == "ran" and resumed.summary["resumed_from"] == last
    assert resumed.summary["steps"] == 300
    steps = [json.loads(line)["step"] for line in (resumed.path / "metrics.jsonl").read_text().splitlines()]
    assert steps == list(range(25, 301, 25))  # nothing logged twice, nothing missing
    assert not list(run_dir.glob(".work/train-*"))

    straight = lego_pipeline(tmp_path / "straight").run(until="train")[-1]
    assert straight.summary["resumed_from"] is None
    a = torch.load(resumed.path / "model.pt", weights_only=True)["coarse"]
    b = torch.load(straight.path / "model.pt", weights_only=True)["coarse"]
    assert a.keys() == b.keys()
    for name in a:
        torch.testing.assert_close(a[name], b[name], rtol=0, atol=1e-6, msg=name)


@pytest.mark.slow
def test_nerfpipe_run_on_the_bundled_capture_trains_evaluates_and_exports(tmp_path: Path) -> None:
    from tests.helpers import run_cli

    run_dir = tmp_path / "temple"
    args = [a.replace("ingest.max_size=32", "ingest.max_size=80").replace("eval_stride=25", "eval_stride=1")
            for a in tiny_cli_args()]
    # exports sized for a tiny field: its densities stay low, so the mesh threshold and opacity cut are too
    args += ["--set=export_mesh.resolution=64", "--set=export_mesh.density_threshold=2",
             "--set=export_points.acc_threshold=0.5", "--set=render.frames=4"]
    result = run_cli("run", TEMPLE, "--out", run_dir, *args, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "train: held-out PSNR" in result.stderr
    metrics = json.loads(next((run_dir / "stages" / "train").glob("*/metrics.json")).read_text())
    # no split in the Middlebury capture: every 8th of the 16 photos is held out
    assert metrics["heldout_rule"] == "every 8th image" and [v["name"] for v in metrics["views"]] == [
        "templeSR0001.png", "templeSR0009.png"]
    assert metrics["train_images"] == 14 and all(np.isfinite(v["psnr"]) for v in metrics["views"])
    assert any("composited onto (0.00, 0.00, 0.00)" in d for d in metrics["decisions"])  # the black backdrop
    status = run_cli("status", run_dir)
    assert "train: 300 steps in" in status.stdout and "held-out views (every 8th image): PSNR" in status.stdout
    check_exports_report_and_view(run_dir, result.stdout)


def check_exports_report_and_view(run_dir: Path, run_stdout: str) -> None:
    """What `nerfpipe run` exports by default, the report it writes, and `nerfpipe view` without a display."""
    import re

    import cv2

    from tests.helpers import run_cli
    from nerfpipe.export.depth import DepthIndex
    from nerfpipe.export.mesh import read_mesh
    from nerfpipe.export.points import read_ply

    def result_of(stage: str) -> Path:
        return run_dir / "stages" / stage / json.loads((run_dir / "stages" / stage / "latest.json").read_text())["key"]

    depth = result_of("export_depth")
    index = DepthIndex.load(depth / "depth.json")
    assert [v.role for v in index.views].count("heldout") == 2 and len(index.views) == 16
    view = index.views[0]
    assert np.load(depth / "depth" / f"{view.stem}.depth.npy").shape == (view.height, view.width)
    assert cv2.imread(str(depth / "depth" / f"{view.stem}.depth.png"), cv2.IMREAD_UNCHANGED).dtype == np.uint16
    bounds = json.loads(next((run_dir / "stages" / "bounds").glob("*/bounds.json")).read_text())
    assert index.to_sfm == bounds["to_sfm"]
    assert len(read_ply(result_of("export_points") / "points.ply").xyz) > 0
    mesh_dir = result_of("export_mesh")
    meshes = [read_mesh(mesh_dir / f"mesh{suffix}") for suffix in (".ply", ".obj", ".glb")]
    assert meshes[0].faces > 0 and all(m.faces == meshes[0].faces for m in meshes)
    render = result_of("render")
    assert (render / "render.mp4").stat().st_size > 0 and (render / "depth.mp4").stat().st_size > 0

    page = run_dir / "report" / "index.html"
    assert f"report: {page}" in run_stdout.replace("\n", "")
    text = page.read_text()
    sources = re.findall(r'<img src="([^"]+)"', text)
    assert len(sources) > 20 and all((page.parent / src).is_file() for src in sources)
    for section in ("Capture", "Scene decisions", "Training", "Depth", "Mesh and point cloud", "Novel views", "Time per stage"):
        assert f"<h2>{section}</h2>" in text
    assert "img/mesh.png" in sources and "img/points.png" in sources and "img/training.png" in sources

    env_free = run_cli("view", run_dir, "mesh")
    assert env_free.returncode == 0, env_free.stderr
    shot = run_dir / "view_mesh.png"
    assert f"wrote a screenshot to {shot}" in env_free.stdout.replace("\n", "")
    image = cv2.imread(str(shot))
    assert image is not None and (image < 250).any()  # something drawn on the white background
    wrong = run_cli("view", run_dir, "meshes")
    assert wrong.returncode == 2 and "did you mean mesh?" in wrong.stderr and "Traceback" not in wrong.stderr
