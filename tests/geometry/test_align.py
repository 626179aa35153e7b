from __future__ import annotations

import numpy as np

from nerfpipe.geometry.align import rotation_angle_deg, umeyama


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return q if np.linalg.det(q) > 0 else -q


def test_umeyama_recovers_a_known_similarity():
    rng = np.random.default_rng(3)
    src = rng.normal(size=(20, 3))
    R = random_rotation(rng)
    dst = 2.5 * src @ R.T + np.array([1.0, -2.0, 0.5])
    s, R_est, t = umeyama(src, dst)
    assert np.isclose(s, 2.5) and np.allclose(R_est, R) and np.allclose(t, [1.0, -2.0, 0.5])
    assert np.allclose(s * src @ R_est.T + t, dst)


def test_umeyama_never_returns_a_reflection():
    rng = np.random.default_rng(4)
    src = rng.normal(size=(10, 3))
    dst = src * np.array([1.0, 1.0, -1.0])  # a mirror image: the best proper rotation, not the mirror
    _, R, _ = umeyama(src, dst)
    assert np.isclose(np.linalg.det(R), 1.0)


def test_rotation_angle():
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    assert np.isclose(rotation_angle_deg(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])), 30.0)
    assert rotation_angle_deg(np.eye(3)) == 0.0
