"""ingest -> sfm (pose import) -> undistort -> bounds -> scene on real captures, end to end."""

from __future__ import annotations

import json
import shutil
from itertools import product
from pathlib import Path

import numpy as np
import pytest

from nerfpipe import Pipeline, default_stages
from nerfpipe.geometry.cameras import CameraSet
from tests.helpers import TEMPLE, run_cli, shared

# The lego model's bounding box in the scene frame (the NSVF bounding box of the Blender scene, rounded out).
LEGO_BOX = np.array([[-0.65, -1.16, -0.36], [0.65, 1.16, 1.02]])


def lego_capture(tmp_path: Path, every: int = 10) -> Path:
    """Lego with every ``every``-th train and val frame: the transforms files trimmed to those frames."""
    source = shared("nerf_synthetic_lego_400")
    capture = tmp_path / "lego"
    for split in ("train", "val"):
        doc = json.loads((source / f"transforms_{split}.json").read_text())
        doc["frames"] = doc["frames"][::every]
        (capture / split).mkdir(parents=True)
        for frame in doc["frames"]:
            shutil.copy(source / (frame["file_path"] + ".png"), capture / split)
        (capture / f"transforms_{split}.json").write_text(json.dumps(doc))
    return capture


def result(run_dir: Path, stage: str) -> Path:
    key = json.loads((run_dir / "stages" / stage / "latest.json").read_text())["key"]
    return run_dir / "stages" / stage / key


def test_lego_imports_as_inward_360_with_alpha_and_bounds_that_contain_the_object(tmp_path):
    capture = lego_capture(tmp_path)
    run_dir = tmp_path / "run"
    outcomes = Pipeline(default_stages(), capture, run_dir, overrides={"ingest": {"max_size": "200"}}).run(until="scene")
    assert [o.name for o in outcomes][:2] == ["ingest", "sfm"]
    assert outcomes[1].summary["method"] == "imported transforms"

    scene = json.loads((result(run_dir, "scene") / "scene.json").read_text())
    assert scene["layout"]["value"] == "inward360" and scene["background"]["value"] == "alpha"
    assert scene["lens"]["value"] == "pinhole" and not scene["layout"]["overridden"]

    bounds = json.loads((result(run_dir, "bounds") / "bounds.json").read_text())
    world = CameraSet.load(result(run_dir, "bounds") / "world")
    to_world = np.array(bounds["to_world"])
    corners = np.array([[x, y, z] for x, y, z in product(*LEGO_BOX.T)])
    corners_world = corners @ to_world[:3, :3].T + to_world[:3, 3]
    near_far = {f["name"]: (f["near"], f["far"]) for f in bounds["frames"]}
    assert len(near_far) == 20
    for frame in world.frames:
        w2c = np.linalg.inv(frame.c2w)
        depth = corners_world @ w2c[:3, :3].T[:, 2] + w2c[2, 3]
        near, far = near_far[frame.name]
        assert near <= depth.min() and far >= depth.max(), frame.name
    # the object fits the normalized unit cube
    assert np.all(np.abs(corners_world) <= 1.0 + 1e-6)


def test_status_shows_the_scene_decisions_and_an_override(tmp_path):
    capture = tmp_path / "temple"
    shutil.copytree(TEMPLE, capture)
    run_dir = tmp_path / "run"
    assert run_cli("run", capture, "--out", run_dir, "--set", "ingest.max_size=320", "--until", "scene").returncode == 0
    status = run_cli("status", run_dir)
    assert "scene: layout is inward360: " in status.stdout and "background is " in status.stdout
    overridden = run_cli("run", capture, "--out", run_dir, "--set", "ingest.max_size=320", "--set", "scene.layout=forward", "--until", "scene")
    assert overridden.returncode == 0, overridden.stderr
    scene = json.loads((result(run_dir, "scene") / "scene.json").read_text())
    assert scene["layout"]["value"] == "forward" and scene["layout"]["overridden"]
    assert "inward360" in scene["layout"]["evidence"]  # the data's own answer stays on record


def test_cup_llff_import_keeps_its_near_far(tmp_path):
    """Without triangulated points (sfm.triangulate=false; auto triangulates LLFF poses) the bounds are
    the pose file's own near/far, rescaled with the scene."""
    cup = shared("llff_cup_kwrous")
    run_dir = tmp_path / "run"
    overrides = {"ingest": {"max_size": "100"}, "sfm": {"triangulate": "false"}}
    Pipeline(default_stages(), cup, run_dir, overrides=overrides).run(until="bounds")
    bounds = json.loads((result(run_dir, "bounds") / "bounds.json").read_text())
    assert bounds["method"] == "pose_file" and len(bounds["frames"]) == 77
    poses = np.load(cup / "poses_bounds.npy")
    names = sorted(p.name for p in (cup / "images").iterdir())
    by_name = {f["name"]: f for f in bounds["frames"]}
    for row, name in zip(poses, names):
        frame = by_name[name.replace(".jpg", ".png")]
        # depths scale with the scene; their ratio does not
        assert frame["far"] / frame["near"] == pytest.approx(row[16] / row[15], rel=1e-9)
        assert frame["near"] == pytest.approx(row[15] * bounds["scale"], rel=1e-9)


@pytest.mark.slow
def test_cup_sfm_registers_a_subset_and_calls_it_inward_facing(tmp_path):
    """Acceptance (CI subset): every 3rd photo of the cup (26 of 77, 800x600), poses ignored: at least 95 %
    register, and the scene analysis calls the capture what it is, an inward-facing orbit of the cup (the
    photos circle it over ~190 degrees; they do not all look one way, so it is not forward-facing)."""
    source = shared("llff_cup_kwrous", "images")
    capture = tmp_path / "cup" / "images"
    capture.mkdir(parents=True)
    for name in sorted(p.name for p in source.iterdir())[::3]:
        shutil.copy(source / name, capture)
    run_dir = tmp_path / "run"
    outcomes = Pipeline(default_stages(), capture.parent, run_dir, overrides={"sfm": {"poses": "sfm"}}).run(until="scene")
    sfm = outcomes[1].summary
    assert sfm["total"] == 26 and sfm["registered"] >= 0.95 * 26
    scene = json.loads((result(run_dir, "scene") / "scene.json").read_text())
    assert scene["layout"]["value"] == "inward360", scene["layout"]["evidence"]
    assert scene["background"]["value"] == "none"
