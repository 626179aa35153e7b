"""Virtual cameras for pictures of a scene: the capture's cameras as pinhole views, their frusta, the capture's
up, and views planned to frame a mesh or point cloud (auto_view) or to stand where a photo was taken
(photo_view)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from nerfpipe.geometry.cameras import Camera, CameraSet, invert_pose, look_at

FOV_Y_DEG = 50.0  # vertical field of view of ``auto_view``


DEFAULT_UP = np.array([0.0, 0.0, 1.0])  # world up when no capture camera says otherwise


# A frustum: apex, the image corners (top-left, top-right, bottom-right, bottom-left) at depth ``size``,
# and the tip of a triangle on the top edge that marks the image's "up".
FRUSTUM_POINTS = 6


FRUSTUM_LINES = np.array([[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4], [4, 1], [1, 5], [5, 2]])


@dataclass(frozen=True, eq=False)  # eq=False: an ndarray field has no boolean ==, and identity hashing is what we want
class ViewCamera:
    """A pinhole camera to draw or to render from.

    intrinsics: (fx, fy, cx, cy) in pixels; c2w: (4, 4) camera-to-world, OpenCV axes; width, height: pixels.
    """

    intrinsics: tuple[float, float, float, float]
    c2w: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        c2w = np.array(self.c2w, dtype=np.float64)  # a private copy, so the frozen camera cannot change under us
        if c2w.shape != (4, 4):
            raise ValueError(f"c2w must be (4, 4), got {c2w.shape}")
        c2w.flags.writeable = False
        intrinsics = tuple(float(x) for x in self.intrinsics)
        if len(intrinsics) != 4 or intrinsics[0] <= 0 or intrinsics[1] <= 0:
            raise ValueError(f"intrinsics must be (fx, fy, cx, cy) with fx, fy > 0, got {self.intrinsics}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"image size must be positive, got {self.width} x {self.height}")
        object.__setattr__(self, "c2w", c2w)
        object.__setattr__(self, "intrinsics", intrinsics)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @staticmethod
    def from_camera(camera: Camera, c2w: np.ndarray) -> ViewCamera:
        """The pinhole part of a calibrated camera; lens distortion is left out (it only bends the picture)."""
        return ViewCamera(camera.intrinsics, c2w, camera.width, camera.height)

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates."""
        return self.c2w[:3, 3]

    def to_camera_frame(self, xyz: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (N, 3) points in the camera frame."""
        w2c = invert_pose(self.c2w)
        return np.asarray(xyz, dtype=np.float64) @ w2c[:3, :3].T + w2c[:3, 3]

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel positions of world points: u = fx x/z + cx, v = fy y/z + cy in the camera frame.

        Args:
            xyz: (N, 3) world points.
        Returns:
            uv: (N, 2), pixel (row r, column c) spans [c, c + 1) x [r, r + 1); depth: (N,) camera z. Points
            at or behind the camera (depth <= 0) get non-finite or meaningless uv: test ``depth`` first.
        """
        cam = self.to_camera_frame(xyz)
        fx, fy, cx, cy = self.intrinsics
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([fx * cam[:, 0] / cam[:, 2] + cx, fy * cam[:, 1] / cam[:, 2] + cy], axis=-1)
        return uv, cam[:, 2]

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """One ray per pixel centre, row-major.

        Returns:
            origins: (H * W, 3); directions: (H * W, 3) with a camera-frame z component of 1, so a ray
            parameter t is the depth along the optical axis.
        """
        fx, fy, cx, cy = self.intrinsics
        v, u = np.meshgrid(np.arange(self.height) + 0.5, np.arange(self.width) + 0.5, indexing="ij")
        d_cam = np.stack([(u.ravel() - cx) / fx, (v.ravel() - cy) / fy, np.ones(u.size)], axis=-1)
        directions = d_cam @ self.c2w[:3, :3].T
        return np.broadcast_to(self.center, directions.shape), directions


def cameras_of(camera_set: CameraSet) -> list[ViewCamera]:
    """The registered frames of a camera set as view cameras (what ``show`` draws as frusta)."""
    return [ViewCamera.from_camera(camera_set.camera_of(f), f.c2w) for f in camera_set.frames]


def frustum_points(camera: ViewCamera, size: float) -> np.ndarray:
    """(FRUSTUM_POINTS, 3) world points of one frustum: apex (the camera centre), the four image corners
    at depth ``size`` (top-left, top-right, bottom-right, bottom-left) and the up-marker tip."""
    fx, fy, cx, cy = camera.intrinsics
    w, h = camera.width, camera.height
    pixels = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h], [w / 2, -0.25 * h]])
    corners = np.stack([(pixels[:, 0] - cx) / fx, (pixels[:, 1] - cy) / fy, np.ones(len(pixels))], axis=-1) * size
    local = np.concatenate([np.zeros((1, 3)), corners])
    return local @ camera.c2w[:3, :3].T + camera.c2w[:3, 3]


def frusta_segments(cameras: Sequence[ViewCamera], size: float) -> np.ndarray:
    """(len(cameras) * FRUSTUM_LINES, 2, 3) world segments of all frusta."""
    if not cameras:
        return np.zeros((0, 2, 3))
    points = np.stack([frustum_points(c, size) for c in cameras])  # (C, P, 3)
    return points[:, FRUSTUM_LINES].reshape(-1, 2, 3)


def default_frustum_size(cameras: Sequence[ViewCamera], bounds: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """5% of the diagonal of the camera centres' bounding box; of ``bounds`` (min, max) when the cameras do
    not spread (a single camera); 0.1 when neither has any extent."""
    if len(cameras) > 1:
        centres = np.stack([c.center for c in cameras])
        diagonal = float(np.linalg.norm(centres.max(axis=0) - centres.min(axis=0)))
        if diagonal > 0:
            return 0.05 * diagonal
    if bounds is not None:
        diagonal = float(np.linalg.norm(np.asarray(bounds[1]) - np.asarray(bounds[0])))
        if diagonal > 0:
            return 0.05 * diagonal
    return 0.1


def look_up_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(4, 4) OpenCV c2w at ``eye`` looking at ``target`` with image-up along ``up`` (as far as it can be)."""
    try:
        return look_at(eye, target, down=-up)
    except ValueError:  # looking straight along up: any roll will do
        forward = target - eye
        return look_at(eye, target, down=-np.eye(3)[np.argmin(np.abs(forward))])


def capture_up(cameras: Sequence[ViewCamera]) -> np.ndarray:
    """(3,) unit world "up" of a capture: minus the mean of the cameras' y axes (OpenCV y points down).

    When the cameras disagree on it (|mean| < 0.5: e.g. an orbit shot with the camera rolled 90 degrees,
    as in Middlebury's temple, whose image y axes all lie in the orbit's plane), the normal of the plane
    through the camera centres is used instead, on the side the cameras look down from.
    """
    y_mean = -np.mean([c.c2w[:3, 1] for c in cameras], axis=0)
    if np.linalg.norm(y_mean) >= 0.5 or len(cameras) < 3:
        return y_mean / np.linalg.norm(y_mean) if np.linalg.norm(y_mean) > 1e-6 else DEFAULT_UP
    centres = np.stack([c.center for c in cameras])
    _, s, vt = np.linalg.svd(centres - centres.mean(axis=0))
    if s[1] <= 1e-6 * s[0] or s[2] > 0.5 * s[1]:  # on a line, or not near any one plane
        return y_mean / np.linalg.norm(y_mean) if np.linalg.norm(y_mean) > 1e-6 else DEFAULT_UP
    normal = vt[2]
    looking = np.mean([c.c2w[:3, 2] for c in cameras], axis=0) @ normal
    side = -looking if abs(looking) > 1e-3 else y_mean @ normal
    return normal if side >= 0 else -normal


def auto_view(
    bounds_min: np.ndarray,
    bounds_max: np.ndarray,
    cameras: Sequence[ViewCamera] = (),
    width: int = 800,
    height: int = 600,
) -> ViewCamera:
    """A camera that frames an axis-aligned box, seen from where the capture cameras were.

    It looks at the box centre along d = mean(camera centres) - box centre, with image-up along
    ``capture_up`` (minus the mean of the cameras' y axes, OpenCV y pointing down) and lifted 20 degrees
    towards it, at most 70 degrees above (or below) the horizon. When the cameras stand all around the box
    (d has a small horizontal part), the first camera's side is used. With no cameras: a 3/4 view from
    (1, 1, 1) with world +z up. The distance makes the box's bounding sphere fit both the 50 degree
    vertical field of view and the horizontal one, with a 5% margin.

    Args:
        bounds_min, bounds_max: (3,).
    """
    lo, hi = np.asarray(bounds_min, dtype=np.float64), np.asarray(bounds_max, dtype=np.float64)
    target = (lo + hi) / 2
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    if radius == 0:  # a single point: no scale to go by
        radius = 1.0
    if cameras:
        up = capture_up(cameras)
        offset = np.mean([c.center for c in cameras], axis=0) - target
        if np.linalg.norm(offset - (offset @ up) * up) < 0.2 * radius:
            # the cameras stand all around the box (an orbit): "their side" is where the first one is
            offset = cameras[0].center - target
    else:
        up, offset = DEFAULT_UP, np.array([1.0, 1.0, 1.0])
    horizontal = offset - (offset @ up) * up
    if np.linalg.norm(horizontal) <= 1e-9 * max(radius, float(np.linalg.norm(offset))):  # straight above or below
        horizontal = np.cross(up, np.eye(3)[np.argmin(np.abs(up))])
    elevation = math.atan2(float(offset @ up), float(np.linalg.norm(horizontal)))
    if cameras:
        elevation += math.radians(20)  # lifted a bit: the ground plane of a capture reads better from above
    # never straight down or up, where the image's roll around the view axis would be arbitrary
    elevation = float(np.clip(elevation, -math.radians(70), math.radians(70)))
    direction = math.cos(elevation) * horizontal / np.linalg.norm(horizontal) + math.sin(elevation) * up

    return framing(target, radius, direction, up, width, height)


def framing(target: np.ndarray, radius: float, direction: np.ndarray, up: np.ndarray, width: int,
             height: int) -> ViewCamera:
    """A ``FOV_Y_DEG`` camera on ``target + distance * direction`` (direction: a unit (3,)) looking at ``target``
    with image-up along ``up``, where the sphere of ``radius`` around ``target`` fits both fields of view with
    a 5% margin."""
    fy = (height / 2) / math.tan(math.radians(FOV_Y_DEG) / 2)
    half_fov = min(math.radians(FOV_Y_DEG) / 2, math.atan((width / 2) / fy))
    distance = 1.05 * radius / math.sin(half_fov)  # the cone of half-angle half_fov touches the sphere
    c2w = look_up_at(target + distance * direction, target, up)
    return ViewCamera((fy, fy, width / 2, height / 2), c2w, width, height)


def subject_view(xyz: np.ndarray, cameras: Sequence[ViewCamera] = (), width: int = 800, height: int = 600,
                 keep: float = 0.99) -> ViewCamera:
    """``auto_view``'s direction onto the points ``xyz`` (N, 3), then moved so that they fill the picture:
    centred on their projections' extent and as close as puts every one inside it with a 5% margin. Only
    the middle ``keep`` of the points along each axis count, so that a few stray ones far off (a mesh's
    floaters, a lone SfM point) do not shrink the subject to a speck."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    xyz = xyz[np.all(np.isfinite(xyz), axis=-1)]
    if not len(xyz):
        raise ValueError("nothing to frame")
    lo, hi = np.quantile(xyz, [(1 - keep) / 2, (1 + keep) / 2], axis=0)
    xyz = xyz[np.all((xyz >= lo) & (xyz <= hi), axis=-1)]
    base = auto_view(lo, hi, cameras, width, height)
    axes = base.c2w[:3, :3]  # columns: right, down, forward (OpenCV)
    x, y, z = (xyz @ axes).T
    fx, fy, _, _ = base.intrinsics
    tan_x, tan_y = (width / 2) / fx / 1.05, (height / 2) / fy / 1.05
    cx, cy = (x.min() + x.max()) / 2, (y.min() + y.max()) / 2
    # a point at (x, y, z) in the view's axes lies inside when |x - cx| <= tan_x (z - cz), and so for y
    cz = float(np.min(np.minimum(z - np.abs(x - cx) / tan_x, z - np.abs(y - cy) / tan_y)))
    if np.ptp(x) == 0 and np.ptp(y) == 0:  # one point: keep auto_view's distance
        cz = float(z[0]) - float(np.linalg.norm(base.center - xyz[0]))
    c2w = base.c2w.copy()
    c2w[:3, 3] = axes @ np.array([cx, cy, cz])
    return ViewCamera(base.intrinsics, c2w, width, height)


def photo_view(bounds_min: np.ndarray, bounds_max: np.ndarray, camera: ViewCamera, width: int = 800,
               height: int = 600) -> ViewCamera:
    """A camera that frames an axis-aligned box as a capture camera saw it: from that camera's side of the box
    centre, with its image-up (minus its y axis, as far as it is perpendicular to the new view axis), at the
    distance where the box's bounding sphere fits ``auto_view``'s field of view. A picture of the export
    then reads like the photo (Middlebury's temple lies on its side in every photo, and so in its picture).

    Args:
        bounds_min, bounds_max: (3,).
    """
    lo, hi = np.asarray(bounds_min, dtype=np.float64), np.asarray(bounds_max, dtype=np.float64)
    target = (lo + hi) / 2
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-9)
    direction = camera.center - target
    if np.linalg.norm(direction) <= 1e-9 * radius:  # the camera sits at the centre: look along its own axis
        direction = -camera.c2w[:3, 2]
    return framing(target, radius, direction / np.linalg.norm(direction), -camera.c2w[:3, 1], width, height)
