"""The pieces between a CameraSet and COLMAP's point triangulator: known poses in, ids kept, points back."""

from __future__ import annotations

import numpy as np
import pycolmap
import pytest

from nerfpipe.geometry.cameras import Camera, CameraSet, Frame
from nerfpipe.poses.colmap.triangulate import known_poses_model, max_pose_change, triangulated_points, write_to_database
from tests.helpers import look_at


def ring(n: int = 3) -> CameraSet:
    """``n`` cameras on a ring around the origin; the last one with its own, distorted camera."""
    cameras = {1: Camera.pinhole(500.0, 510.0, 320.0, 240.0, 640, 480),
               7: Camera("OPENCV", 640, 480, (480.0, 490.0, 321.0, 239.0, 0.1, -0.02, 0.001, 0.0))}
    frames = [Frame(f"sub/p{i}.png", 1 if i < n - 1 else 7,
                    look_at(np.array([3.0 * np.cos(i), 3.0 * np.sin(i), 1.0]), np.zeros(3))) for i in range(n)]
    return CameraSet(cameras, frames, source="test")


def test_known_poses_become_a_model_with_fixed_ids_in_the_database(tmp_path):
    cameras = ring()
    model = known_poses_model(cameras)
    assert sorted(model.images) == [1, 2, 3] and model.num_reg_images() == 3
    for image_id, frame in zip(sorted(model.images), cameras.frames):
        image = model.images[image_id]
        assert image.name == frame.name
        assert np.allclose(image.cam_from_world().matrix(), frame.w2c[:3], atol=1e-12)
        camera = model.cameras[image.camera_id]
        assert camera.model.name == cameras.camera_of(frame).model and camera.has_prior_focal_length
        assert np.allclose(camera.params, cameras.camera_of(frame).params)
    assert max_pose_change(model, cameras) < 1e-12
    assert triangulated_points(model, cameras) is None  # no points yet

    database = tmp_path / "database.db"
    with pycolmap.Database.open(database) as db:
        write_to_database(model, db)
    with pycolmap.Database.open(database) as db:
        assert {(im.image_id, im.name, im.camera_id) for im in db.read_all_images()} == {
            (i, f.name, i) for i, f in enumerate(cameras.frames, start=1)}
        assert db.num_frames() == db.num_rigs() == 3


def test_a_moved_pose_is_measured():
    cameras = ring()
    model = known_poses_model(cameras)
    before = cameras.frames[1].w2c
    cameras.frames[1].c2w[:3, 3] += [0.25, 0.0, 0.0]  # the camera centre moves 0.25 along x
    # w2c's translation -R^T c moves by R^T [0.25, 0, 0]: its largest entry is what is reported
    expected = np.abs(cameras.frames[1].w2c - before).max()
    assert expected > 0.1 and max_pose_change(model, cameras) == pytest.approx(expected, abs=1e-12)
