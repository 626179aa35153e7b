"""Camera paths for novel-view videos: a spiral for forward-facing captures, an orbit for 360° ones.

A forward-facing capture only constrains what lies in front of its cameras, so a path must stay close to
them: LLFF's spiral (Mildenhall et al. 2019, ``render_path_spiral``, the path of the NeRF paper's
forward-facing videos) circles the mean camera within the spread of the captured positions, every pose
looking at one focus point ahead. A 360° capture surrounds its object, so the path may go all the way
round: a level circle at the distance and elevation the photos were taken from, looking at the object.

Every function is pure numpy and returns (N, 4, 4) camera-to-world poses in the OpenCV convention of
``nerfpipe.geometry.cameras`` (x right, y down, the camera looks along +z), in the frame of the input poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# the mean camera of the train stage, so the spiral circles the very frame a forward model's NDC rays use
from nerfpipe.geometry.cameras import look_at, mean_camera
from nerfpipe.geometry.normalize import Similarity

# (``dt = .75`` in its ``load_llff_data``), a depth a little behind the nearest content.
FOCUS_DISPARITY_WEIGHT = 0.75
# The orbit's auto elevation stays this far off the poles: straight above the target a camera's x axis
# (perpendicular to up and to the viewing axis) is undefined.
MAX_AUTO_ELEVATION_DEG = 85.0


def _check_poses(c2ws: np.ndarray) -> np.ndarray:
    c2ws = np.asarray(c2ws, dtype=np.float64)
    if c2ws.ndim != 3 or c2ws.shape[1:] != (4, 4) or len(c2ws) == 0:
        raise ValueError(f"c2ws must be (M, 4, 4) with M >= 1, got {c2ws.shape}")
    return c2ws


def _check_frames(n_frames: int) -> None:
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")


# -- spiral (forward-facing) ------------------------------------------------------------------------------
def focus_depth(near: float, far: float, weight: float = FOCUS_DISPARITY_WEIGHT) -> float:
    """LLFF's focus depth: 1 / ((1 - w) / near + w / far), the depth at disparity (1 - w) / near + w / far.

    By hand, near 1, far 10, w 0.75: 1 / (0.25 + 0.075) = 3.077.
    """
    if not 0.0 < near < far:
        raise ValueError(f"need 0 < near < far, got near {near}, far {far}")
    return 1.0 / ((1.0 - weight) / near + weight / far)


def spiral_radii(c2ws: np.ndarray, percentile: float = 90.0) -> np.ndarray:
    """(3,) radii of the spiral along the mean camera's x, y, z: the ``percentile`` of |camera centre -
    mean centre| per axis of the mean camera's frame (LLFF takes the 90th of its recentred poses)."""
    c2ws = _check_poses(c2ws)
    if not 0.0 <= percentile <= 100.0:
        raise ValueError(f"radius_percentile must be in [0, 100], got {percentile}")
    mean = mean_camera(c2ws)
    local = (c2ws[:, :3, 3] - mean[:3, 3]) @ mean[:3, :3]  # (M, 3) positions in the mean camera's frame
    return np.percentile(np.abs(local), percentile, axis=0)


def spiral_path(c2ws: np.ndarray, near: float, far: float, n_frames: int, n_rotations: float = 2,
                radius_percentile: float = 90.0, zrate: float = 0.5) -> np.ndarray:
    """LLFF's spiral around the mean camera of a forward-facing capture.

    Frame k at angle theta_k = 2 pi n_rotations k / n_frames sits at (OpenCV axes of the mean camera)::

        c = mean_centre + R (r_x cos theta, r_y sin theta, r_z sin(zrate theta))

    (LLFF's (cos, -sin, -sin) in its OpenGL axes, whose y and z point the other way), with ``r`` from
    ``spiral_radii``; it looks at the focus point ``mean_centre + focus_depth(near, far) * mean_z`` and
    keeps the mean camera's down axis as its own, made perpendicular to its viewing axis.

    Args:
        c2ws: (M, 4, 4) captured poses; near, far: scene depth bounds (along the viewing axis).
        n_frames: N; the angles run over [0, 2 pi n_rotations), so a whole number of rotations loops.
    Returns:
        (N, 4, 4) poses.
    """
    c2ws = _check_poses(c2ws)
    _check_frames(n_frames)
    mean = mean_camera(c2ws)
    rotation, center = mean[:3, :3], mean[:3, 3]
    radii = spiral_radii(c2ws, radius_percentile)
    focus = center + focus_depth(near, far) * rotation[:, 2]
    down = rotation[:, 1]
    poses = []
    for theta in np.linspace(0.0, 2.0 * np.pi * n_rotations, n_frames + 1)[:-1]:
        local = radii * np.array([np.cos(theta), np.sin(theta), np.sin(theta * zrate)])
        poses.append(look_at(center + rotation @ local, focus, down))
    return np.stack(poses)


# -- orbit (360°) -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Orbit:
    """A circle of cameras around ``target``: unit ``up`` axis, ``radius`` (distance of every camera from
    the target), ``elevation`` in degrees above the plane through the target perpendicular to up, and
    ``start`` (3,), the unit horizontal direction from the target to the first camera."""

    target: np.ndarray
    up: np.ndarray
    radius: float
    elevation: float
    start: np.ndarray


def orbit_of(c2ws: np.ndarray, target: np.ndarray, elevation: float | None = None) -> Orbit:
    """The orbit a 360° capture suggests: up = -(mean of the cameras' y axes), the cameras' median distance
    from ``target``, their mean elevation above it (or ``elevation`` degrees, in (-90, 90)), starting at the
    first camera's azimuth so the video begins near a photographed view."""
    c2ws = _check_poses(c2ws)
    target = np.asarray(target, dtype=np.float64).reshape(3)
    up = -c2ws[:, :3, 1].mean(axis=0)
    if np.linalg.norm(up) < 1e-6:
        raise ValueError("the cameras' down axes cancel out; no up direction for an orbit")
    up /= np.linalg.norm(up)
    offsets = c2ws[:, :3, 3] - target
    distances = np.linalg.norm(offsets, axis=1)
    if np.median(distances) <= 0.0:
        raise ValueError("the cameras sit on the orbit target; no orbit radius")
    if elevation is None:
        heights = offsets @ up
        sines = np.divide(heights, distances, out=np.zeros_like(heights), where=distances > 0)
        elevation = float(np.degrees(np.arcsin(np.clip(sines, -1.0, 1.0))).mean())
        elevation = float(np.clip(elevation, -MAX_AUTO_ELEVATION_DEG, MAX_AUTO_ELEVATION_DEG))
    elif not -90.0 < elevation < 90.0:
        raise ValueError(f"elevation must be in (-90, 90) degrees, got {elevation}")
    # the first camera's horizontal direction; if it sits exactly above the target, any horizontal axis
    start = offsets[0] - (offsets[0] @ up) * up
    if np.linalg.norm(start) < 1e-9 * max(distances[0], 1.0):
        start = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    start /= np.linalg.norm(start)
    return Orbit(target, up, float(np.median(distances)), float(elevation), start)


def orbit_path(c2ws: np.ndarray, target: np.ndarray, n_frames: int, elevation: float | None = None) -> np.ndarray:
    """A circle around the up axis through ``target`` (see ``orbit_of``), every pose looking at the target.

    Frame k at azimuth phi_k = 2 pi k / n_frames (counter-clockwise seen from above) sits at::

        c = target + radius (cos(el) (cos phi s + sin phi (up x s)) + sin(el) up)

    with s the start direction, so all frames are at the same distance and the same height; each pose's y
    axis is -up made perpendicular to its viewing axis, so the horizon stays level and the image upright.

    Args:
        c2ws: (M, 4, 4) captured poses; target: (3,); elevation: degrees, None for the cameras' mean.
    Returns:
        (N, 4, 4) poses.
    """
    _check_frames(n_frames)
    orbit = orbit_of(c2ws, target, elevation)
    el = np.radians(orbit.elevation)
    side = np.cross(orbit.up, orbit.start)
    poses = []
    for phi in np.linspace(0.0, 2.0 * np.pi, n_frames + 1)[:-1]:
        horizontal = np.cos(phi) * orbit.start + np.sin(phi) * side
        eye = orbit.target + orbit.radius * (np.cos(el) * horizontal + np.sin(el) * orbit.up)
        poses.append(look_at(eye, orbit.target, -orbit.up))
    return np.stack(poses)


# -- choosing -----------------------------------------------------------------------------------------------
LAYOUTS = ("forward", "inward360", "unbounded360")


def path_for_scene(layout: str, c2ws: np.ndarray, near: float, far: float, target: np.ndarray, n_frames: int,
                   *, kind: str = "auto", n_rotations: float = 2, elevation: float | None = None
                   ) -> tuple[np.ndarray, str]:
    """The path that suits the scene's ``layout``: the spiral for "forward", the orbit around ``target``
    for "inward360" and "unbounded360"; ``kind`` ("spiral" / "orbit") overrides the choice.

    Returns:
        (N, 4, 4) poses and one line saying which path and why, with its size.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"unknown scene layout {layout!r}; expected one of {', '.join(LAYOUTS)}")
    if kind not in ("auto", "spiral", "orbit"):
        raise ValueError(f"path kind must be auto, spiral or orbit, got {kind!r}")
    chosen = kind if kind != "auto" else "spiral" if layout == "forward" else "orbit"
    why = f"{layout} scene" if kind == "auto" else f"asked for, {layout} scene"
    if chosen == "spiral":
        poses = spiral_path(c2ws, near, far, n_frames, n_rotations)
        radii = spiral_radii(c2ws)
        text = (f"spiral ({why}): {n_rotations:g} turns around the mean camera, radii "
                f"{radii[0]:.3g} x {radii[1]:.3g} x {radii[2]:.3g}, looking at depth {focus_depth(near, far):.3g}")
    else:
        poses = orbit_path(c2ws, target, n_frames, elevation)
        orbit = orbit_of(c2ws, target, elevation)
        centre = ", ".join(f"{0.0 if abs(v) < 1e-9 else v:.3g}" for v in orbit.target)  # no "-1.11e-16"
        source = "given" if elevation is not None else "the cameras' mean"
        text = (f"orbit ({why}): radius {orbit.radius:.3g} around ({centre}) at "
                f"{orbit.elevation:.1f} deg elevation ({source})")
    return poses, text


def transform_poses(c2ws: np.ndarray, similarity: np.ndarray) -> np.ndarray:
    """Poses (N, 4, 4) moved by a 4x4 similarity [s R | t] (e.g. bounds' ``to_sfm``): centres go through
    the similarity, rotations through R alone, so the results stay rigid camera-to-world matrices."""
    c2ws = np.asarray(c2ws, dtype=np.float64)
    similarity = np.asarray(similarity, dtype=np.float64)
    if similarity.shape != (4, 4):
        raise ValueError(f"similarity must be (4, 4), got {similarity.shape}")
    try:
        return Similarity.from_matrix(similarity).apply_c2w(c2ws)
    except ValueError:
        raise ValueError("similarity must preserve orientation (positive determinant)") from None
