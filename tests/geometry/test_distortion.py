"""Distortion maths: displacement worked out by hand, the half-pixel convention, and remap tables."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from nerfpipe.geometry.cameras import Camera
from nerfpipe.geometry.distortion import (
    image_grid,
    max_distortion_displacement,
    opencv_K,
    undistort_pixels,
    undistorted_camera,
    undistortion_maps,
)


def simple_radial(k1: float, f: float = 400.0, width: int = 640, height: int = 480) -> Camera:
    # principal point at the image centre (COLMAP convention), so the corner (0, 0) lies at
    # normalized distorted radius sqrt(320^2 + 240^2) / 400 = 400 / 400 = 1
    return Camera("SIMPLE_RADIAL", width, height, (f, width / 2, height / 2, k1))


def test_pinhole_cameras_move_nothing_exactly():
    assert max_distortion_displacement(Camera("SIMPLE_PINHOLE", 640, 480, (500.0, 320.0, 240.0))) == 0.0
    assert max_distortion_displacement(Camera("PINHOLE", 640, 480, (500.0, 510.0, 321.0, 239.0))) == 0.0
    assert max_distortion_displacement(Camera("OPENCV", 640, 480, (500.0, 510.0, 321.0, 239.0, 0, 0, 0, 0))) == 0.0
    assert max_distortion_displacement(simple_radial(0.0)) == 0.0


def test_simple_radial_displacement_at_the_corner_matches_f_k1_r3():
    # A ray at undistorted normalized radius r lands at r (1 + k1 r^2): it moves by f k1 r^3 pixels.
    # The corner is at distorted radius 1, so r solves r + k1 r^3 = 1.
    # k1 = 0.05: r = 0.95628 (0.95628 + 0.05 * 0.87449 = 1.00000), f k1 r^3 = 400 * 0.05 * 0.87449 = 17.490 px
    assert max_distortion_displacement(simple_radial(0.05)) == pytest.approx(17.490, rel=0.01)
    # k1 = 0.001: r = 0.99900, so f k1 r^3 = 400 * 0.001 * 0.997 = 0.399 px, ~ f k1 (corner radius)^3 = 0.4
    assert max_distortion_displacement(simple_radial(0.001)) == pytest.approx(0.399, rel=0.01)
    # barrel: k1 = -0.05 gives r - 0.05 r^3 = 1 -> r = 1.05674 (1.05674 - 0.05 * 1.18006 = 0.99974 ~ 1),
    # f |k1| r^3 = 400 * 0.05 * 1.1801 = 23.60 px
    assert max_distortion_displacement(simple_radial(-0.05)) == pytest.approx(23.60, rel=0.01)


def test_displacement_grows_with_k1_and_the_grid_reaches_the_corners():
    pincushion = [max_distortion_displacement(simple_radial(k)) for k in (0.0, 0.005, 0.01, 0.02, 0.05, 0.1)]
    barrel = [max_distortion_displacement(simple_radial(-k)) for k in (0.0, 0.005, 0.01, 0.02, 0.05)]
    assert np.all(np.diff(pincushion) > 0) and np.all(np.diff(barrel) > 0)
    grid = image_grid(640, 480, samples=8)
    for corner in ([0, 0], [640, 0], [0, 480], [640, 480]):
        assert np.any(np.all(grid == corner, axis=1))
    assert grid.min(axis=0).tolist() == [0, 0] and grid.max(axis=0).tolist() == [640, 480]


def test_fisheye_is_never_a_pinhole_even_with_zero_coefficients():
    # equidistant projection: at 300 px from the centre, theta = 300 / 300 = 1 rad, and a pinhole puts
    # that ray at 300 tan(1) = 467.2 px: a displacement of 167.2 px at the ends of the horizontal axis
    fisheye = Camera("OPENCV_FISHEYE", 600, 400, (300.0, 300.0, 300.0, 200.0, 0.0, 0.0, 0.0, 0.0))
    assert max_distortion_displacement(fisheye) > 167.2 * 1.5  # the corners move even more
    moved = undistort_pixels(fisheye, np.array([[600.0, 200.0]]))
    assert moved[0] == pytest.approx([300 + 300 * np.tan(1.0), 200.0], abs=1e-6)
    # at f = 150 the image's corners lie 500 px = 3.3 rad off-axis: beyond 90 degrees, no pinhole shows them
    wide = Camera("OPENCV_FISHEYE", 600, 400, (150.0, 150.0, 300.0, 200.0, 0.0, 0.0, 0.0, 0.0))
    assert max_distortion_displacement(wide) == float("inf")
    assert np.isinf(undistort_pixels(wide, np.array([[300.0 + 150 * 1.6, 200.0]]))).all()  # 1.6 rad > pi / 2


def test_undistort_pixels_inverts_the_lens_model():
    camera = Camera("OPENCV", 640, 512, (518.7, 518.9, 316.2, 250.2, -0.057, 0.091, 0.0001, 0.0021))
    rays = np.random.default_rng(0).uniform(-0.6, 0.6, (50, 3)) * [1, 1, 0] + [0, 0, 1]
    # projectPoints works in OpenCV's pixel convention; + 0.5 for COLMAP's
    distorted = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), opencv_K(camera), camera.distortion())[0]
    pinhole = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), opencv_K(camera), None)[0]
    recovered = undistort_pixels(camera, distorted.reshape(-1, 2) + 0.5)
    assert recovered == pytest.approx(pinhole.reshape(-1, 2) + 0.5, abs=1e-6)


def test_zero_distortion_maps_are_the_identity():
    camera = Camera("OPENCV", 640, 480, (400.0, 410.0, 320.3, 240.7, 0.0, 0.0, 0.0, 0.0))
    map_x, map_y, pinhole = undistortion_maps(camera)
    assert map_x.shape == map_y.shape == (480, 640) and map_x.dtype == np.float32
    assert np.abs(map_x - np.arange(640)[None, :]).max() < 1e-3
    assert np.abs(map_y - np.arange(480)[:, None]).max() < 1e-3
    assert pinhole.model == "PINHOLE" and pinhole.params == pytest.approx(camera.params[:4], abs=1e-9)


def test_half_pixel_convention_a_centred_lens_stays_centred():
    # cx = W / 2 in COLMAP's convention is the image centre, (W - 1) / 2 in OpenCV's. The lens is symmetric
    # about it, so the table must be too: map_x[y, x] + map_x[y, W-1-x] = W - 1. Feeding COLMAP's cx to
    # OpenCV unshifted would put the centre half a pixel off and break this by ~1 px at the border.
    camera = simple_radial(-0.08)
    map_x, map_y, pinhole = undistortion_maps(camera)
    assert np.abs(map_x + map_x[:, ::-1] - 639).max() < 1e-3
    assert np.abs(map_y + map_y[::-1, :] - 479).max() < 1e-3
    assert (pinhole.cx, pinhole.cy) == pytest.approx((320.0, 240.0), abs=1e-6)


def test_maps_follow_the_lens_model_worked_by_hand():
    camera = simple_radial(0.03)
    map_x, map_y, pinhole = undistortion_maps(camera)
    for x, y in [(0, 0), (639, 479), (100, 400), (320, 17)]:
        # output pixel (x, y) -> COLMAP position (x + 0.5, y + 0.5) -> normalized ray of the pinhole
        nx, ny = (x + 0.5 - pinhole.cx) / pinhole.fx, (y + 0.5 - pinhole.cy) / pinhole.fy
        scale = 1 + 0.03 * (nx * nx + ny * ny)  # SIMPLE_RADIAL
        u, v = 400 * nx * scale + 320, 400 * ny * scale + 240  # COLMAP position in the input
        assert (map_x[y, x], map_y[y, x]) == pytest.approx((u - 0.5, v - 0.5), abs=1e-3)


@pytest.mark.parametrize(
    "camera",
    [
        simple_radial(-0.15),
        simple_radial(0.08),
        # off-centre principal point and tangential terms: where a 9 x 9 grid can miss the tightest point
        Camera("OPENCV", 640, 512, (518.7, 518.9, 290.0, 270.0, -0.2, 0.09, 0.004, -0.003)),
        Camera("FULL_OPENCV", 640, 512, (518.7, 518.9, 316.2, 250.2, -0.057, 0.091, 0.0001, 0.0021, -0.011, 0, 0, 0)),
        Camera("OPENCV_FISHEYE", 640, 480, (300.0, 300.0, 320.0, 240.0, 0.05, 0.01, 0.0, 0.0)),
    ],
    ids=["barrel", "pincushion", "off-centre", "full-opencv", "fisheye"],
)
def test_undistorted_images_have_no_black_border(camera):
    map_x, map_y, pinhole = undistortion_maps(camera)
    assert pinhole.model == "PINHOLE" and (pinhole.width, pinhole.height) == (camera.width, camera.height)
    # every output pixel samples inside the input: between the outer pixel centres 0 .. W-1 (OpenCV
    # convention); OpenCV's fisheye estimate measures to the image edge, so up to half a pixel further
    margin = 0.5 if camera.is_fisheye else 1e-3
    assert map_x.min() > -margin and map_x.max() < camera.width - 1 + margin
    assert map_y.min() > -margin and map_y.max() < camera.height - 1 + margin
    if not camera.is_fisheye:  # alpha = 0 keeps all of the valid area: both axes reach the border
        assert map_x.min() < 0.5 and map_x.max() > camera.width - 1.5
        assert map_y.min() < 0.5 and map_y.max() > camera.height - 1.5


def test_new_camera_agrees_with_opencv_alpha_0():
    params = (518.7, 518.9, 316.2, 250.2, -0.057, 0.091, 0.0001, 0.0021, -0.011, 0.0, 0.0, 0.0)
    camera = Camera("FULL_OPENCV", 640, 512, params)
    ours = opencv_K(undistorted_camera(camera))
    theirs, _ = cv2.getOptimalNewCameraMatrix(opencv_K(camera), camera.distortion(), (640, 512), 0)
    assert ours == pytest.approx(theirs, rel=1e-3)
