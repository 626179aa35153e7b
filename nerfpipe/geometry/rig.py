"""What kind of rig took the photos: where the cameras' optical axes converge, how widely they look around, how
far they stand from the centre and how much of the circle around it they cover; and from that, whether the
capture is forward-facing or looks inward (rig_kind)."""

from __future__ import annotations

from typing import Literal

import numpy as np

RigKind = Literal["forward", "inward", "outward"]


# -- directions ------------------------------------------------------------------------------------------
def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def optical_axes(c2ws: np.ndarray) -> np.ndarray:
    """(N, 4, 4) c2w -> (N, 3) unit viewing directions (OpenCV +z axis in world)."""
    return unit(np.asarray(c2ws, dtype=np.float64)[:, :3, 2])


# -- rig geometry ----------------------------------------------------------------------------------------
def look_at_center(c2ws: np.ndarray) -> np.ndarray:
    """The point closest to all optical axes in the least-squares sense, (N, 4, 4) c2w -> (3,).

    Minimizes sum_i ||(I - d_i d_i^T)(p - o_i)||^2 over p (distance from p to the line o_i + t d_i), whose
    normal equations are (sum_i P_i) p = sum_i P_i o_i with P_i = I - d_i d_i^T. For (nearly) parallel
    axes the system is singular along the common direction; lstsq then returns the minimum-norm solution,
    which callers reject with ``axis_angles_to``.
    """
    c2ws = np.asarray(c2ws, dtype=np.float64)
    d = optical_axes(c2ws)
    o = c2ws[:, :3, 3]
    projectors = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    lhs = projectors.sum(axis=0)
    rhs = np.einsum("nij,nj->i", projectors, o)
    return np.linalg.lstsq(lhs, rhs, rcond=None)[0]


def axis_angles_to(c2ws: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(N,) angles in degrees between each optical axis and the direction from its camera to ``point`` (3,).

    0 means the camera looks straight at the point, 180 that the point is behind it.
    """
    c2ws = np.asarray(c2ws, dtype=np.float64)
    to_point = np.asarray(point, dtype=np.float64)[None] - c2ws[:, :3, 3]
    norms = np.linalg.norm(to_point, axis=1)
    cos = np.einsum("ij,ij->i", optical_axes(c2ws), to_point) / np.maximum(norms, 1e-300)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def viewing_spread(c2ws: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean viewing direction m = normalize(sum_i d_i) (3,) and the angles (N,) in degrees between each d_i and m."""
    d = optical_axes(c2ws)
    total = d.sum(axis=0)
    norm = np.linalg.norm(total)
    if norm < 1e-12:
        return np.zeros(3), np.full(len(d), 90.0)
    mean = total / norm
    return mean, np.degrees(np.arccos(np.clip(d @ mean, -1.0, 1.0)))


def rig_kind(c2ws: np.ndarray, forward_max_angle_deg: float = 45.0, converge_max_angle_deg: float = 25.0) -> RigKind:
    """How a rig looks at its scene, from the poses alone.

    ``forward``: every viewing direction lies within ``forward_max_angle_deg`` of the mean one (the
    paper's real forward-facing scenes, Section 6.1). ``inward``: otherwise, when the cameras look at a
    common point (median angle between an axis and the direction to ``look_at_center`` below
    ``converge_max_angle_deg``). ``outward``: neither (panoramas, walk-throughs).
    """
    c2ws = np.asarray(c2ws, dtype=np.float64)
    _, angles = viewing_spread(c2ws)
    if len(c2ws) < 2 or angles.max() < forward_max_angle_deg:
        return "forward"
    if np.median(axis_angles_to(c2ws, look_at_center(c2ws))) < converge_max_angle_deg:
        return "inward"
    return "outward"


def rig_radius(c2ws: np.ndarray, center: np.ndarray, fraction: float = 0.5) -> float:
    """Radius of the scene sphere assumed around ``center`` when there are no points: ``fraction`` of the
    median camera distance to it (0.5 of 4 = 2 for the NeRF synthetic scenes)."""
    c2ws = np.asarray(c2ws, dtype=np.float64)
    return float(fraction * np.median(np.linalg.norm(c2ws[:, :3, 3] - np.asarray(center), axis=1)))


OVERHEAD_SHARE = 0.5


def azimuth_gaps(c2ws: np.ndarray, center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cameras' azimuths about +z (world up) through ``center``, sorted, in degrees, and the gap after
    each to the next round the circle (they sum to 360). Cameras nearly above the centre (nearer its vertical
    axis than ``OVERHEAD_SHARE`` of the cameras' median distance from it) are left out: their azimuth says
    little about where the photographer walked, and a few shots from overhead would otherwise close the gap
    of a walk part way round. Fewer than two cameras left: two empty arrays."""
    c2ws = np.asarray(c2ws, dtype=np.float64)
    offset = c2ws[:, :2, 3] - np.asarray(center, dtype=np.float64)[:2]
    radius = np.linalg.norm(offset, axis=1)
    keep = (radius > 1e-12) & (radius >= OVERHEAD_SHARE * np.median(radius))
    if keep.sum() < 2:
        return np.zeros(0), np.zeros(0)
    az = np.sort(np.degrees(np.arctan2(offset[keep, 1], offset[keep, 0])))
    return az, np.diff(np.concatenate([az, az[:1] + 360.0]))


def azimuth_coverage(c2ws: np.ndarray, center: np.ndarray) -> float:
    """Degrees of azimuth about +z (world up) through ``center`` that the cameras cover: 360 minus the
    largest of their ``azimuth_gaps`` (360 for a full ring; 0 for fewer than two cameras round it)."""
    _, gaps = azimuth_gaps(c2ws, center)
    return float(360.0 - gaps.max()) if len(gaps) else 0.0
