"""Scene normalization and near/far bounds: pure numpy maths on camera rigs and sparse points.

The normalized world nerfpipe trains in is fixed by these choices, the same for every capture:

- **z is up.** The rig's up direction (``up_direction``) is rotated onto +z, so "above the object" and
  "the floor" mean the same thing in every scene, and a viewer's turntable turns about z.
- **The yaw is fixed by the first camera:** after the up alignment, the first camera whose optical axis
  is not (nearly) vertical looks along +y (its heading is +y). Without this the result would depend on
  the yaw of whatever frame SfM happened to pick.
- **The region of interest is centred on the origin and fits the unit cube [-1, 1]^3.** The region is the
  robust box of the sparse points (outliers rejected), or, with no points, the box of the cameras centred
  on the rig's look-at centre (inward-facing rigs) or on the cameras' centroid (forward-facing ones).

So the result is invariant to any similarity transform (rotation, uniform scale, translation) of the
SfM frame: SfM reconstructions are only defined up to one, and two runs of the same capture should train
in the same world.

Near/far bounds follow NeRF (Mildenhall et al. 2020): a ray r(t) = o + t d is integrated between near and
far bounds t_n and t_f (Section 4, Eq. 1), and Section 5.3 takes "scene bounds" from ground truth for
synthetic scenes and from COLMAP for real ones. For real captures we take them, as LLFF does for the
paper's forward-facing scenes (Section 6.1), from the depths of the sparse points each image sees
(``near_far_from_points``); with no points (an imported ``transforms.json``) from the rig geometry
(``near_far_from_rig``), which for the synthetic 360° scenes reproduces their usual near/far of 2 / 6.

Conventions: ``c2w`` are (4, 4) OpenCV camera-to-world matrices (x right, y down, the camera looks along
+z), so a camera's optical axis is ``c2w[:3, 2]`` and its up vector is ``-c2w[:3, 1]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nerfpipe.geometry.rig import look_at_center, optical_axes, rig_kind, unit

WORLD_UP = np.array([0.0, 0.0, 1.0])
WORLD_HEADING = np.array([0.0, 1.0, 0.0])



@dataclass(frozen=True)
class Similarity:
    """x' = s R x + t: a uniform scale ``scale`` (s > 0), a rotation ``rotation`` (3, 3) and a translation (3,)."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def apply_points(self, xyz: np.ndarray) -> np.ndarray:
        """(..., 3) points -> (..., 3) points, x' = s R x + t."""
        xyz = np.asarray(xyz, dtype=np.float64)
        return self.scale * xyz @ self.rotation.T + self.translation

    def apply_c2w(self, c2w: np.ndarray) -> np.ndarray:
        """(..., 4, 4) camera-to-world -> (..., 4, 4) in the new frame.

        The rotation block becomes R R_c (still orthonormal: a camera is never scaled), the centre
        becomes s R o + t, so distances from the camera scale by s.
        """
        c2w = np.asarray(c2w, dtype=np.float64)
        out = c2w.copy()
        out[..., :3, :3] = self.rotation @ c2w[..., :3, :3]
        out[..., :3, 3] = self.apply_points(c2w[..., :3, 3])
        return out

    def inverse(self) -> "Similarity":
        """x = R^T (x' - t) / s, i.e. scale 1/s, rotation R^T, translation -R^T t / s."""
        rotation = self.rotation.T
        return Similarity(1.0 / self.scale, rotation, -(rotation @ self.translation) / self.scale)

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix [[s R, t], [0, 1]]."""
        out = np.eye(4)
        out[:3, :3] = self.scale * self.rotation
        out[:3, 3] = self.translation
        return out

    @staticmethod
    def from_matrix(matrix: np.ndarray) -> "Similarity":
        """Inverse of ``matrix()``: s is the cube root of det(s R) (s > 0 for a proper similarity)."""
        matrix = np.asarray(matrix, dtype=np.float64)
        scale = float(np.cbrt(np.linalg.det(matrix[:3, :3])))
        if scale <= 0:
            raise ValueError("not a similarity with positive scale (a reflection or a degenerate matrix)")
        return Similarity(scale, matrix[:3, :3] / scale, matrix[:3, 3].copy())


def up_vectors(c2ws: np.ndarray) -> np.ndarray:
    """(N, 4, 4) c2w -> (N, 3) unit image-up vectors (OpenCV -y axis in world)."""
    return unit(-np.asarray(c2ws, dtype=np.float64)[:, :3, 1])


def up_direction(
    c2ws: np.ndarray, ring_flatness: float = 0.2, ring_max_axis_cos: float = 0.7, level_max_angle_deg: float = 30.0
) -> np.ndarray:
    """The rig's up direction, (N, 4, 4) c2w -> (3,) unit vector.

    Default: u = normalize(sum_i up_i), the mean of the cameras' up vectors (-y of OpenCV c2w). People
    hold cameras level, so this is the world's up for handheld and forward-facing captures. When the
    cameras' right vectors pin down a horizontal plane (``level_horizon_up``) whose normal lies within
    ``level_max_angle_deg`` of u, that normal is returned instead: it is exact for level cameras on a
    sphere, where the mean up vector is biased.

    Photos turned a quarter (a phone held sideways for landscape photos of a standing scene, or the other way):
    then the cameras' y axes are the level ones and the mean up vector is horizontal. When the right vectors
    are not level but the y axes are (``level_horizon_up`` with ``axis=1``), their normal is returned, its
    sign chosen so the cameras look down on average.

    Ring rigs (turntables, gantries, orbits) are handled separately, because their cameras may be rolled
    (the Middlebury temple images are shot sideways, and half of a ring may be upside down): when the
    camera centres lie close to a plane (singular values s1 >= s2 >= s3 of the centred positions with
    s3 < ``ring_flatness`` * s2, and s2 > ``ring_flatness`` * s1 so it is not a line) and the cameras look
    across that plane rather than along its normal (median |d_i . n| < ``ring_max_axis_cos``, which rules
    out forward-facing rigs, whose centres also lie in a plane, normal to their common viewing direction),
    the up direction is the plane's normal n (the last right-singular vector). Its sign agrees with the mean
    up vector when that is decisive (|n . u| >= 0.25 |u|), else it is chosen so the cameras look down on
    average (sum_i d_i . n <= 0): photographers and gantries shoot objects from above more often than from
    below.
    """
    c2ws = np.asarray(c2ws, dtype=np.float64)
    mean_up = up_vectors(c2ws).sum(axis=0)
    centers = c2ws[:, :3, 3]
    if len(centers) >= 3:
        _, sv, vt = np.linalg.svd(centers - centers.mean(axis=0))
        normal = vt[2]
        flat = sv[1] > 0 and sv[2] < ring_flatness * sv[1] and sv[1] > ring_flatness * sv[0]
        if flat:
            across = np.median(np.abs(optical_axes(c2ws) @ normal)) < ring_max_axis_cos
            if across:
                along_up = float(normal @ mean_up)
                if abs(along_up) >= 0.25 * np.linalg.norm(mean_up) and along_up != 0.0:
                    return normal * np.sign(along_up)
                looking = float(optical_axes(c2ws).sum(axis=0) @ normal)
                return -normal if looking > 0 else normal
    norm = np.linalg.norm(mean_up)
    if norm < 1e-9:
        raise ValueError("the cameras' up vectors cancel out; cannot tell which way is up")
    mean_up = mean_up / norm
    level = level_horizon_up(c2ws)
    if level is not None and float(level @ mean_up) >= np.cos(np.radians(level_max_angle_deg)):
        return level
    turned = level_horizon_up(c2ws, axis=1) if level is None else None
    return mean_up if turned is None else turned


def level_horizon_up(c2ws: np.ndarray, planarity: float = 0.05, spread: float = 0.1, axis: int = 0) -> np.ndarray | None:
    """Up as the direction perpendicular to every camera's right vector, or ``None`` when that is ill-posed.

    A camera held level (no roll) has a horizontal x axis, so up is the eigenvector of
    S = (1/N) sum_i x_i x_i^T with the smallest eigenvalue l1 (l1 <= l2 <= l3). It is used only when the
    right vectors do span a plane (l1 < ``planarity`` * l2) in more than one direction (l2 > ``spread``;
    not so for forward-facing rigs, whose right vectors are all alike). Unlike the mean up vector, it is
    not biased by where on a sphere the cameras are (the mean up of cameras on an upper hemisphere
    looking at its centre tilts towards the side with more cameras). The sign agrees with the mean up.

    ``axis=1``: the same for the cameras' y axes, level in photos turned a quarter; the mean up vector is
    then no guide to the sign, which is chosen so the cameras look down on average.
    """
    c2ws = np.asarray(c2ws, dtype=np.float64)
    level = unit(c2ws[:, :3, axis])
    values, vectors = np.linalg.eigh(level.T @ level / len(level))
    if not (values[0] < planarity * values[1] and values[1] > spread):
        return None
    up = vectors[:, 0]
    if axis == 1:
        return -up if float(optical_axes(c2ws).sum(axis=0) @ up) > 0 else up
    return up if float(up @ up_vectors(c2ws).sum(axis=0)) >= 0 else -up


def rotation_aligning(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) rotation R with R a = b, for unit vectors a, b (3,); the smallest such rotation.

    Rodrigues for the rotation about v = a x b by the angle between them:
    R = I + [v]x + [v]x^2 / (1 + c), c = a . b. That is ill-conditioned as c -> -1, so when a and b point
    into opposite half-spaces (c < 0) we first align a with -b (well-conditioned) and then turn by pi
    about an axis u perpendicular to b (H = 2 u u^T - I maps -b to b).
    """
    a = unit(np.asarray(a, dtype=np.float64))
    b = unit(np.asarray(b, dtype=np.float64))
    c = float(a @ b)
    if c < 0:
        # the least-aligned basis axis gives a well-defined perpendicular
        helper = np.eye(3)[int(np.argmin(np.abs(b)))]
        u = unit(np.cross(b, helper))
        half_turn = 2.0 * np.outer(u, u) - np.eye(3)
        return half_turn @ rotation_aligning(a, -b)
    v = np.cross(a, b)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def rotation_about_z(angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about +z (counter-clockwise seen from above)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def canonical_rotation(c2ws: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(3, 3) rotation taking ``up`` to +z and the first camera's heading to +y.

    The heading is the horizontal part of a camera's optical axis after the up alignment; the first
    camera whose axis is at least ~12° off vertical (horizontal part >= 0.2) is used, else the first
    camera's right vector (x axis). This fixes the yaw that an up alignment alone leaves free.
    """
    align = rotation_aligning(up, WORLD_UP)
    rotated = align @ np.asarray(c2ws, dtype=np.float64)[:, :3, :3]
    heading = None
    for axis_index in (2, 0):
        horizontal = rotated[:, :2, axis_index]
        norms = np.linalg.norm(horizontal, axis=1)
        usable = np.flatnonzero(norms >= 0.2)
        if len(usable):
            heading = horizontal[usable[0]] / norms[usable[0]]
            break
    if heading is None:
        return align
    yaw = np.arctan2(WORLD_HEADING[1], WORLD_HEADING[0]) - np.arctan2(heading[1], heading[0])
    return rotation_about_z(yaw) @ align


def robust_box(points: np.ndarray, quantile: float = 0.01, mad_k: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box (lo (3,), hi (3,)) of ``points`` (N, 3), ignoring stray points.

    Two steps: drop points whose distance r_j = ||x_j - med|| to the coordinate-wise median exceeds
    median(r) + ``mad_k`` * 1.4826 * MAD(r) (MAD = median |r_j - median(r)|, 1.4826 making it a standard
    deviation for Gaussian data); then take the per-axis ``quantile`` and 1 - ``quantile`` quantiles of
    the rest. The box is axis-aligned in the frame of ``points``: call it after rotating to the frame
    whose axes matter (``normalization`` does).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        raise ValueError("robust_box needs at least one point")
    r = np.linalg.norm(points - np.median(points, axis=0), axis=1)
    med = np.median(r)
    mad = np.median(np.abs(r - med))
    kept = points[r <= med + mad_k * 1.4826 * mad] if mad > 0 else points
    if len(kept) < 2:
        kept = points
    return np.quantile(kept, quantile, axis=0), np.quantile(kept, 1.0 - quantile, axis=0)


def normalization(
    c2ws: np.ndarray,
    points: np.ndarray | None = None,
    quantile: float = 0.01,
    mad_k: float = 5.0,
    forward_max_angle_deg: float = 45.0,
    converge_max_angle_deg: float = 25.0,
) -> Similarity:
    """The similarity from the SfM frame to nerfpipe's normalized world; c2ws (N, 4, 4), points (M, 3) or None.

    1. Rotate: R = ``canonical_rotation`` (up -> +z, first camera's heading -> +y).
    2. Region of interest, in the rotated frame: with points, their ``robust_box`` and its centre; without,
       the box of the camera centres, centred on ``look_at_center`` for inward-facing rigs or on the
       cameras' centroid for forward-facing (and outward) ones (``rig_kind``).
    3. Scale s = 1 / max(hi - c, c - lo) over the axes, so the region fits [-1, 1]^3 centred on c.

    Result: x' = s (R x - c), i.e. ``Similarity(s, R, -s c)``.
    """
    c2ws = np.asarray(c2ws, dtype=np.float64)
    if c2ws.ndim != 3 or c2ws.shape[1:] != (4, 4) or len(c2ws) == 0:
        raise ValueError(f"c2ws must be (N, 4, 4) with N >= 1, got {c2ws.shape}")
    rotation = canonical_rotation(c2ws, up_direction(c2ws))
    if points is not None and len(points) > 0:
        lo, hi = robust_box(np.asarray(points, dtype=np.float64) @ rotation.T, quantile, mad_k)
        center = (lo + hi) / 2.0
    else:
        rotated = np.einsum("ij,njk->nik", rotation, c2ws[:, :3, :])
        cams = np.concatenate([rotated, np.tile([[[0.0, 0.0, 0.0, 1.0]]], (len(c2ws), 1, 1))], axis=1)
        centers = cams[:, :3, 3]
        lo, hi = centers.min(axis=0), centers.max(axis=0)
        if rig_kind(cams, forward_max_angle_deg, converge_max_angle_deg) == "inward":
            center = look_at_center(cams)
        else:
            center = centers.mean(axis=0)
    half = float(np.max(np.maximum(hi - center, center - lo)))
    scale = 1.0 / half if half > 1e-12 else 1.0
    return Similarity(scale, rotation, -scale * center)


# -- near / far ------------------------------------------------------------------------------------------
def depths(c2w: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Depths z_c (M,) of world points ``xyz`` (M, 3) in the camera ``c2w`` (4, 4): z_c = d . (x - o)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    return (np.asarray(xyz, dtype=np.float64) - c2w[:3, 3]) @ c2w[:3, 2]


def project(c2w: np.ndarray, K: np.ndarray, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions uv (M, 2) and depths z (M,) of world points ``xyz`` (M, 3) in the pinhole camera K
    (3, 3) at ``c2w`` (4, 4, OpenCV); a point at or behind the camera (z <= 0) gets uv as if at z = 1."""
    c2w = np.asarray(c2w, dtype=np.float64)
    cam = (np.asarray(xyz, dtype=np.float64) - c2w[:3, 3]) @ c2w[:3, :3]
    z = cam[:, 2]
    uv = cam[:, :2] / np.where(z > 0, z, 1.0)[:, None] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    return uv, z


def in_view(c2w: np.ndarray, K: np.ndarray, width: int, height: int, xyz: np.ndarray) -> np.ndarray:
    """(M,) bool: which points (M, 3) project inside the image of a pinhole camera K (3, 3), in front of it."""
    uv, z = project(c2w, K, xyz)
    return (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= width) & (uv[:, 1] >= 0) & (uv[:, 1] <= height)


def near_far_from_points(
    c2w: np.ndarray,
    points_xyz_world: np.ndarray,
    near_percentile: float = 0.1,
    far_percentile: float = 99.9,
    margin: float = 0.1,
    min_points: int = 1,
) -> tuple[float, float] | None:
    """Near/far bounds of one image from the sparse points it sees; c2w (4, 4), points (M, 3).

    With z_j > 0 the depths of the points in front of the camera (``depths``):
    near = P_{near_percentile}(z) * (1 - margin), far = P_{far_percentile}(z) * (1 + margin). The
    percentiles (0.1 / 99.9 by default, as LLFF's ``imgs2poses`` computes the bounds of the paper's
    forward-facing scenes) ignore a few mismatched points; the relative margin keeps surfaces at the
    extremes inside [near, far]. ``None`` when fewer than ``min_points`` points lie in front.
    """
    z = depths(c2w, points_xyz_world)
    z = z[z > 0]
    if len(z) < max(1, min_points):
        return None
    near = float(np.percentile(z, near_percentile)) * (1.0 - margin)
    far = float(np.percentile(z, far_percentile)) * (1.0 + margin)
    return max(near, 0.0), far


def near_far_from_rig(
    c2ws: np.ndarray, center: np.ndarray, radius: float, near_floor: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """Near/far (N,), (N,) of each camera for a scene inside the sphere (``center`` (3,), ``radius``).

    With D_i = ||o_i - center||: near_i = max(D_i - radius, near_floor * radius), far_i = D_i + radius,
    so [near_i, far_i] holds every point of the sphere along any ray (the floor keeps near positive for a
    camera inside the sphere). For the NeRF synthetic scenes (cameras at D = 4, ``radius`` = 2) this
    gives their usual bounds 2 / 6 (Section 5.3: ground-truth bounds for synthetic data).
    """
    c2ws = np.asarray(c2ws, dtype=np.float64)
    dist = np.linalg.norm(c2ws[:, :3, 3] - np.asarray(center, dtype=np.float64), axis=1)
    return np.maximum(dist - radius, near_floor * radius), dist + radius


