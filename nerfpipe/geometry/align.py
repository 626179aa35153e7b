"""Similarity alignment of two point sets (Umeyama 1991), used to compare camera rigs up to gauge."""

from __future__ import annotations

import numpy as np


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Scale s, rotation R (3, 3) and translation t (3,) minimising sum |dst_i - (s R src_i + t)|^2.

    ``src``, ``dst``: (N, 3) corresponding points, N >= 3 and not collinear. Closed form of
    S. Umeyama, "Least-squares estimation of transformation parameters between two point patterns",
    TPAMI 1991, Eqs. 40-42: from the SVD of the cross-covariance, with a reflection guard.
    """
    mu_src, mu_dst = src.mean(0), dst.mean(0)
    a, b = src - mu_src, dst - mu_dst
    cov = b.T @ a / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    var_src = (a**2).sum() / len(src)
    s = float(np.trace(np.diag(D) @ S) / var_src)
    t = mu_dst - s * R @ mu_src
    return s, R, t


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a rotation matrix in degrees, from its trace (clipped for round-off)."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))
