"""The bounds stage: the normalized world it writes, its near/far bounds, and lego's rig-only bounds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nerfpipe import Pipeline
from nerfpipe.geometry.cameras import OPENGL_TO_OPENCV, Camera, CameraSet, Frame, Points
from nerfpipe.geometry.normalize import Similarity, depths, in_view
from nerfpipe.pipeline import ParamError
from nerfpipe.stages.bounds import BoundsStage
from tests.helpers import SavedCameras, look_at, shared


def run_bounds(cameras: CameraSet, tmp_path: Path, **overrides) -> tuple[Path, dict]:
    (tmp_path / "capture").mkdir(exist_ok=True)  # no photos: the cameras come from the stage before
    pipe = Pipeline([SavedCameras(cameras), BoundsStage()], tmp_path / "capture", tmp_path / "run",
                    overrides={"bounds": overrides})
    path = pipe.run()[-1].path
    return path, json.loads((path / "bounds.json").read_text())


def ring_with_points(n_frames: int = 12, seed: int = 0) -> CameraSet:
    """A ring of 640x480 cameras around a box of points, in an arbitrary SfM frame (rotated, scaled, moved)."""
    rng = np.random.default_rng(seed)
    camera = Camera.pinhole(500.0, 500.0, 320.0, 240.0, 640, 480)
    c2ws = np.array([
        look_at(np.array([3 * np.cos(a), 3 * np.sin(a), 1.0]), np.zeros(3))
        for a in np.linspace(0, 2 * np.pi, n_frames, endpoint=False)
    ])
    xyz = rng.uniform([-0.8, -0.5, -0.4], [0.8, 0.5, 0.4], (4000, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    sfm = Similarity(0.37, q if np.linalg.det(q) > 0 else -q, np.array([4.0, -1.0, 2.5]))
    c2ws, xyz = sfm.apply_c2w(c2ws), sfm.apply_points(xyz)
    visible = [np.flatnonzero(in_view(c, camera.K(), 640, 480, xyz)) for c in c2ws]
    frames = [Frame(f"f{i:03d}.png", 1, c) for i, c in enumerate(c2ws)]
    points = Points(xyz, rng.integers(0, 255, (len(xyz), 3), dtype=np.uint8), np.full(len(xyz), 0.5), visible)
    return CameraSet({1: camera}, frames, points, source="test")


def test_world_is_the_pinhole_set_moved_by_to_world(tmp_path):
    sfm = ring_with_points()
    out, bounds = run_bounds(sfm, tmp_path)
    world = CameraSet.load(out / "world")
    to_world = Similarity.from_matrix(np.array(bounds["to_world"]))
    np.testing.assert_allclose(np.array(bounds["to_world"]) @ np.array(bounds["to_sfm"]), np.eye(4), atol=1e-9)
    assert [f.name for f in world.frames] == [f.name for f in sfm.frames] and world.cameras == sfm.cameras
    for original, moved in zip(sfm.frames, world.frames):
        np.testing.assert_allclose(moved.c2w, to_world.apply_c2w(original.c2w), atol=1e-9)
    np.testing.assert_allclose(world.points.xyz, to_world.apply_points(sfm.points.xyz), atol=1e-9)
    assert all(np.array_equal(a, b) for a, b in zip(world.points.visible, sfm.points.visible))
    assert bounds["scale"] == pytest.approx(to_world.scale)
    # world z is the SfM up direction
    np.testing.assert_allclose(to_world.rotation @ np.array(bounds["up"]), [0, 0, 1], atol=1e-9)
    # the points' robust box fills [-1, 1]^3 along its longest axis; the scene box is it grown by 10 % of its
    # extent on every side, and no margin gives the robust box itself
    lo, hi = np.array(bounds["scene_box"])
    _, tight = run_bounds(sfm, tmp_path, box_margin=0.0)
    tight_lo, tight_hi = np.array(tight["scene_box"])
    assert np.all(tight_lo >= -1 - 1e-9) and np.all(tight_hi <= 1 + 1e-9)
    assert max(tight_hi.max(), -tight_lo.min()) == pytest.approx(1.0)
    np.testing.assert_allclose(lo, tight_lo - 0.1 * (tight_hi - tight_lo), atol=1e-9)
    np.testing.assert_allclose(hi, tight_hi + 0.1 * (tight_hi - tight_lo), atol=1e-9)


def test_point_bounds_hold_every_point_each_image_sees(tmp_path):
    out, bounds = run_bounds(ring_with_points(), tmp_path)
    world = CameraSet.load(out / "world")
    assert bounds["method"] == "points" and bounds["rig"] == "inward"
    for frame, record, seen in zip(world.frames, bounds["frames"], world.points.visible):
        z = depths(frame.c2w, world.points.xyz[seen])
        assert record["name"] == frame.name and record["method"] == "points"
        assert record["near"] <= z.min() and z.max() <= record["far"]
        # 0.1 / 99.9 percentiles with a 10% margin: tight around the visible depths
        assert record["near"] > 0.85 * z.min() and record["far"] < 1.15 * z.max()
    assert bounds["near"] == min(f["near"] for f in bounds["frames"])
    assert bounds["far"] == max(f["far"] for f in bounds["frames"])


def test_images_seeing_too_few_points_fall_back_to_the_scene_box(tmp_path):
    sfm = ring_with_points()
    sfm.points.visible[3] = sfm.points.visible[3][:4]
    _, bounds = run_bounds(sfm, tmp_path, min_points=10)
    methods = [f["method"] for f in bounds["frames"]]
    assert methods[3] == "rig" and methods.count("rig") == 1
    assert 0 < bounds["frames"][3]["near"] < bounds["frames"][3]["far"]


def test_lego_rig_without_points_gets_bounds_that_contain_the_object(tmp_path):
    doc = json.loads(shared("nerf_synthetic_lego_400", "transforms_train.json").read_text())
    focal = 0.5 * 400 / np.tan(0.5 * doc["camera_angle_x"])
    frames = [
        Frame(f["file_path"].lstrip("./") + ".png", 1, np.array(f["transform_matrix"]) @ OPENGL_TO_OPENCV, "train")
        for f in doc["frames"]
    ]
    lego = CameraSet({1: Camera.pinhole(focal, focal, 200.0, 200.0, 400, 400)}, frames, None, "transforms_json")
    out, bounds = run_bounds(lego, tmp_path)
    assert bounds["method"] == "rig" and bounds["rig"] == "inward"
    to_world = Similarity.from_matrix(np.array(bounds["to_world"]))
    np.testing.assert_allclose(to_world.apply_points(np.zeros(3)), 0, atol=1e-6)  # cameras look at the origin
    np.testing.assert_allclose(bounds["up"], [0, 0, 1], atol=1e-6)
    near = np.array([f["near"] for f in bounds["frames"]]) / bounds["scale"]
    far = np.array([f["far"] for f in bounds["frames"]]) / bounds["scale"]
    np.testing.assert_allclose(near, 2.0, atol=0.05)  # the usual 2 / 6 of the NeRF synthetic scenes
    np.testing.assert_allclose(far, 6.0, atol=0.05)
    world = CameraSet.load(out / "world")
    dist = np.linalg.norm(world.centers(), axis=1) / bounds["scale"]  # distance to the origin, scene units
    assert np.all(near <= dist - 1.5) and np.all(far >= dist + 1.5)
    assert world.points is None and (out / "world" / "points3d.npz").exists() is False
    manifest = json.loads((out / "manifest.json").read_text())
    assert BoundsStage().describe(out, manifest)[0].startswith("100 images, rig-based near/far 0.5")


def test_bad_percentiles_are_refused(tmp_path):
    with pytest.raises(ParamError, match="near_percentile < far_percentile"):
        run_bounds(ring_with_points(), tmp_path, near_percentile="50", far_percentile="10")
