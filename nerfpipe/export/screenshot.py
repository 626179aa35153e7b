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
import os
import socket
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from nerfpipe.export.raster import draw_segments, render_mesh, splat_points
from nerfpipe.export.views import (
    FRUSTUM_LINES,
    FRUSTUM_POINTS,
    ViewCamera,
    default_frustum_size,
    frusta_segments,
    frustum_points,
    subject_view,
)
from nerfpipe.export.o3d import open3d
from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.pipeline.errors import InputError, NerfpipeError

if TYPE_CHECKING:  # Open3D is optional: imported inside the functions that need it
    import open3d as o3d

log = logging.getLogger(__name__)

FRUSTUM_RGB = (255, 100, 0)  # orange: stands out on white, black, grey meshes and most photo colours


def _open3d() -> Any:
    try:
        return open3d()
    except ImportError:
        raise NerfpipeError("showing meshes and point clouds needs Open3D; install it with `pip install open3d`") from None


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


# -- rendering ----------------------------------------------------------------------------------------


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
    frame_cameras: bool = False,
) -> np.ndarray:
    """Render a mesh, a point cloud and camera frusta on the CPU, with no display and no GPU.

    The mesh is ray-cast (vertex colours where it has them, else grey) with headlight Lambert shading;
    points are disc splats of ``point_radius`` pixels (their colours where they have them, else dark grey),
    depth-tested against each other and against the mesh; frusta are drawn over everything in orange.

    Args:
        width, height: the image size of the automatic view; a given ``view`` brings its own size.
        view: the camera to render from; by default ``subject_view`` of the mesh and points (the frusta too
            with ``frame_cameras``, or when there is nothing else), the frusta drawn where they fall.
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
    segments = frusta_segments(cameras, frustum_size)
    if view is None:
        subject = [np.asarray(mesh.vertices)] if mesh is not None else []
        subject += [np.asarray(points.points)] if points is not None and points.has_points() else []
        if frame_cameras or not subject:
            subject.append(segments.reshape(-1, 3))
        xyz = np.concatenate([s.reshape(-1, 3) for s in subject])
        if not len(xyz):
            raise ValueError("nothing to draw: give a mesh, points or cameras, or a view")
        view = subject_view(xyz, cameras, width, height)

    H, W = view.height, view.width
    depth = np.full((H, W), np.inf)
    image = np.broadcast_to(np.asarray(background, dtype=np.float64), (H, W, 3)).copy()
    if mesh is not None:
        mesh_depth, mesh_rgb = render_mesh(mesh, view)
        hit = np.isfinite(mesh_depth)
        image[hit], depth = mesh_rgb[hit], mesh_depth
    if points is not None and points.has_points():
        xyz = np.asarray(points.points)
        rgb = np.asarray(points.colors) if points.has_colors() else np.full((len(xyz), 3), 0.25)
        point_depth, point_rgb = splat_points(xyz, rgb, view, point_radius)
        # 1% slack: points sampled from the surface itself must not lose to it by rounding
        visible = point_depth < depth * 1.01
        image[visible] = point_rgb[visible]
    out = np.round(np.clip(image, 0.0, 1.0) * 255).astype(np.uint8)
    draw_segments(out, segments, view, FRUSTUM_RGB)
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
            # Open3D logs through Python's print: what sits in sys.stdout's buffer (without PYTHONUNBUFFERED)
            # must reach the captured file before the terminal is given back
            sys.stdout.flush()
            sys.stderr.flush()
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
    frame_cameras: bool = False,
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

    image = screenshot(mesh, points, cameras, width, height, frustum_size=frustum_size, frame_cameras=frame_cameras)
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
