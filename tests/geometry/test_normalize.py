"""Normalization and near/far maths on synthetic rigs whose answers are known by construction."""

from __future__ import annotations

import numpy as np
import pytest

from nerfpipe.geometry import cameras
from nerfpipe.geometry.normalize import (
    Similarity,
    near_far_from_points,
    near_far_from_rig,
    normalization,
    robust_box,
    rotation_aligning,
    up_direction,
)
from nerfpipe.geometry.rig import azimuth_coverage, look_at_center, rig_kind, rig_radius

Z = np.array([0.0, 0.0, 1.0])


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = Z) -> np.ndarray:
    """OpenCV c2w of a level camera at ``eye`` looking at ``target``, image-up along ``up``."""
    return cameras.look_at(eye, target, down=-np.asarray(up))


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def small_rotation(rng: np.random.Generator, degrees: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = np.radians(degrees) * rng.uniform(-1, 1)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def ring_rig(n: int = 24, radius: float = 3.0, height: float = 0.8, tilt_deg: float = 0.0, seed: int = 0) -> np.ndarray:
    """Cameras on a horizontal ring looking at the origin, each rolled/pitched by up to ``tilt_deg``."""
    rng = np.random.default_rng(seed)
    out = []
    for a in np.linspace(0, 2 * np.pi, n, endpoint=False):
        c2w = look_at(np.array([radius * np.cos(a), radius * np.sin(a), height]), np.zeros(3))
        c2w[:3, :3] = c2w[:3, :3] @ small_rotation(rng, tilt_deg)
        out.append(c2w)
    return np.array(out)


def sphere_rig(n: int = 40, radius: float = 4.0, upper_only: bool = False) -> np.ndarray:
    """Fibonacci-sphere cameras at ``radius`` looking at the origin (never exactly at a pole)."""
    i = np.arange(n) + 0.5
    z = (1 - i / n) if upper_only else (1 - 2 * i / n)
    phi = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z**2)
    eyes = radius * np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return np.array([look_at(e, np.zeros(3)) for e in eyes])


def forward_rig(n: int = 20, seed: int = 1) -> np.ndarray:
    """Handheld forward-facing capture: cameras on a 1 x 0.6 patch of the plane y = -5, looking along +y."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        eye = np.array([rng.uniform(-0.5, 0.5), -5.0, rng.uniform(-0.3, 0.3)])
        c2w = look_at(eye, eye + np.array([0.0, 1.0, 0.0]) + rng.normal(scale=0.05, size=3))
        out.append(c2w)
    return np.array(out)


def scene_points(n: int = 3000, seed: int = 2) -> np.ndarray:
    """Points in a 1.2 x 0.8 x 0.6 box off the origin, plus 1% far outliers (SfM mismatches)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-0.6, -0.4, -0.3], [0.6, 0.4, 0.3], (n, 3)) + [0.1, -0.05, 0.2]
    pts[: n // 100] = rng.normal(scale=40.0, size=(n // 100, 3))
    return pts


def moved(c2ws: np.ndarray, points: np.ndarray | None, seed: int) -> tuple[np.ndarray, np.ndarray | None, Similarity]:
    rng = np.random.default_rng(seed)
    sim = Similarity(float(rng.uniform(0.2, 5.0)), random_rotation(rng), rng.normal(scale=10.0, size=3))
    return sim.apply_c2w(c2ws), None if points is None else sim.apply_points(points), sim


# -- similarity -----------------------------------------------------------------------------------------
def test_similarity_apply_inverse_matrix_agree():
    rng = np.random.default_rng(3)
    sim = Similarity(2.5, random_rotation(rng), np.array([1.0, -2.0, 3.0]))
    x = rng.normal(size=(10, 3))
    np.testing.assert_allclose(sim.inverse().apply_points(sim.apply_points(x)), x, atol=1e-12)
    homogeneous = np.c_[x, np.ones(10)] @ sim.matrix().T
    np.testing.assert_allclose(homogeneous[:, :3], sim.apply_points(x), atol=1e-12)
    np.testing.assert_allclose(sim.matrix() @ sim.inverse().matrix(), np.eye(4), atol=1e-12)
    back = Similarity.from_matrix(sim.matrix())
    assert back.scale == pytest.approx(2.5) and np.allclose(back.rotation, sim.rotation)
    # a camera keeps an orthonormal rotation; its centre moves like a point
    c2w = ring_rig(1)[0]
    moved_c2w = sim.apply_c2w(c2w)
    np.testing.assert_allclose(moved_c2w[:3, :3].T @ moved_c2w[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(moved_c2w[:3, 3], sim.apply_points(c2w[:3, 3]), atol=1e-12)
    np.testing.assert_allclose(moved_c2w[3], [0, 0, 0, 1])


def test_rotation_aligning_including_opposite_and_nearly_opposite_vectors():
    rng = np.random.default_rng(4)
    pairs = [(Z, -Z), (np.array([1.0, 0, 0]), np.array([-1.0, 0, 0])), (Z, Z)]
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    near_opposite = -a + 1e-9 * rng.normal(size=3)
    pairs += [(a, near_opposite / np.linalg.norm(near_opposite))]
    pairs += [(v / np.linalg.norm(v), w / np.linalg.norm(w)) for v, w in rng.normal(size=(20, 2, 3))]
    for a, b in pairs:
        R = rotation_aligning(a, b)
        np.testing.assert_allclose(R @ a, b, atol=1e-9)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)


# -- up direction ---------------------------------------------------------------------------------------
def test_up_is_the_ring_normal_for_randomly_tilted_cameras():
    rng = np.random.default_rng(5)
    for seed in range(5):
        rig = ring_rig(tilt_deg=8.0, seed=seed)
        Q = random_rotation(rng)
        rotated, _, _ = moved(rig, None, seed)
        sim_q = Similarity(1.0, Q, np.zeros(3))
        np.testing.assert_allclose(up_direction(sim_q.apply_c2w(rig)), Q @ Z, atol=1e-9)
        # after normalization the ring is horizontal (+z up): every camera at the same height
        world = normalization(rotated).apply_c2w(rotated)
        assert np.ptp(world[:, 2, 3]) < 1e-9
        assert np.mean(world[:, 2, 3]) > 0  # the ring is above the look-at centre it looks down on


def test_up_is_exact_for_level_cameras_on_a_hemisphere():
    # the mean up vector of hemisphere cameras tilts towards where there are more cameras; their level
    # horizons do not
    rig = sphere_rig(30, upper_only=True)[:20]
    np.testing.assert_allclose(up_direction(rig), Z, atol=1e-9)


@pytest.mark.parametrize("quarter", [1, -1], ids=["turned-left", "turned-right"])
def test_up_of_photos_turned_a_quarter_is_the_normal_of_their_level_y_axes(quarter):
    # a phone held sideways, walked along part of a circle above a cup (as ../shared/data/llff_cup_kwrous):
    # the cameras' y axes are level, their x axes point up or down, and their mean up vector is horizontal
    rig = sphere_rig(30, upper_only=True)[:20]
    turn = np.array([[0.0, -quarter, 0.0], [quarter, 0.0, 0.0], [0.0, 0.0, 1.0]])  # about each camera's own z
    turned = rig.copy()
    turned[:, :3, :3] = rig[:, :3, :3] @ turn
    assert np.all(np.abs(turned[:, :3, 1] @ Z) < 1e-9)  # their y axes are horizontal
    np.testing.assert_allclose(up_direction(turned), Z, atol=1e-9)
    Q = random_rotation(np.random.default_rng(6))
    np.testing.assert_allclose(up_direction(Similarity(1.0, Q, np.zeros(3)).apply_c2w(turned)), Q @ Z, atol=1e-9)


def test_up_of_a_forward_facing_rig_is_the_mean_up_vector():
    np.testing.assert_allclose(up_direction(forward_rig()), Z, atol=0.05)


# -- normalization --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "rig,points",
    [(ring_rig(tilt_deg=5.0), scene_points()), (sphere_rig(), None), (forward_rig(), scene_points()), (forward_rig(), None)],
    ids=["ring+points", "sphere", "forward+points", "forward"],
)
def test_normalized_result_is_invariant_to_a_similarity_of_the_input(rig, points):
    reference = normalization(rig, points)
    for seed in range(4):
        rig2, points2, _ = moved(rig, points, seed)
        sim2 = normalization(rig2, points2)
        np.testing.assert_allclose(sim2.apply_c2w(rig2), reference.apply_c2w(rig), atol=1e-9)
        if points is not None:
            np.testing.assert_allclose(sim2.apply_points(points2), reference.apply_points(points), atol=1e-9)


def test_round_trip_to_sfm_and_back():
    rig, points, _ = moved(ring_rig(), scene_points(), 7)
    to_world = normalization(rig, points)
    to_sfm = to_world.inverse()
    np.testing.assert_allclose(to_sfm.apply_points(to_world.apply_points(points)), points, atol=1e-9)
    np.testing.assert_allclose(to_sfm.apply_c2w(to_world.apply_c2w(rig)), rig, atol=1e-9)


def test_robust_box_of_the_points_fills_the_unit_cube():
    rig, points, _ = moved(ring_rig(), scene_points(), 8)
    world = normalization(rig, points).apply_points(points)
    lo, hi = robust_box(world)
    assert np.all(lo >= -1 - 1e-9) and np.all(hi <= 1 + 1e-9)
    assert max(np.max(hi), -np.min(lo)) == pytest.approx(1.0)  # the longest side spans [-1, 1]
    np.testing.assert_allclose((lo + hi) / 2, 0, atol=1e-9)
    # the outliers (1% at ~40x the object size) did not inflate the box: it still spans the object's
    # 1.2 x 0.8 x 0.6 proportions, up to the 1% quantile cut
    np.testing.assert_allclose(np.sort(hi - lo), np.sort([2.0, 0.8 / 1.2 * 2, 0.6 / 1.2 * 2]), rtol=0.05)


def test_without_points_inward_rigs_centre_on_the_look_at_point_and_forward_rigs_on_the_cameras():
    rig = sphere_rig()
    rig[:, :3, 3] += [1.0, 2.0, 3.0]
    assert rig_kind(rig) == "inward"
    np.testing.assert_allclose(look_at_center(rig), [1.0, 2.0, 3.0], atol=1e-9)
    sim = normalization(rig)
    np.testing.assert_allclose(sim.apply_points(np.array([1.0, 2.0, 3.0])), 0, atol=1e-9)
    assert np.abs(sim.apply_c2w(rig)[:, :3, 3]).max() == pytest.approx(1.0)
    fwd = forward_rig()
    assert rig_kind(fwd) == "forward"
    np.testing.assert_allclose(normalization(fwd).apply_c2w(fwd)[:, :3, 3].mean(axis=0), 0, atol=1e-9)


# -- near / far -----------------------------------------------------------------------------------------
def test_near_far_from_points_at_known_depths():
    c2w = look_at(np.zeros(3), np.array([0.0, 1.0, 0.0]))  # looks along +y
    depth = np.arange(1.0, 1001.0)  # 1, 2, ..., 1000
    pts = np.c_[np.zeros(1000), depth, np.zeros(1000)]
    behind = np.c_[np.zeros(50), -np.arange(1.0, 51.0), np.zeros(50)]  # never counted
    # numpy's linear percentile: P_q = 1 + q/100 * 999 -> P_0.1 = 1.999, P_99.9 = 999.001
    near, far = near_far_from_points(c2w, np.r_[pts, behind], 0.1, 99.9, margin=0.0)
    assert near == pytest.approx(1.999) and far == pytest.approx(999.001)
    near, far = near_far_from_points(c2w, pts, 0.1, 99.9, margin=0.1)
    assert near == pytest.approx(1.999 * 0.9) and far == pytest.approx(999.001 * 1.1)
    # sideways offsets do not change a depth (z in the camera, not distance)
    near, far = near_far_from_points(c2w, pts + [3.0, 0.0, -2.0], 0.0, 100.0, margin=0.0)
    assert (near, far) == pytest.approx((1.0, 1000.0))
    assert near_far_from_points(c2w, behind) is None
    assert near_far_from_points(c2w, pts[:5], min_points=10) is None


def test_lego_like_rig_without_points_bounds_contain_the_object():
    rig = sphere_rig(40, radius=4.0)
    sim = normalization(rig)
    world = sim.apply_c2w(rig)
    center = look_at_center(world)
    near, far = near_far_from_rig(world, center, rig_radius(world, center))
    # back in the input's units: the usual 2 / 6 of the NeRF synthetic scenes
    np.testing.assert_allclose(near / sim.scale, 2.0, atol=1e-9)
    np.testing.assert_allclose(far / sim.scale, 6.0, atol=1e-9)
    # every camera's [near, far] holds the whole object sphere (radius 1.5 around the origin)
    obj_center, obj_radius = sim.apply_points(np.zeros(3)), 1.5 * sim.scale
    dist = np.linalg.norm(world[:, :3, 3] - obj_center, axis=1)
    assert np.all(near <= dist - obj_radius) and np.all(far >= dist + obj_radius)


def test_azimuth_coverage():
    assert azimuth_coverage(ring_rig(24), np.zeros(3)) == pytest.approx(345.0)
    assert azimuth_coverage(ring_rig(24)[:7], np.zeros(3)) == pytest.approx(90.0)
