"""Lens distortion: how far it moves pixels, and the remap tables that remove it (numpy + OpenCV).

Cameras follow ``nerfpipe.geometry.cameras``: COLMAP models and COLMAP's pixel convention, where the
centre of the top-left pixel is at (0.5, 0.5) and the image covers [0, W] x [0, H]. OpenCV puts that
pixel centre at (0, 0), so every call into OpenCV goes through ``opencv_K`` (cx, cy - 0.5) and every
camera matrix coming back is shifted by + 0.5 again. Remap tables are OpenCV's: ``cv2.remap`` reads
them with integer pixel centres on both sides, which is what it expects.

Distortion acts on normalized coordinates (x, y) = ((u - cx) / fx, (v - cy) / fy) of the ideal pinhole
camera. For the OpenCV models, with r^2 = x^2 + y^2,

    x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)

(y_d likewise), and for the fisheye models, with theta = atan(r), x_d = x theta_d / r where
theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8).
"""

from __future__ import annotations

import numpy as np

from nerfpipe.geometry.cameras import Camera

# cv2.undistortPoints inverts the distortion by fixed-point iteration; OpenCV's default (5 iterations)
# leaves hundredths of a pixel on strong lenses, so iterate until the re-distorted point is within 1e-9.
_CRITERIA = (3, 100, 1e-9)  # cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS


def to_opencv_K(K: np.ndarray) -> np.ndarray:
    """(3, 3) calibration matrix from COLMAP's pixel convention to OpenCV's: cx - 0.5, cy - 0.5."""
    K = np.array(K, dtype=np.float64)
    K[:2, 2] -= 0.5
    return K


def opencv_K(camera: Camera) -> np.ndarray:
    """(3, 3) calibration matrix of ``camera`` in OpenCV's pixel convention."""
    return to_opencv_K(camera.K())


def image_grid(width: int, height: int, samples: int = 64) -> np.ndarray:
    """(N, 2) pixel positions (COLMAP convention) covering the whole image [0, W] x [0, H].

    A ``samples`` x ``samples`` grid over the image, plus ``4 * samples`` points along each of the four
    edges, corners included: distortion is largest at the border, usually in the corners.
    """
    if samples < 2:
        raise ValueError(f"samples must be at least 2, got {samples}")
    xs, ys = np.linspace(0.0, width, samples), np.linspace(0.0, height, samples)
    interior = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    ex, ey = np.linspace(0.0, width, 4 * samples), np.linspace(0.0, height, 4 * samples)
    border = np.concatenate([
        np.stack([ex, np.zeros_like(ex)], 1),
        np.stack([ex, np.full_like(ex, height)], 1),
        np.stack([np.zeros_like(ey), ey], 1),
        np.stack([np.full_like(ey, width), ey], 1),
    ])
    return np.concatenate([interior, border])


def undistort_pixels(camera: Camera, pixels: np.ndarray, new_K: np.ndarray | None = None) -> np.ndarray:
    """Where the pinhole camera ``new_K`` (default: the camera's own K) sees what ``camera`` sees at ``pixels``.

    pixels: (N, 2) positions in ``camera``'s image, COLMAP convention. new_K: (3, 3), COLMAP convention.
    Returns (N, 2) positions in the pinhole image, COLMAP convention; inf for fisheye pixels whose ray is
    at or beyond 90 degrees off-axis (no pinhole image shows it).
    """
    import cv2

    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    K = opencv_K(camera)
    P = K.copy() if new_K is None else to_opencv_K(new_K)
    if len(pixels) == 0:
        return np.zeros((0, 2))
    # pixels - 0.5: COLMAP -> OpenCV positions; + 0.5 on the way back
    if not camera.is_fisheye:
        ideal = cv2.undistortPoints(pixels - 0.5, K, camera.distortion(), R=np.eye(3), P=P, criteria=_CRITERIA)
        return ideal.reshape(-1, 2) + 0.5
    ideal = cv2.fisheye.undistortPoints(pixels - 0.5, K, camera.distortion(), R=np.eye(3), P=P, criteria=_CRITERIA)
    ideal = ideal.reshape(-1, 2) + 0.5
    # OpenCV returns huge finite numbers for rays at or beyond 90 degrees; theta_d grows with theta, so
    # those are the pixels whose distorted angle theta_d reaches theta_d(pi / 2)
    theta_d = np.hypot((pixels[:, 0, 0] - camera.cx) / camera.fx, (pixels[:, 0, 1] - camera.cy) / camera.fy)
    k = camera.distortion()
    right_angle = np.pi / 2 * (1 + sum(k[i] * (np.pi / 2) ** (2 * i + 2) for i in range(4)))
    ideal[theta_d >= right_angle] = np.inf
    return ideal


def max_distortion_displacement(camera: Camera, samples: int = 64) -> float:
    """Largest distance in pixels between a pixel and where the pinhole camera with the same K puts it.

    For each p on ``image_grid(W, H, samples)`` (the whole image, border and corners included):
    d(p) = |p - undistort(p)|, with undistort mapping through the camera's own K, so only the lens moves
    points. For SIMPLE_RADIAL, a point at undistorted normalized radius r moves by f k1 r^3.
    Pinhole models (no distortion coefficients, or all zero) return exactly 0.0. Fisheye models never do:
    with all coefficients zero they are still equidistant (r = f theta, not f tan theta); one whose image
    reaches 90 degrees off-axis returns inf (no pinhole camera can show it).
    """
    if not camera.is_fisheye and not camera.has_distortion:
        return 0.0
    grid = image_grid(camera.width, camera.height, samples)
    moved = undistort_pixels(camera, grid)
    displacement = np.linalg.norm(moved - grid, axis=1)
    if not np.all(np.isfinite(displacement)):
        return float("inf")
    return float(displacement.max())


def undistorted_camera(camera: Camera) -> Camera:
    """The PINHOLE camera of the same size that shows only valid pixels of ``camera`` (no black borders).

    Like ``cv2.getOptimalNewCameraMatrix(alpha=0)``, but with every border pixel instead of a 9 x 9 grid,
    so off-centre principal points and tangential terms cannot leave a sliver of border: the border pixel
    centres are undistorted to normalized coordinates, the rectangle [x0, x1] x [y0, y1] bounded by the
    innermost point of each edge is taken (x0 = max over the left column, x1 = min over the right column,
    likewise for y), and the new camera maps it onto the output pixel centres:
    fx' = (W - 1) / (x1 - x0), cx' = -fx' x0 (OpenCV convention; + 0.5 for COLMAP's).
    Fisheye models use ``cv2.fisheye.estimateNewCameraMatrixForUndistortRectify`` with balance 0 (one
    focal length, fitted to the four edge midpoints; it measures to the image edge, so the remap tables
    may reach up to half a pixel past the outer pixel centres: remap with ``BORDER_REPLICATE``).
    """
    import cv2

    width, height = camera.width, camera.height
    K = opencv_K(camera)
    if camera.is_fisheye:
        new_K = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
            K, camera.distortion(), (width, height), np.eye(3), balance=0.0
        )
        fx, fy, cx, cy = (float(v) for v in (new_K[0, 0], new_K[1, 1], new_K[0, 2] + 0.5, new_K[1, 2] + 0.5))
        return Camera.pinhole(fx, fy, cx, cy, width, height)
    # border pixel centres, OpenCV convention (0 .. W-1), every pixel
    xs, ys = np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)
    left = np.stack([np.zeros_like(ys), ys], 1)
    right = np.stack([np.full_like(ys, width - 1), ys], 1)
    top = np.stack([xs, np.zeros_like(xs)], 1)
    bottom = np.stack([xs, np.full_like(xs, height - 1)], 1)
    border = np.concatenate([left, right, top, bottom]).reshape(-1, 1, 2)
    normalized = cv2.undistortPoints(border, K, camera.distortion(), criteria=_CRITERIA).reshape(-1, 2)
    n_y, n_x = height, width
    x0 = normalized[:n_y, 0].max()
    x1 = normalized[n_y : 2 * n_y, 0].min()
    y0 = normalized[2 * n_y : 2 * n_y + n_x, 1].max()
    y1 = normalized[2 * n_y + n_x :, 1].min()
    if not (np.isfinite([x0, x1, y0, y1]).all() and x1 > x0 and y1 > y0):
        raise ValueError(f"{camera.model} camera {camera.params}: its distortion leaves no valid pinhole image")
    fx, fy = float((width - 1) / (x1 - x0)), float((height - 1) / (y1 - y0))
    # back to COLMAP's convention: + 0.5
    return Camera.pinhole(fx, fy, float(-fx * x0) + 0.5, float(-fy * y0) + 0.5, width, height)


def undistortion_maps(camera: Camera) -> tuple[np.ndarray, np.ndarray, Camera]:
    """Remap tables that turn ``camera``'s images into images of ``undistorted_camera(camera)``.

    Returns (map_x, map_y, pinhole): map_x, map_y are (H, W) float32 in OpenCV's convention, ready for
    ``cv2.remap(image, map_x, map_y, ...)``: output pixel [y, x] samples the input at (map_x[y, x],
    map_y[y, x]), both with pixel centres at integers. ``pinhole`` is the PINHOLE camera (COLMAP
    convention) of the output. Each entry is the forward distortion of the output pixel's ray, so the
    tables are exact (no iteration), and with zero distortion they are the identity.
    """
    import cv2

    pinhole = undistorted_camera(camera)
    size = (camera.width, camera.height)
    # both camera matrices in OpenCV's convention (cx - 0.5): the tables index pixels with centres at integers
    K, new_K = opencv_K(camera), opencv_K(pinhole)
    if camera.is_fisheye:
        map_x, map_y = cv2.fisheye.initUndistortRectifyMap(K, camera.distortion(), np.eye(3), new_K, size, cv2.CV_32FC1)
    else:
        map_x, map_y = cv2.initUndistortRectifyMap(K, camera.distortion(), np.eye(3), new_K, size, cv2.CV_32FC1)
    return map_x, map_y, pinhole
