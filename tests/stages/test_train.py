"""The train stage: its parameters and presets, what it writes, resuming a killed training, a run end to end."""

from __future__ import annotations

import re

import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from nerfpipe.artifacts import ViewSplit
from nerfpipe.nerf.policy import build_model
from nerfpipe.pipeline import Pipeline, param_specs
from nerfpipe.pipeline.errors import ParamError
from nerfpipe.pipeline.params import build_params
from nerfpipe.stages import TrainParams, TrainStage, default_stages
from tests.helpers import TEMPLE, interruptible, shared
from tests.nerf.scenes import bounds_of, scene_of, world_of_one_camera

# a training small enough for a test: lego at 32 px, a 2x32 MLP, 16 + 16 samples
TINY = {
    "ingest": {"max_size": 32},
    "train": {"field.kind": "mlp", "steps": 300, "optim.batch_rays": 256, "sampler.n_coarse": 16, "sampler.n_fine": 16,
              "field.depth": 2, "field.width": 32, "field.view_width": 16, "checkpoint_every": 100, "eval_stride": 25,
              "optim.lr": 5e-3, "keep_checkpoints": 0,
              "optim.density_noise": 0.3},  # noise on, so resuming is shown to redraw the same noise too
}


def tiny_cli_args() -> list[str]:
    return [f"--set={stage}.{k}={v}" for stage, values in TINY.items() for k, v in values.items()]


def test_paper_preset_has_the_papers_values() -> None:
    params = build_params("train", TrainParams, TrainStage.presets, "paper", {})
    f, s, o = params.field, params.sampler, params.optim
    assert (params.steps, o.batch_rays, s.n_coarse, s.n_fine, s.kind) == (200_000, 4096, 64, 128, "hierarchical")
    assert (f.kind, f.depth, f.width, f.view_width, f.skip_after) == ("mlp", 8, 256, 128, 5)
    assert (f.pos_freqs, f.dir_freqs, o.lr, o.lr_final, o.adam_eps) == (10, 4, 5e-4, 5e-5, 1e-7)
    assert f.fine_network and f.density_activation == "relu" and not f.include_input
    model, _ = build_model(params, scene_of("inward360"), world_of_one_camera(), bounds_of(), torch.device("cpu"))
    linear = [m for m in model.coarse.modules() if isinstance(m, torch.nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linear] == (
        [(60, 256)] + [(256, 256)] * 4 + [(256 + 60, 256)] + [(256, 256)] * 2 + [(256, 1), (256, 256), (256 + 24, 128), (128, 3)]
    )
    assert model.fine is not None and model.sampler.config.n_fine == 128


def test_bad_train_values_are_parameter_errors() -> None:
    for overrides in ({"density_noise": "loud"}, {"steps": "0", "seconds": "0"}, {"steps": "-1"}, {"lr_final": "0"}, {"skip_after": "4", "depth": "4"},
                      {"early_stop": "1"}, {"grid_min_resolution": "128", "grid_max_resolution": "64"},
                      {"occupancy": "maybe"}, {"field": "voxels"}, {"adam_beta2": "1"}, {"march_steps": "0"}):
        with pytest.raises(ParamError):
            build_params("train", TrainParams, TrainStage.presets, None, overrides)
    assert {"autocast", "field.levels", "sampler.steps", "optim.lr"} <= {spec.name for spec in param_specs(TrainParams)}


def lego_pipeline(run_dir: Path, extra: dict | None = None, **train: object) -> Pipeline:
    overrides = {"ingest": TINY["ingest"], "train": {**TINY["train"], **train}}
    return Pipeline(default_stages(), shared("nerf_synthetic_lego_400"), run_dir, None, overrides, extra=extra)


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_training_writes_model_metrics_and_held_out_renders(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    import urllib.error
    import urllib.request

    # watched (`nerfpipe run --view`): the web viewer answers while the field trains, and is gone afterwards
    from nerfpipe.nerf.train.trainer import Trainer

    port, pages = free_port(), []

    def fetch() -> int | str:
        try:
            with urllib.request.urlopen(f"http://localhost:{port}", timeout=30) as page:
                return page.status
        except urllib.error.HTTPError as refused:  # it answers, but not without the printed URL's token
            return refused.code
        except OSError:
            return "closed"

    step = Trainer.train_step

    def looking(self, at: int):  # mid-training, ask the viewer for its page
        if at == 150:
            pages.append(fetch())
        return step(self, at)

    with caplog.at_level("INFO", logger="nerfpipe"), pytest.MonkeyPatch.context() as patch:
        patch.setattr(Trainer, "train_step", looking)
        outcome = lego_pipeline(tmp_path / "run", extra={"watch_port": port}).run(until="train")[-1]
    assert pages == [403] and fetch() == "closed"  # served during training, and only then
    assert f"train: watch the field learn at http://localhost:{port}" in caplog.text
    out = outcome.path
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == 300 and metrics["heldout_rule"] == "the capture's val split"
    assert [v["name"] for v in metrics["views"]] == ["val/r_0.png", "val/r_25.png", "val/r_50.png", "val/r_75.png"]
    views = ViewSplit.load(out / "views.json")
    assert views.heldout == [v["name"] for v in metrics["views"]] and len(views.train) == 100
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
    # 300 steps of 256 rays (hierarchical sampling: a fixed batch), over 100 training photos of 32 x 32 pixels
    assert metrics["rays"] == 300 * 256 and metrics["rays_per_pixel"] == 0.75
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


KILL_AFTER_STEP_100 = """
import os, signal, sys

from nerfpipe.nerf.train import trainer

save = trainer.save_checkpoint


def save_then_die(folder, step, *args, **kwargs):
    save(folder, step, *args, **kwargs)
    if step == 100:
        os.kill(os.getpid(), signal.SIGKILL)


trainer.save_checkpoint = save_then_die
sys.argv = ["nerfpipe", *sys.argv[1:]]
from nerfpipe.cli.main import main

main()
"""


def test_resumed_training_matches_an_uninterrupted_one(tmp_path: Path) -> None:
    """SIGKILL mid-training; the rerun resumes from the last checkpoint and ends at the same weights."""
    lego = shared("nerf_synthetic_lego_400")
    run_dir = tmp_path / "killed"
    cmd = [sys.executable, "-m", "nerfpipe", "run", str(lego), "--out", str(run_dir), "--until", "train", *tiny_cli_args()]
    # the run kills itself right after writing the checkpoint of step 100: no race with a watcher's clock
    killed = subprocess.run([sys.executable, "-c", KILL_AFTER_STEP_100, *cmd[3:]], capture_output=True, text=True,
                            timeout=900)
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-2000:]
    assert not (run_dir / "stages" / "train").exists() or not list((run_dir / "stages" / "train").glob("*/manifest.json"))
    written = sorted(run_dir.glob(".work/train-*/checkpoints/step_*.pt"))
    last = max(int(p.stem.split("_")[1]) for p in written)
    assert last == 100

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
             "--set=export_mesh.watertight=true",
             "--set=export_points.acc_threshold=0.5", "--set=render.frames=4", "--set=render.short_side=0"]
    port = free_port()
    result = run_cli("run", TEMPLE, "--out", run_dir, *args, "--view", "--port", str(port), timeout=1200)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "train: held-out PSNR" in result.stderr
    assert f"train: watch the field learn at http://localhost:{port}" in result.stderr
    assert "train: the training viewer stopped" in result.stderr
    metrics = json.loads(next((run_dir / "stages" / "train").glob("*/metrics.json")).read_text())
    # no split in the Middlebury capture: every 8th of the 16 photos is held out
    assert metrics["heldout_rule"] == "every 8th image" and [v["name"] for v in metrics["views"]] == [
        "templeSR0001.png", "templeSR0009.png"]
    assert metrics["train_images"] == 14 and all(np.isfinite(v["psnr"]) for v in metrics["views"])
    assert any("composited onto (0.00, 0.00, 0.00)" in d for d in metrics["decisions"])  # the black backdrop
    # no EXIF, and at 80 px too few triangulated points (18) to measure the exposure by: constant, no per-image
    # exposure (the full-size run measures 0.11 stops over 1417 points: README); nor points to vouch for the
    # calibrated poses, so they are refined
    exposure = json.loads(next((run_dir / "stages" / "scene").glob("*/scene.json")).read_text())["exposure_varies"]
    assert exposure["value"] is False and exposure["measured"]["source"] == "none", exposure["evidence"]
    assert metrics["appearance"] is None and metrics["pose_refinement"]["cameras"] == 14
    assert any("no sparse points to check the camera poses by" in d for d in metrics["decisions"])
    assert (next((run_dir / "stages" / "train").glob("*/cameras")) / "cameras.json").is_file()
    status = run_cli("status", run_dir)
    assert "train: 300 steps in" in status.stdout
    # scored at the size the evaluation budget allows (80x60 itself, unless the machine renders very slowly)
    w, h = metrics["eval_size"]
    assert f"held-out views (every 8th image) at {w}x{h}: PSNR" in " ".join(status.stdout.split())
    assert metrics["eval_scale"] == pytest.approx(w / 80, abs=0.02) and [v["size"] for v in metrics["views"]] == [[w, h]] * 2
    check_exports_report_and_view(run_dir, result.stdout)
    check_poisson_mesh(run_dir, args)


def check_poisson_mesh(run_dir: Path, args: list[str]) -> None:
    """The temple is an object on a black backdrop, so `auto` meshed its density; asked for, the mesh is a
    Poisson surface of the agreed points (a scene's default), textured and scored the same way."""
    from nerfpipe.export.mesh import read_mesh
    from tests.helpers import run_cli

    def summary() -> dict:
        latest = json.loads((run_dir / "stages" / "export_mesh" / "latest.json").read_text())["key"]
        return json.loads((run_dir / "stages" / "export_mesh" / latest / "manifest.json").read_text())["summary"]

    assert summary()["method"] == "marching_cubes"
    rerun = run_cli("run", TEMPLE, "--out", run_dir, *args, "--set=export_mesh.method=poisson", "--until=export_mesh")
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert "export_mesh: a Poisson surface of" in rerun.stderr
    poisson = summary()
    assert poisson["method"] == "poisson" and poisson["faces"] > 0 and poisson["heldout"]["views"] == 2
    assert read_mesh(run_dir / "exports" / "mesh.glb").faces > 0


def check_exports_report_and_view(run_dir: Path, run_stdout: str) -> None:
    """What `nerfpipe run` exports by default, the report it writes, and `nerfpipe view` without a display."""
    import re

    import cv2

    from nerfpipe import Pipeline, default_stages
    from nerfpipe.export.depth import DepthIndex
    from nerfpipe.export.mesh import read_mesh
    from nerfpipe.export.points import read_ply
    from tests.helpers import run_cli, video_info

    def result_of(stage: str) -> Path:
        return run_dir / "stages" / stage / json.loads((run_dir / "stages" / stage / "latest.json").read_text())["key"]

    depth = result_of("export_depth")
    index = DepthIndex.load(depth / "depth.json")
    # the free-space check's estimates, low rather than high: export_depth counts its float arrays (0.88 of the
    # full-size demo's output; at this run's 20x15 views the JSON sidecars weigh as much), ingest a share of
    # the pixels that PNG keeps of a full-size photo (less than of an 80 px one)
    pipe = Pipeline.from_run_dir(default_stages(), run_dir)
    for stage, low in (("export_depth", 0.4), ("ingest", 0.1)):
        planned = pipe.plan()[stage]
        needed = planned.stage.expected_bytes(pipe.stage_inputs(stage), planned.params)
        written = sum(meta["size"] for meta in pipe.result(stage).manifest["outputs"].values())
        assert low * written < needed <= written, (stage, needed, written)
    assert [v.role for v in index.views].count("heldout") == 2 and len(index.views) == 16
    view = index.views[0]
    assert np.load(depth / "depth" / f"{view.stem}.depth.npy").shape == (view.height, view.width)
    assert cv2.imread(str(depth / "depth" / f"{view.stem}.depth.png"), cv2.IMREAD_UNCHANGED).dtype == np.uint16
    bounds = json.loads(next((run_dir / "stages" / "bounds").glob("*/bounds.json")).read_text())
    assert index.to_sfm == bounds["to_sfm"]
    assert len(read_ply(result_of("export_points") / "points.ply").xyz) > 0
    mesh_dir = result_of("export_mesh")
    meshes = [read_mesh(mesh_dir / f"mesh{suffix}") for suffix in (".ply", ".obj")]
    assert meshes[0].faces > 0 and meshes[1].faces == meshes[0].faces
    # the GLB: the mesh simplified and textured from the training photos, scored on the held-out views
    glb = read_mesh(mesh_dir / "mesh.glb")
    assert 0 < glb.faces <= min(meshes[0].faces, 50_000)
    summary = json.loads((mesh_dir / "manifest.json").read_text())["summary"]
    assert summary["texture"]["photos"] == 14 and summary["heldout"]["views"] == 2
    closed = summary["watertight"]  # the printable remesh, as trimesh and Open3D judge it
    assert closed["watertight"] and closed["edge_manifold"] and (mesh_dir / "mesh_watertight.glb").is_file()
    render = result_of("render")
    assert (render / "render.mp4").stat().st_size > 0 and (render / "depth.mp4").stat().st_size > 0
    exports = run_dir / "exports"  # what a user takes away, under stable names
    listed = re.search(rf"exports: {re.escape(str(exports))} \((.*?)\)", run_stdout.replace("\n", "")).group(1).split(", ")
    assert listed[:9] == ["mesh.glb", "mesh.ply", "mesh.obj", "points.ply", "render.mp4", "depth.mp4", "depth",
                          "camera_path.json", "camera_path.nerfstudio.json"]
    assert {"mesh_watertight.glb", "mesh_watertight.ply", "transforms.json", "images", "sparse", "masks"} <= set(listed)
    assert sorted(listed) == sorted(p.name for p in exports.iterdir())  # what it says is what is there
    transforms = json.loads((exports / "transforms.json").read_text())
    assert len(transforms["frames"]) == 16 and all((exports / f["file_path"]).is_file() for f in transforms["frames"])
    assert (exports / "render.mp4").read_bytes() == (render / "render.mp4").read_bytes()

    page = run_dir / "report" / "index.html"
    assert f"report: {page}" in run_stdout.replace("\n", "")
    text = page.read_text()
    sources = re.findall(r'<img src="([^"]+)"', text)
    assert len(sources) > 20 and all((page.parent / src).is_file() for src in sources)
    for section in ("Capture", "Scene decisions", "Training", "Depth", "Mesh and point cloud", "Novel views", "Time per stage"):
        assert f"<h2>{section}</h2>" in text
    assert "img/mesh.png" in sources and "img/points.png" in sources and "img/training.png" in sources
    # the novel views play in the page: H.264 videos beside it (scripts/check_report_videos.py plays them in Chromium)
    for name in ("render.mp4", "depth.mp4"):
        assert f'<video src="{name}"' in text and video_info(page.parent / name).codec == "h264"

    check_web_viewer(run_dir)

    env_free = run_cli("view", run_dir, "mesh")
    assert env_free.returncode == 0, env_free.stderr
    shot = run_dir / "view_mesh.png"
    assert f"wrote a screenshot to {shot}" in env_free.stdout.replace("\n", "")
    image = cv2.imread(str(shot))
    assert image is not None and (image < 250).any()  # something drawn on the white background
    wrong = run_cli("view", run_dir, "meshes")
    assert wrong.returncode == 2 and "did you mean mesh?" in wrong.stderr and "Traceback" not in wrong.stderr


# the phone capture that used to collapse: 71 portrait frames of a can on a tiled floor, walls behind
BEER_SMALL = {"ingest": {"max_size": 160}, "train": {"steps": 200, "eval_stride": 4, "checkpoint_every": 1000}}


def train_beer(run_dir: Path, **train: str) -> dict:
    overrides = {**BEER_SMALL, "train": {**BEER_SMALL["train"], **train}}
    pipe = Pipeline(default_stages(), shared("colmap_beer_yhuoyuh"), run_dir, overrides=overrides)
    pipe.run(until="train")
    return json.loads((pipe.result("train").path / "metrics.json").read_text())


@pytest.mark.slow
def test_a_phone_capture_with_a_room_behind_trains_in_contracted_space_and_a_clipped_box_is_caught(tmp_path: Path) -> None:
    metrics = train_beer(tmp_path / "beer")
    guard = metrics["stall_guard"]
    assert any("contracted into a shell" in line for line in metrics["decisions"])
    assert metrics["field"] == "grid" and not guard["stalled"] and guard["restarted_at"] is None
    # a flat render in the mean colour scores 18.5 dB on these bright frames; measured: 24.0 dB after 250 steps
    assert guard["batch_psnr_ema"] > guard["mean_colour_psnr"] + 4.0
    assert metrics["psnr"] > guard["mean_colour_psnr"] + 2.0
    # the old ray space, rays clipped to the scene box: half of them miss it and render black; the guard says so
    clipped = train_beer(tmp_path / "beer", steps="220", **{"space.contract": "off"})["stall_guard"]
    assert clipped["restarted_at"] == 200 and clipped["stalled"]  # checked at step 200, restarted, still there at 220
    assert clipped["batch_psnr_ema"] < clipped["mean_colour_psnr"] + 1.0


def check_web_viewer(run_dir: Path) -> None:
    """`nerfpipe view RUN --web`: the page is served, its scene holds the mesh, the point cloud and one frustum
    (with its photo) per camera, the field renders from a camera, and Ctrl-C stops it cleanly."""
    import signal
    import subprocess
    import sys
    import urllib.request

    import viser

    from nerfpipe import Pipeline, default_stages
    from nerfpipe.export.web import render_view, serve, web_scene

    pipe = Pipeline.from_run_dir(default_stages(), run_dir)
    path = {stage: pipe.result(stage).path for stage in ("ingest", "bounds", "train", "export_mesh", "export_points")}
    scene = web_scene(path["train"], path["train"] / "cameras", path["ingest"] / "images", path["bounds"] / "bounds.json",
                      path["export_mesh"] / "mesh.ply", path["export_points"] / "points.ply")
    viewer = serve(scene, port=free_port())
    try:
        opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor())  # the token becomes a cookie
        page = opener.open(viewer.url, timeout=10).read().decode()
        assert "<html" in page.lower()
        assert isinstance(viewer.mesh, viser.GlbHandle) and isinstance(viewer.points, viser.PointCloudHandle)
        assert len(viewer.frusta) == len(scene.frames) == 16
        assert all(isinstance(f, viser.CameraFrustumHandle) for f in viewer.frusta)
        assert all(frame.photo is not None for frame in scene.frames)
    finally:
        viewer.stop()
    first = scene.frames[0]
    image = render_view(scene, first.c2w, first.fov, first.aspect, 64)
    assert image.shape == (48, 64, 3) and image.dtype == np.uint8 and image.max() > 50  # the temple, lit

    port = free_port()
    process = subprocess.Popen([sys.executable, "-m", "nerfpipe", "view", str(run_dir), "--web", "--port", str(port)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=interruptible)
    try:
        line = ""
        while "web viewer:" not in line:
            line = process.stdout.readline()
            assert line or process.poll() is None, process.stderr.read()
        url = re.search(rf"http://localhost:{port}/\?token=[\w-]+", line).group(0)
        assert f"web viewer: {url} (16 cameras with their photos, a mesh of" in line
        opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor())
        assert opener.open(url, timeout=10).status == 200
    finally:
        process.send_signal(signal.SIGINT)
        try:
            out, err = process.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()  # leave no viewer behind
            raise
    assert process.returncode == 0 and "web viewer stopped" in out and "Traceback" not in err, err


@pytest.mark.parametrize("stage_name", ["train", "export_depth", "render"])
def test_a_stage_that_renders_takes_the_gpu_preset_on_a_cuda_device_unless_told_otherwise(stage_name, tmp_path,
                                                                                           monkeypatch) -> None:
    import nerfpipe.nerf.presets as presets

    stage = next(s for s in default_stages() if s.name == stage_name)
    monkeypatch.setattr(presets, "NVIDIA_DRIVER", tmp_path / "no-driver")
    assert stage.machine_preset({}) is None  # no driver: torch is not asked
    monkeypatch.setattr(presets, "NVIDIA_DRIVER", tmp_path)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert stage.machine_preset({}) is None  # a driver, but torch sees no device (a CPU build)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda *a: "NVIDIA H200")
    name, why = stage.machine_preset({})
    assert name == "gpu" and "sized for the CUDA device NVIDIA H200" in why and "gpu" in stage.presets
    assert stage.machine_preset({"device": "cpu"}) is None
    params = build_params(stage_name, stage.Params, stage.presets, name, {})
    if stage_name == "train":
        assert stage.machine_preset({"field.kind": "grid"}) is None  # a field of the user's own
        assert (params.field.kind, params.field.max_resolution, params.field.log2_table) == ("hash", 2048, 19)
        assert params.optim.batch_samples == 2**18 and params.compile == "auto" and params.eval_scale == "1"
    else:  # full size
        assert params.scale == 1.0
