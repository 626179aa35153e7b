"""Keyframe camera paths: through every keyframe, smooth between them, closed when looped; a render's own
camera_path.json loads back as the same frames; a broken file is one line naming it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nerfpipe.export.camera_path import CameraPath, Keyframe, focal_of, fov_of, nerfstudio_path
from nerfpipe.pipeline.errors import InputError
from tests.helpers import look_at


def ring(n: int, radius: float = 3.0) -> list[Keyframe]:
    """``n`` cameras on a circle about z, looking at the origin; fields of view 40, 45, 50, ..."""
    keys = []
    for i in range(n):
        angle = 2 * np.pi * i / n
        eye = np.array([radius * np.cos(angle), radius * np.sin(angle), 0.5])
        keys.append(Keyframe(look_at(eye, np.zeros(3)), 40.0 + 5 * i))
    return keys


def test_the_path_passes_through_every_keyframe():
    keys = ring(4)
    path = CameraPath(tuple(keys), frames=13, fps=24)  # 4 knots, 3 spans of 4 frames
    poses, fovs = path.sample()
    assert poses.shape == (13, 4, 4) and fovs.shape == (13,)
    for i, key in enumerate(keys):
        assert np.allclose(poses[4 * i], key.c2w, atol=1e-9) and fovs[4 * i] == pytest.approx(key.fov)
    rotations = poses[:, :3, :3]
    assert np.allclose(rotations @ rotations.transpose(0, 2, 1), np.eye(3), atol=1e-9)  # rotations throughout
    assert np.allclose(np.linalg.det(rotations), 1.0)


def test_between_keyframes_the_path_is_smooth_and_a_loop_closes():
    keys = ring(6)
    poses, _ = CameraPath(tuple(keys), frames=60, loop=True).sample()
    centres = poses[:, :3, 3]
    steps = np.linalg.norm(np.diff(np.vstack([centres, centres[:1]]), axis=0), axis=1)
    assert steps.max() < 1.6 * steps.mean()  # no jump, including from the last frame back to the first
    assert np.allclose(np.linalg.norm(centres[:, :2], axis=1), 3.0, rtol=0.03)  # stays near the circle
    assert np.allclose(poses[0], keys[0].c2w) and np.allclose(poses[10], keys[1].c2w, atol=1e-9)


def test_one_or_two_keyframes():
    keys = ring(4)
    poses, fovs = CameraPath((keys[0],), frames=5).sample()
    assert np.allclose(poses, keys[0].c2w) and np.all(fovs == keys[0].fov)
    poses, fovs = CameraPath((keys[0], keys[1]), frames=3).sample()
    assert np.allclose(poses[0], keys[0].c2w) and np.allclose(poses[2], keys[1].c2w, atol=1e-9)
    assert fovs[1] == pytest.approx(42.5)


def test_a_saved_path_loads_back(tmp_path):
    path = CameraPath(tuple(ring(3)), frames=30, fps=12.5, loop=True)
    path.save(tmp_path / "camera_path.json")
    loaded = CameraPath.load(tmp_path / "camera_path.json")
    assert (loaded.frames, loaded.fps, loaded.loop) == (30, 12.5, True)
    assert all(np.allclose(a.c2w, b.c2w) and a.fov == b.fov for a, b in zip(loaded.keyframes, path.keyframes))


def test_a_renders_own_camera_path_gives_its_frames_again(tmp_path):
    """The render stage's camera_path.json: each frame a keyframe, sampled once each: the same poses."""
    keys = ring(5)
    doc = {"camera": {"model": "PINHOLE", "width": 64, "height": 48, "params": [50.0, 50.0, 32.0, 24.0]},
           "fps": 10, "frames": [{"c2w": k.c2w.tolist()} for k in keys]}
    (tmp_path / "camera_path.json").write_text(json.dumps(doc))
    loaded = CameraPath.load(tmp_path / "camera_path.json")
    poses, fovs = loaded.sample()
    assert loaded.frames == 5 and loaded.fps == 10 and np.allclose(poses, [k.c2w for k in keys], atol=1e-9)
    assert fovs == pytest.approx([fov_of(48, 50.0)] * 5)
    assert focal_of(48, fov_of(48, 50.0)) == pytest.approx(50.0)


@pytest.mark.parametrize("doc, problem", [
    ([], "is not a camera path"),
    ({"frames": 10}, "has no keyframes list"),
    ({"keyframes": []}, "has no keyframes"),
    ({"keyframes": [{"c2w": np.eye(3).tolist(), "fov": 50}]}, "keyframe 0: c2w is not a 4x4 matrix"),
    ({"keyframes": [{"c2w": (2 * np.eye(4)).tolist(), "fov": 50}]}, "keyframe 0: c2w is not a rigid transform"),
    ({"keyframes": [{"c2w": np.eye(4).tolist(), "fov": 180}]}, "keyframe 0: fov is 180, not a vertical field"),
    ({"keyframes": [{"c2w": np.eye(4).tolist(), "fov": 50}], "frames": 0}, "frames is 0, not a whole number"),
    ({"keyframes": [{"c2w": np.eye(4).tolist(), "fov": 50}], "fps": "fast"}, "fps is 'fast', not a positive"),
])
def test_a_broken_camera_path_is_one_line_naming_it(tmp_path, doc, problem):
    (tmp_path / "path.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=problem) as err:
        CameraPath.load(tmp_path / "path.json")
    assert err.value.path == tmp_path / "path.json" and "\n" not in str(err.value)


def test_nerfstudios_schema_round_trips_every_frame(tmp_path):
    # ns-render's camera path: camera_to_world as 16 numbers, OpenGL axes, row-major; fov vertical in degrees
    poses = np.array([look_at(np.array([3.0 * np.cos(a), 3.0 * np.sin(a), 1.0]), np.zeros(3)) for a in (0.0, 0.5, 1.0)])
    fovs = np.array([40.0, 50.0, 45.0])
    doc = nerfstudio_path(poses, fovs, 640, 360, 12.0)
    assert doc["camera_type"] == "perspective" and doc["seconds"] == 0.25 and len(doc["camera_path"]) == 3
    first = np.array(doc["camera_path"][0]["camera_to_world"]).reshape(4, 4)
    assert np.allclose(first[:3, 2], -poses[0][:3, 2])  # OpenGL: the camera looks down its -z
    assert doc["camera_path"][0]["aspect"] == pytest.approx(640 / 360)
    (tmp_path / "path.json").write_text(json.dumps(doc))
    path = CameraPath.load(tmp_path / "path.json")
    assert path.frame == "sfm" and path.frames == 3 and path.fps == 12.0
    sampled, sampled_fovs = path.sample()
    assert np.allclose(sampled, poses, atol=1e-9) and np.allclose(sampled_fovs, fovs)
    # without fps, nerfstudio's seconds give it
    del doc["fps"]
    (tmp_path / "path.json").write_text(json.dumps(doc))
    assert CameraPath.load(tmp_path / "path.json").fps == pytest.approx(12.0)
    doc["camera_path"][1]["camera_to_world"] = [1, 2, 3]
    (tmp_path / "path.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"camera_path\[1\]: camera_to_world is not 16 numbers"):
        CameraPath.load(tmp_path / "path.json")
