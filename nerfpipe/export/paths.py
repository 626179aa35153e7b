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
from nerfpipe.geometry.normalize import WORLD_UP, Similarity
from nerfpipe.geometry.rig import axis_angles_to, azimuth_coverage, azimuth_gaps, look_at_center, unit

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


def orbit_of(c2ws: np.ndarray, target: np.ndarray, elevation: float | None = None,
             up: np.ndarray = WORLD_UP) -> Orbit:
    """The orbit a 360° capture suggests around the world's ``up`` (the bounds stage's +z, whatever the
    photos' roll): the cameras' median distance from ``target``, their mean elevation above it (or
    ``elevation`` degrees, in (-90, 90)), starting at the first camera's azimuth so the video begins near a
    photographed view."""
    c2ws = _check_poses(c2ws)
    target = np.asarray(target, dtype=np.float64).reshape(3)
    up = _unit_up(up)
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


def orbit_path(c2ws: np.ndarray, target: np.ndarray, n_frames: int, elevation: float | None = None,
               up: np.ndarray = WORLD_UP) -> np.ndarray:
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
    orbit = orbit_of(c2ws, target, elevation, up)
    el = np.radians(orbit.elevation)
    side = np.cross(orbit.up, orbit.start)
    poses = []
    for phi in np.linspace(0.0, 2.0 * np.pi, n_frames + 1)[:-1]:
        horizontal = np.cos(phi) * orbit.start + np.sin(phi) * side
        eye = orbit.target + orbit.radius * (np.cos(el) * horizontal + np.sin(el) * orbit.up)
        poses.append(look_at(eye, orbit.target, -orbit.up))
    return np.stack(poses)


def _unit_up(up: np.ndarray) -> np.ndarray:
    up = np.asarray(up, dtype=np.float64).reshape(3)
    if np.linalg.norm(up) < 1e-9:
        raise ValueError("the up direction is the zero vector")
    return unit(up)


# -- sweep (360° captures that do not circle their object) ------------------------------------------------
@dataclass(frozen=True)
class Sweep:
    """Where a capture that does not circle its target stands: azimuths ``lo`` .. ``hi`` (radians about
    ``up`` through ``target``, from the horizontal unit vectors ``e1`` towards ``e2``), and the cameras'
    horizontal distance and height above the target as quadratics of the azimuth (``radius``, ``height``:
    ``np.polyfit`` coefficients), each clamped to the range the cameras span."""

    target: np.ndarray
    up: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    lo: float
    hi: float
    radius: np.ndarray
    height: np.ndarray
    radius_range: tuple[float, float]
    height_range: tuple[float, float]

    def poses(self, n_frames: int) -> np.ndarray:
        """(N, 4, 4) poses out and back along the sweep, easing at both ends so the loop is smooth, looking at
        the target with the horizon level: frame k at azimuth lo + (hi - lo) (1 - cos 2 pi k/N) / 2."""
        _check_frames(n_frames)
        t = np.arange(n_frames) / n_frames
        azimuth = self.lo + (self.hi - self.lo) * (1.0 - np.cos(2.0 * np.pi * t)) / 2.0
        return np.stack([look_at(eye, self.target, -self.up) for eye in self.eye(azimuth)])

    def eye(self, azimuth: np.ndarray) -> np.ndarray:
        """(N, 3) camera centres at ``azimuth`` (N,) radians."""
        r = np.clip(np.polyval(self.radius, azimuth), *self.radius_range)
        h = np.clip(np.polyval(self.height, azimuth), *self.height_range)
        horizontal = np.cos(azimuth)[:, None] * self.e1 + np.sin(azimuth)[:, None] * self.e2
        return self.target + r[:, None] * horizontal + h[:, None] * self.up


def sweep_of(c2ws: np.ndarray, target: np.ndarray, up: np.ndarray = WORLD_UP, spread: float = 10.0) -> Sweep:
    """The sweep of azimuths a capture covers around ``target``, framed on the largest gap between the
    cameras' azimuths (where no photo was taken): azimuths count from the direction opposite the gap's
    middle, and the sweep runs from their ``spread`` to their 100 - ``spread`` percentile, so the path stays
    where photos were taken and never crosses the gap. Cameras nearly above the target do not make or close
    a gap (``geometry.rig.azimuth_gaps``). Raises ``ValueError`` for cameras spread evenly all round the
    target, whose largest gap is not ``GAP_STANDS_OUT`` times their next largest (an orbit suits them)."""
    c2ws = _check_poses(c2ws)
    target = np.asarray(target, dtype=np.float64).reshape(3)
    up = _unit_up(up)
    offsets = c2ws[:, :3, 3] - target
    heights = offsets @ up
    horizontal = offsets - heights[:, None] * up
    r = np.linalg.norm(horizontal, axis=1)
    if np.median(r) <= 1e-9:
        raise ValueError("the cameras stand above the target; no sweep around it")
    frame = _up_frame(up)
    opposite = np.radians(_opposite_largest_gap(_in_frame(c2ws, target, frame)))
    c, s = np.cos(opposite), np.sin(opposite)
    e1, e2 = c * frame[0] + s * frame[1], c * frame[1] - s * frame[0]
    azimuth = np.arctan2(horizontal @ e2, horizontal @ e1)
    degree = min(2, len(np.unique(np.round(azimuth, 6))) - 1)
    radius = np.polyfit(azimuth, r, degree) if degree > 0 else np.array([np.median(r)])
    height = np.polyfit(azimuth, heights, degree) if degree > 0 else np.array([np.median(heights)])
    lo, hi = np.percentile(azimuth, [spread, 100.0 - spread])
    return Sweep(target, up, e1, e2, float(lo), float(hi), radius, height,
                 (float(r.min()), float(r.max())), (float(heights.min()), float(heights.max())))


# a capture is a sweep with a gap in it when its largest gap between azimuths is this many times its next largest
GAP_STANDS_OUT = 1.5


def _opposite_largest_gap(local: np.ndarray) -> float:
    """The azimuth (degrees) opposite the middle of the largest gap between the azimuths of the cameras ``local``
    (N, 4, 4), in a frame whose +z is up and whose origin is the target (``geometry.rig.azimuth_gaps``).
    Raises ``ValueError`` where no gap stands out (``GAP_STANDS_OUT``). By hand, cameras at 0, 90 and 180 deg:
    the gap from 180 to 360 is the largest, its middle at 270, so the sweep centres on 90 deg."""
    az, gaps = azimuth_gaps(local, np.zeros(3))
    if not len(gaps):  # fewer than two cameras round the target: centre on where they stand
        mean = local[:, :2, 3].mean(axis=0)
        return float(np.degrees(np.arctan2(mean[1], mean[0])))
    order = np.argsort(gaps)
    if gaps[order[-1]] < GAP_STANDS_OUT * gaps[order[-2]]:
        raise ValueError("the cameras stand all round the target; an orbit suits them")
    largest = order[-1]
    return float(az[largest] + gaps[largest] / 2.0 + 180.0)


def sweep_path(c2ws: np.ndarray, target: np.ndarray, n_frames: int, up: np.ndarray = WORLD_UP) -> np.ndarray:
    """Out and back along the cameras' sweep around ``target`` (``sweep_of``, ``Sweep.poses``): (N, 4, 4) poses."""
    _check_frames(n_frames)
    return sweep_of(c2ws, target, up).poses(n_frames)


# -- choosing -----------------------------------------------------------------------------------------------
LAYOUTS = ("forward", "inward360", "unbounded360")


# a 360° capture whose cameras cover less azimuth than this gets a sweep: the cup's photos cover 270 deg, and
# 40 % of its orbit (azimuths 108-252 deg from the first photo) rendered fog; the temple's ring of 16 covers 318
ORBIT_MIN_COVERAGE_DEG = 300.0


def path_for_scene(layout: str, c2ws: np.ndarray, near: float, far: float, target: np.ndarray, n_frames: int,
                   *, kind: str = "auto", n_rotations: float = 2, elevation: float | None = None,
                   up: np.ndarray = WORLD_UP) -> tuple[np.ndarray, str]:
    """The path that suits the scene: the spiral for a "forward" layout; for "inward360" and "unbounded360",
    the orbit around ``target`` where the cameras cover at least ``ORBIT_MIN_COVERAGE_DEG`` of azimuth (a
    turntable or a walk all round), else a sweep out and back along the cameras, looking at the point their
    optical axes converge on. ``kind`` ("spiral" / "orbit" / "sweep") overrides the choice; ``up`` is the
    world's up (the bounds stage's +z).

    Returns:
        (N, 4, 4) poses and one line saying which path and why, with its size.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"unknown scene layout {layout!r}; expected one of {', '.join(LAYOUTS)}")
    if kind not in ("auto", "spiral", "orbit", "sweep"):
        raise ValueError(f"path kind must be auto, spiral, orbit or sweep, got {kind!r}")
    c2ws = _check_poses(c2ws)
    coverage = _coverage(c2ws, np.asarray(target, dtype=np.float64), _unit_up(up))
    if kind != "auto":
        chosen, why = kind, f"asked for, {layout} scene"
    elif layout == "forward":
        chosen, why = "spiral", "forward scene"
    elif coverage >= ORBIT_MIN_COVERAGE_DEG:
        chosen, why = "orbit", f"{layout} scene, cameras all round: {coverage:.0f} deg of azimuth"
    else:
        chosen, why = "sweep", f"{layout} scene, cameras on {coverage:.0f} deg of azimuth"
        try:
            sweep_of(c2ws, _focus(c2ws, target), up)
        except ValueError:  # spread all round the centre, though with gaps (a few photos of a turntable)
            chosen, why = "orbit", f"{layout} scene, cameras on {coverage:.0f} deg of azimuth but all round the centre"
    if chosen == "spiral":
        poses = spiral_path(c2ws, near, far, n_frames, n_rotations)
        radii = spiral_radii(c2ws)
        text = (f"spiral ({why}): {n_rotations:g} turns around the mean camera, radii "
                f"{radii[0]:.3g} x {radii[1]:.3g} x {radii[2]:.3g}, looking at depth {focus_depth(near, far):.3g}")
    elif chosen == "orbit":
        poses = orbit_path(c2ws, target, n_frames, elevation, up)
        orbit = orbit_of(c2ws, target, elevation, up)
        source = "given" if elevation is not None else "the cameras' mean"
        text = (f"orbit ({why}): radius {orbit.radius:.3g} around ({_shown(orbit.target)}) at "
                f"{orbit.elevation:.1f} deg elevation ({source})")
    else:
        focus = _focus(c2ws, target)
        _check_frames(n_frames)
        sweep = sweep_of(c2ws, focus, up)
        poses = sweep.poses(n_frames)
        text = (f"sweep ({why}): out and back over {np.degrees(sweep.hi - sweep.lo):.0f} deg of the cameras' "
                f"azimuths at their distance and height, looking at ({_shown(focus)}), where their axes converge")
    return poses, text


def _focus(c2ws: np.ndarray, target: np.ndarray) -> np.ndarray:
    """What a sweep looks at: where the cameras' optical axes converge, or ``target`` (the scene's centre) where
    they meet nowhere useful (at a mean angle of more than 45 degrees, or far beyond the cameras)."""
    focus = look_at_center(c2ws)
    if axis_angles_to(c2ws, focus).mean() > 45.0 or np.linalg.norm(focus - target) > 2.0 * np.linalg.norm(
            c2ws[:, :3, 3] - target, axis=1).max():
        return np.asarray(target, dtype=np.float64)
    return focus


def _up_frame(up: np.ndarray) -> np.ndarray:
    """(3, 3) rows: two horizontal unit axes and ``up`` (unit), a right-handed frame with up along z."""
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(up, e1), up])


def _in_frame(c2ws: np.ndarray, target: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """The poses' centres in ``frame`` (``_up_frame``) about ``target``: what ``geometry.rig``'s azimuth
    functions, which measure about +z, take."""
    local = np.array(c2ws, dtype=np.float64)
    local[:, :3, 3] = (c2ws[:, :3, 3] - target) @ frame.T
    return local


def _coverage(c2ws: np.ndarray, target: np.ndarray, up: np.ndarray) -> float:
    """Degrees of azimuth about ``up`` through ``target`` the cameras cover (``geometry.rig.azimuth_coverage``
    in the frame whose +z is ``up``)."""
    return azimuth_coverage(_in_frame(c2ws, target, _up_frame(up)), np.zeros(3))


def _shown(point: np.ndarray) -> str:
    return ", ".join(f"{0.0 if abs(v) < 1e-9 else v:.3g}" for v in point)  # no "-1.11e-16"


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
