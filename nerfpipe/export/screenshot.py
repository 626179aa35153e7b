"""Pictures of meshes, point clouds and camera frusta, with or without a display.

A run directory is often on a headless machine (a GPU server, CI), and Open3D's own offscreen renderer
needs Vulkan or EGL that such machines may not have. So ``screenshot`` is a small CPU renderer of its own:
meshes through Open3D's ``RaycastingScene`` (Embree, one ray per pixel), point clouds as z-buffered
splats and frusta as lines, all in numpy and OpenCV. ``show`` opens Open3D's interactive viewer when
there is a display and writes a screenshot when there is not.

Cameras are pinholes in nerfpipe's convention (``nerfpipe.geometry.cameras``): OpenCV axes (x right,
y down, looking along +z), camera-to-world ``c2w``, and the centre of the top-left pixel at (0.5, 0.5).
"""

from __future__ import annotations

import logging
import math
import os
import socket
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from nerfpipe.geometry.cameras import Camera, CameraSet, invert_pose, look_at
from nerfpipe.pipeline.errors import InputError, NerfpipeError

if TYPE_CHECKING:  # Open3D is optional: imported inside the functions that need it
    import open3d as o3d

log = logging.getLogger(__name__)

FOV_Y_DEG = 50.0  # vertical field of view of ``auto_view``
FRUSTUM_RGB = (255, 100, 0)  # orange: stands out on white, black, grey meshes and most photo colours
MESH_GREY = 0.72
DEFAULT_UP = np.array([0.0, 0.0, 1.0])  # world up when no capture camera says otherwise

# A frustum: apex, the image corners (top-left, top-right, bottom-right, bottom-left) at depth ``size``,
# and the tip of a triangle on the top edge that marks the image's "up".
FRUSTUM_POINTS = 6
FRUSTUM_LINES = np.array([[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4], [4, 1], [1, 5], [5, 2]])


def _open3d() -> Any:
    try:
        import open3d
    except ImportError:
        raise NerfpipeError("showing meshes and point clouds needs Open3D; install it with `pip install open3d`") from None
    return open3d


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
        return ViewCamera((camera.fx, camera.fy, camera.cx, camera.cy), c2w, camera.width, camera.height)

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


def _frusta_segments(cameras: Sequence[ViewCamera], size: float) -> np.ndarray:
    """(len(cameras) * FRUSTUM_LINES, 2, 3) world segments of all frusta."""
    if not cameras:
        return np.zeros((0, 2, 3))
    points = np.stack([frustum_points(c, size) for c in cameras])  # (C, P, 3)
    return points[:, FRUSTUM_LINES].reshape(-1, 2, 3)


def frusta_lineset(cameras: Sequence[ViewCamera], size: float) -> o3d.geometry.LineSet:
    """One pyramid per camera, apex at its centre and base the image rectangle at depth ``size``, plus a
    triangle on the top edge that shows which way the image is up.

    Camera i owns points [FRUSTUM_POINTS i, FRUSTUM_POINTS (i + 1)) (the first is its apex) and lines
    [len(FRUSTUM_LINES) i, len(FRUSTUM_LINES) (i + 1)).
    """
    o3d = _open3d()
    lines = o3d.geometry.LineSet()
    if not cameras:
        return lines
    points = np.concatenate([frustum_points(c, size) for c in cameras])
    index = (FRUSTUM_LINES[None] + FRUSTUM_POINTS * np.arange(len(cameras))[:, None, None]).reshape(-1, 2)
    lines.points = o3d.utility.Vector3dVector(points)
    lines.lines = o3d.utility.Vector2iVector(index.astype(np.int32))
    lines.colors = o3d.utility.Vector3dVector(np.tile(np.array(FRUSTUM_RGB) / 255.0, (len(index), 1)))
    return lines


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


def _look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
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

    return _framing(target, radius, direction, up, width, height)


def _framing(target: np.ndarray, radius: float, direction: np.ndarray, up: np.ndarray, width: int,
             height: int) -> ViewCamera:
    """A ``FOV_Y_DEG`` camera on ``target + distance * direction`` (direction: a unit (3,)) looking at ``target``
    with image-up along ``up``, where the sphere of ``radius`` around ``target`` fits both fields of view with
    a 5% margin."""
    fy = (height / 2) / math.tan(math.radians(FOV_Y_DEG) / 2)
    half_fov = min(math.radians(FOV_Y_DEG) / 2, math.atan((width / 2) / fy))
    distance = 1.05 * radius / math.sin(half_fov)  # the cone of half-angle half_fov touches the sphere
    c2w = _look_at(target + distance * direction, target, up)
    return ViewCamera((fy, fy, width / 2, height / 2), c2w, width, height)


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
    return _framing(target, radius, direction / np.linalg.norm(direction), -camera.c2w[:3, 1], width, height)


# -- rendering ----------------------------------------------------------------------------------------


def _render_mesh(mesh: o3d.geometry.TriangleMesh, view: ViewCamera) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast a mesh, headlight Lambert shading: colour (0.25 + 0.75 |n . d|) per pixel.

    Returns:
        depth: (H, W) camera z of the first hit, inf where no triangle is hit; rgb: (H, W, 3) in [0, 1].
    """
    o3d = _open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    origins, directions = view.pixel_rays()
    rays = np.concatenate([origins, directions], axis=-1).astype(np.float32)
    hits = scene.cast_rays(o3d.core.Tensor(rays))
    t_hit = hits["t_hit"].numpy()  # in units of the direction, whose z is 1: the depth
    hit = np.isfinite(t_hit)
    rgb = np.zeros((len(rays), 3))
    ids = hits["primitive_ids"].numpy()[hit].astype(np.int64)
    if mesh.has_vertex_colors():
        # primitive_uvs (a, b) are barycentrics: p = (1 - a - b) v0 + a v1 + b v2
        ab = hits["primitive_uvs"].numpy()[hit].astype(np.float64)
        weights = np.stack([1.0 - ab[:, 0] - ab[:, 1], ab[:, 0], ab[:, 1]], axis=-1)
        corner_colors = np.asarray(mesh.vertex_colors)[np.asarray(mesh.triangles)[ids]]  # (n, 3, 3)
        base = np.einsum("nk,nkc->nc", weights, corner_colors)
    else:
        base = np.full((len(ids), 3), MESH_GREY)
    normals = hits["primitive_normals"].numpy()[hit].astype(np.float64)
    d = directions[hit] / np.linalg.norm(directions[hit], axis=-1, keepdims=True)
    cosine = np.abs(np.sum(normals * d, axis=-1)) / np.maximum(np.linalg.norm(normals, axis=-1), 1e-12)
    rgb[hit] = np.clip(base * (0.25 + 0.75 * cosine)[:, None], 0.0, 1.0)
    depth = np.where(hit, t_hit, np.inf)
    return depth.reshape(view.height, view.width), rgb.reshape(view.height, view.width, 3)


def _disc_offsets(radius: int) -> list[tuple[int, int]]:
    # r^2 + r rather than r^2 rounds the disc: radius 1 is the full 3x3 block, radius 2 a 21-pixel disc
    r = int(radius)
    return [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if dy * dy + dx * dx <= r * r + r]


def _splat_points(
    xyz: np.ndarray, rgb: np.ndarray, view: ViewCamera, radius: int
) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffered disc splats of ``radius`` pixels; where splats overlap the nearest point wins.

    Two passes, so the cost of the splat size does not grow with the number of points: first the nearest
    point of each pixel, then a min-depth filter with the disc over that image. Both give the same
    picture as drawing every disc with a depth test.

    Args:
        xyz: (N, 3) world points; rgb: (N, 3) in [0, 1].
    Returns:
        depth: (H, W), inf where no splat; rgb: (H, W, 3).
    """
    H, W, r = view.height, view.width, int(radius)
    uv, z = view.project(xyz)
    with np.errstate(invalid="ignore"):
        ok = (z > 0) & np.all(np.isfinite(uv), axis=-1)
        col = np.floor(uv[:, 0], where=ok, out=np.zeros(len(z)))
        row = np.floor(uv[:, 1], where=ok, out=np.zeros(len(z)))
    # padded by r, so points just off the image still spill their disc onto it
    ok &= (col >= -r) & (col < W + r) & (row >= -r) & (row < H + r)
    col, row, z, rgb = col[ok].astype(np.int64) + r, row[ok].astype(np.int64) + r, z[ok], rgb[ok]
    Wp, Hp = W + 2 * r, H + 2 * r
    index = row * Wp + col
    order = np.lexsort((z, index))  # by pixel, then nearest first
    first = order[np.r_[True, index[order][1:] != index[order][:-1]]] if len(order) else order
    nearest_z = np.full(Hp * Wp, np.inf)
    nearest_rgb = np.zeros((Hp * Wp, 3))
    nearest_z[index[first]] = z[first]
    nearest_rgb[index[first]] = rgb[first]
    nearest_z, nearest_rgb = nearest_z.reshape(Hp, Wp), nearest_rgb.reshape(Hp, Wp, 3)

    depth = np.full((H, W), np.inf)
    out = np.zeros((H, W, 3))
    for dy, dx in _disc_offsets(r):
        shifted_z = nearest_z[r + dy : r + dy + H, r + dx : r + dx + W]
        nearer = shifted_z < depth
        depth[nearer] = shifted_z[nearer]
        out[nearer] = nearest_rgb[r + dy : r + dy + H, r + dx : r + dx + W][nearer]
    return depth, out


def _clip_segments(p0: np.ndarray, p1: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """Liang-Barsky clipping of 2D segments to the box [lo, hi].

    Args:
        p0, p1: (M, 2); lo, hi: (2,).
    Returns:
        keep: (M,) bool; q0, q1: (M, 2) clipped end points (meaningful where ``keep``).
    """
    d = p1 - p0
    t0, t1 = np.zeros(len(p0)), np.ones(len(p0))
    keep = np.ones(len(p0), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in range(2):
            for p, q in ((-d[:, axis], p0[:, axis] - lo[axis]), (d[:, axis], hi[axis] - p0[:, axis])):
                parallel = p == 0
                keep &= ~(parallel & (q < 0))
                t = q / p
                t0 = np.where(~parallel & (p < 0), np.maximum(t0, t), t0)
                t1 = np.where(~parallel & (p > 0), np.minimum(t1, t), t1)
    keep &= t0 <= t1
    return keep, p0 + t0[:, None] * d, p0 + t1[:, None] * d


def _draw_segments(image: np.ndarray, segments: np.ndarray, view: ViewCamera, color: tuple[int, int, int]) -> None:
    """Draw world segments (M, 2, 3) into ``image`` (H, W, 3) uint8, no depth test; the parts behind the
    camera are cut off at a near plane first, since a projection through z <= 0 flips them across the image."""
    import cv2

    if len(segments) == 0:
        return
    cam = view.to_camera_frame(segments.reshape(-1, 3)).reshape(-1, 2, 3)
    near = 1e-6 * max(1.0, float(np.abs(cam).max()))
    za, zb = cam[:, 0, 2], cam[:, 1, 2]
    keep = (za > near) | (zb > near)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip((near - za) / (zb - za), 0.0, 1.0)  # where the segment crosses z = near
    crossing = cam[:, 0] + t[:, None] * (cam[:, 1] - cam[:, 0])
    a = np.where((za > near)[:, None], cam[:, 0], crossing)
    b = np.where((zb > near)[:, None], cam[:, 1], crossing)
    fx, fy, cx, cy = view.intrinsics
    focal, centre = np.array([fx, fy]), np.array([cx, cy])
    with np.errstate(divide="ignore", invalid="ignore"):
        # cv2 puts integer coordinates on pixel centres; ours are at +0.5
        pa = a[:, :2] / a[:, 2:] * focal + centre - 0.5
        pb = b[:, :2] / b[:, 2:] * focal + centre - 0.5
    keep &= np.all(np.isfinite(pa), axis=-1) & np.all(np.isfinite(pb), axis=-1)
    pa, pb = pa[keep], pb[keep]
    # clipped in float first: cv2 takes int32 coordinates, which a point near the camera plane overflows
    inside, pa, pb = _clip_segments(pa, pb, np.array([-2.0, -2.0]), np.array([view.width + 1.0, view.height + 1.0]))
    shift = 4  # sub-pixel end points: cv2 reads coordinates as fixed point with 4 fractional bits
    thickness = max(1, round(min(view.width, view.height) / 400))
    starts = np.round(pa[inside] * 2**shift).astype(int)
    ends = np.round(pb[inside] * 2**shift).astype(int)
    for (x0, y0), (x1, y1) in zip(starts, ends, strict=True):
        cv2.line(image, (int(x0), int(y0)), (int(x1), int(y1)), color, thickness, cv2.LINE_AA, shift)


def _bounds(
    mesh: o3d.geometry.TriangleMesh | None, points: o3d.geometry.PointCloud | None, extra: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    parts = [extra.reshape(-1, 3)]
    if mesh is not None:
        parts.append(np.asarray(mesh.vertices).reshape(-1, 3))
    if points is not None:
        parts.append(np.asarray(points.points).reshape(-1, 3))
    xyz = np.concatenate(parts)
    xyz = xyz[np.all(np.isfinite(xyz), axis=-1)]
    return (xyz.min(axis=0), xyz.max(axis=0)) if len(xyz) else None


def screenshot(
    mesh: o3d.geometry.TriangleMesh | None = None,
    points: o3d.geometry.PointCloud | None = None,
    cameras: Sequence[ViewCamera] = (),
    width: int = 800,
    height: int = 600,
    view: ViewCamera | None = None,
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
    *,
    frustum_size: float | None = None,
    point_radius: int = 2,
) -> np.ndarray:
    """Render a mesh, a point cloud and camera frusta on the CPU, with no display and no GPU.

    The mesh is ray-cast (vertex colours where it has them, else grey) with headlight Lambert shading;
    points are disc splats of ``point_radius`` pixels (their colours where they have them, else dark grey),
    depth-tested against each other and against the mesh; frusta are drawn over everything in orange.

    Args:
        width, height: the image size of the automatic view; a given ``view`` brings its own size.
        view: the camera to render from; by default ``auto_view`` of everything given (frusta included).
        background: RGB in [0, 1].
        frustum_size: depth of the frusta's image plane; by default ``default_frustum_size``.
    Returns:
        (H, W, 3) uint8 RGB.
    """
    cameras = list(cameras)
    if mesh is not None and not mesh.has_triangles():
        mesh = None
    if frustum_size is None:
        frustum_size = default_frustum_size(cameras, _bounds(mesh, points, np.zeros((0, 3))))
    segments = _frusta_segments(cameras, frustum_size)
    if view is None:
        bounds = _bounds(mesh, points, segments.reshape(-1, 3))
        if bounds is None:
            raise ValueError("nothing to draw: give a mesh, points or cameras, or a view")
        view = auto_view(bounds[0], bounds[1], cameras, width, height)

    H, W = view.height, view.width
    depth = np.full((H, W), np.inf)
    image = np.broadcast_to(np.asarray(background, dtype=np.float64), (H, W, 3)).copy()
    if mesh is not None:
        mesh_depth, mesh_rgb = _render_mesh(mesh, view)
        hit = np.isfinite(mesh_depth)
        image[hit], depth = mesh_rgb[hit], mesh_depth
    if points is not None and points.has_points():
        xyz = np.asarray(points.points)
        rgb = np.asarray(points.colors) if points.has_colors() else np.full((len(xyz), 3), 0.25)
        point_depth, point_rgb = _splat_points(xyz, rgb, view, point_radius)
        # 1% slack: points sampled from the surface itself must not lose to it by rounding
        visible = point_depth < depth * 1.01
        image[visible] = point_rgb[visible]
    out = np.round(np.clip(image, 0.0, 1.0) * 255).astype(np.uint8)
    _draw_segments(out, segments, view, FRUSTUM_RGB)
    return out


# -- interactive viewer or screenshot ---------------------------------------------------------------


def has_display() -> bool:
    """Whether a window could open: ``DISPLAY`` or ``WAYLAND_DISPLAY`` is set *and* its server answers.

    A stale ``DISPLAY`` (an ssh session without forwarding, a dead X server) is common, and Open3D then
    falls back to an invisible offscreen window whose event loop never returns.
    """
    wayland = os.environ.get("WAYLAND_DISPLAY", "")
    if wayland:
        runtime = Path(os.environ.get("XDG_RUNTIME_DIR", "/nonexistent"))
        if (Path(wayland) if os.path.isabs(wayland) else runtime / wayland).exists():
            return True
    display = os.environ.get("DISPLAY", "")
    if not display or ":" not in display:
        return False
    host, _, number = display.rpartition(":")
    if host.startswith("/"):  # macOS launchd socket: /private/tmp/com.apple.launchd.xxx/org.xquartz:0
        return os.path.exists(display)
    try:
        n = int(number.split(".")[0])
    except ValueError:
        return False
    if host in ("", "unix"):
        return os.path.exists(f"/tmp/.X11-unix/X{n}")
    try:
        with socket.create_connection((host, 6000 + n), timeout=0.5):
            return True
    except OSError:
        return False


def _open_window(vis: Any, title: str, width: int, height: int) -> bool:
    """Open ``vis``'s window; False when Open3D could only make an offscreen context.

    Open3D >= 0.19 falls back to EGL offscreen rendering when GLFW finds no display and still reports
    success; the only sign is its log line, so its output is captured while the window opens.
    """
    o3d = _open3d()
    sys.stdout.flush()
    sys.stderr.flush()
    with tempfile.TemporaryFile() as captured:
        saved = os.dup(1), os.dup(2)
        try:
            os.dup2(captured.fileno(), 1)
            os.dup2(captured.fileno(), 2)
            with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Info):
                opened = vis.create_window(window_name=title, width=width, height=height)
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
        captured.seek(0)
        text = captured.read().decode("utf-8", errors="replace")
    log.debug("open3d window: %s", text.strip())
    if opened and "offscreen" in text.lower():
        vis.destroy_window()
        return False
    return bool(opened)


def show(
    mesh: o3d.geometry.TriangleMesh | None = None,
    points: o3d.geometry.PointCloud | None = None,
    cameras: Sequence[ViewCamera] = (),
    *,
    screenshot_path: Path,
    title: str = "nerfpipe",
    width: int = 800,
    height: int = 600,
    frustum_size: float | None = None,
) -> Path | None:
    """Open Open3D's interactive viewer when there is a display (``has_display``); otherwise, or when no
    window opens on it, write ``screenshot(...)`` to ``screenshot_path`` as a PNG.

    Returns:
        None after the window was closed, or ``screenshot_path`` (a PNG) when no window could open.
    """
    cameras = list(cameras)
    if frustum_size is None:
        frustum_size = default_frustum_size(cameras, _bounds(mesh, points, np.zeros((0, 3))))
    if has_display():
        try:
            o3d = _open3d()
            vis = o3d.visualization.Visualizer()
            if _open_window(vis, title, width, height):
                if mesh is not None:
                    # a copy: the viewer's lighting needs normals, and the caller's mesh stays as it was
                    mesh = o3d.geometry.TriangleMesh(mesh)
                    if not mesh.has_vertex_normals():
                        mesh.compute_vertex_normals()
                for geometry in (mesh, points, frusta_lineset(cameras, frustum_size) if cameras else None):
                    if geometry is not None:
                        vis.add_geometry(geometry)
                vis.run()
                vis.destroy_window()
                return None
            log.warning("could not open a window on this display; writing a screenshot instead")
        except (RuntimeError, NerfpipeError) as err:
            log.warning("could not open a window (%s); writing a screenshot instead", err)

    import cv2

    image = screenshot(mesh, points, cameras, width, height, frustum_size=frustum_size)
    screenshot_path = Path(screenshot_path)
    screenshot_path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(screenshot_path), np.ascontiguousarray(image[..., ::-1])):
        raise InputError(screenshot_path, "could not be written", "check that the folder is writable")
    return screenshot_path


# -- reading exports ----------------------------------------------------------------------------------


def load_mesh(path: Path) -> o3d.geometry.TriangleMesh:
    """A triangle mesh file (PLY, OBJ, ...); InputError when it is missing, unreadable or has no triangles."""
    o3d = _open3d()
    if not Path(path).is_file():
        raise InputError(path, "does not exist", "rerun the stage that writes it")
    mesh = o3d.io.read_triangle_mesh(str(path))
    if not mesh.has_triangles():
        raise InputError(path, "has no triangles (empty or damaged)", "rerun the stage that writes it with --force")
    return mesh


def load_points(path: Path) -> o3d.geometry.PointCloud:
    """A point cloud file (PLY, PCD, ...); InputError when it is missing, unreadable or empty."""
    o3d = _open3d()
    if not Path(path).is_file():
        raise InputError(path, "does not exist", "rerun the stage that writes it")
    cloud = o3d.io.read_point_cloud(str(path))
    if not cloud.has_points():
        raise InputError(path, "has no points (empty or damaged)", "rerun the stage that writes it with --force")
    return cloud


def sparse_points(camera_set: CameraSet) -> o3d.geometry.PointCloud | None:
    """The SfM points of a camera set as a coloured point cloud, or None when it has none."""
    if camera_set.points is None or len(camera_set.points.xyz) == 0:
        return None
    o3d = _open3d()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(camera_set.points.xyz, dtype=np.float64)))
    cloud.colors = o3d.utility.Vector3dVector(np.asarray(camera_set.points.rgb, dtype=np.float64) / 255.0)
    return cloud
