"""The pieces between a CameraSet and COLMAP's point triangulator: known poses in, ids kept, points back."""

from __future__ import annotations

import numpy as np
import pycolmap
import pytest

from nerfpipe.geometry.cameras import Camera, CameraSet, Frame
from nerfpipe.poses.colmap.triangulate import (adjusted_cameras, adjusts, bundle_adjust, known_poses_model, max_pose_change,
                                              triangulated_points, with_distortion, write_to_database)
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
        assert image.camera_id == frame.camera_id and camera.has_prior_focal_length  # shared as the CameraSet shares
        known = with_distortion(cameras.camera_of(frame))
        assert camera.model.name == known.model and np.allclose(camera.params, known.params)
    assert max_pose_change(model, cameras) < 1e-12
    assert triangulated_points(model, cameras) is None  # no points yet

    database = tmp_path / "database.db"
    with pycolmap.Database.open(database) as db:
        write_to_database(model, db)
    with pycolmap.Database.open(database) as db:
        assert {(im.image_id, im.name, im.camera_id) for im in db.read_all_images()} == {
            (i, f.name, f.camera_id) for i, f in enumerate(cameras.frames, start=1)}
        assert db.num_frames() == 3 and db.num_rigs() == 2  # a frame an image, a rig a camera


def test_a_pinhole_becomes_its_radial_twin_projecting_alike():
    simple = with_distortion(Camera("SIMPLE_PINHOLE", 640, 480, (500.0, 320.0, 240.0)))
    assert simple == Camera("SIMPLE_RADIAL", 640, 480, (500.0, 320.0, 240.0, 0.0))
    assert with_distortion(Camera.pinhole(500.0, 500.0, 321.0, 239.0, 640, 480)) == \
        Camera("SIMPLE_RADIAL", 640, 480, (500.0, 321.0, 239.0, 0.0))
    for kept in (Camera.pinhole(500.0, 510.0, 321.0, 239.0, 640, 480),  # two focal lengths: a lab's calibration
                 Camera("OPENCV", 640, 480, (480.0, 490.0, 321.0, 239.0, 0.1, -0.02, 0.001, 0.0))):
        assert with_distortion(kept) is kept
    # the same pixels for the same points: COLMAP's projection of a camera-frame point through each model
    points = np.array([[0.3, -0.2, 1.0], [-0.5, 0.4, 2.0], [0.0, 0.0, 3.0]])
    for before in (Camera("SIMPLE_PINHOLE", 640, 480, (500.0, 320.0, 240.0)), Camera.pinhole(500.0, 500.0, 321.0, 239.0, 640, 480)):
        after = with_distortion(before)
        uv = [pycolmap.Camera(model=c.model, width=640, height=480, params=list(c.params)).img_from_cam(points)
              for c in (before, after)]
        assert np.allclose(uv[0], uv[1], atol=1e-9)


def test_bundle_adjustment_recovers_a_lens_the_pose_file_left_out():
    """Six known poses around 300 points; the photos taken through a lens of f = 600 px and radial distortion
    k1 = -0.03 (COLMAP's SIMPLE_RADIAL), the pose file saying a pinhole of f = 590 px (an LLFF file drops the
    distortion COLMAP found). The triangulated points reproject 1.7 px off; adjusted, the focal length and k1
    are the lens's and the poses stay where they were."""
    rng = np.random.default_rng(0)
    lens = pycolmap.Camera(model="SIMPLE_RADIAL", width=640, height=480, params=[600.0, 320.0, 240.0, -0.03])
    frames = [Frame(f"p{i}.png", 1, look_at(np.array([4 * np.cos(a), 4 * np.sin(a), 1.0]), np.zeros(3)))
              for i, a in enumerate(np.linspace(0.0, 1.5, 6))]
    given = CameraSet({1: Camera.pinhole(590.0, 590.0, 320.0, 240.0, 640, 480)}, frames, source="test")
    model = known_poses_model(given)
    xyz = rng.uniform(-1.0, 1.0, (300, 3))
    for image_id, frame in zip(sorted(model.images), frames):
        in_camera = (frame.w2c[:3, :3] @ xyz.T + frame.w2c[:3, 3:]).T
        model.images[image_id].points2D = pycolmap.Point2DList(
            [pycolmap.Point2D(uv) for uv in lens.img_from_cam(np.ascontiguousarray(in_camera))])
    for j, point in enumerate(xyz):
        track = pycolmap.Track()
        for image_id in model.images:
            track.add_element(image_id, j)
        model.add_point3D(point, track)

    before, after = bundle_adjust(model)
    assert 1.0 < before < 3.0 and after < 1e-4
    adjusted = adjusted_cameras(model, given)
    assert adjusted.cameras[1].model == "SIMPLE_RADIAL"
    f, cx, cy, k1 = adjusted.cameras[1].params
    assert f == pytest.approx(600.0, abs=0.01) and (cx, cy) == (320.0, 240.0) and k1 == pytest.approx(-0.03, abs=1e-5)
    assert [f.name for f in adjusted.frames] == [f.name for f in frames]
    assert max(np.abs(a.c2w - b.c2w).max() for a, b in zip(adjusted.frames, frames)) < 1e-6
    assert len(adjusted.points.xyz) == 300 and given.cameras[1].model == "PINHOLE"  # the input is left as it was


@pytest.mark.parametrize("choice, before, after, points, kept", [
    ("auto", 1.29, 0.61, 9194, True), ("auto", 1.0, 0.8, 5000, True), ("auto", 1.0, 0.81, 10000, False),
    ("auto", 0.36, 0.21, 10000, False), ("auto", 0.51, 0.3, 10000, True),  # the temple's lab calibration stays
    ("on", 0.36, 0.35, 10000, True), ("off", 1.29, 0.49, 10000, False),
    ("auto", 0.36, 0.0, 0, False), ("on", 1.29, 0.2, 4999, False)])  # the adjustment lost the points: astray
def test_adjusted_poses_are_kept_where_they_reproject_a_fifth_closer_through_most_points(choice, before, after, points,
                                                                                        kept):
    assert adjusts(choice, before, after, 10000, points) is kept


def test_a_moved_pose_is_measured():
    cameras = ring()
    model = known_poses_model(cameras)
    before = cameras.frames[1].w2c
    cameras.frames[1].c2w[:3, 3] += [0.25, 0.0, 0.0]  # the camera centre moves 0.25 along x
    # w2c's translation -R^T c moves by R^T [0.25, 0, 0]: its largest entry is what is reported
    expected = np.abs(cameras.frames[1].w2c - before).max()
    assert expected > 0.1 and max_pose_change(model, cameras) == pytest.approx(expected, abs=1e-12)
