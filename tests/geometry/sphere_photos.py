"""Silhouettes of a sphere photographed from a ring of pinhole cameras, computed exactly."""

from __future__ import annotations

import numpy as np

from nerfpipe.geometry.hull import Silhouettes

CENTER, RADIUS = np.array([0.2, -0.1, 0.0]), 0.3
SIZE, FOCAL = 80, 100.0  # 80 px square images, a 43.6 degree field of view


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """4x4 OpenCV camera-to-world (x right, y down, looking along +z) at ``eye`` looking at ``target``."""
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([x, y, z], axis=1)
    c2w[:3, 3] = eye
    return c2w


def ring(n: int = 12, distance: float = 2.5, height: float = 0.8) -> np.ndarray:
    angles = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.array([look_at(CENTER + [distance * np.cos(a), distance * np.sin(a), height], CENTER) for a in angles])


def sphere_silhouette(c2w: np.ndarray) -> np.ndarray:
    """(SIZE, SIZE) bool: the pixels whose ray (through the pixel centre) passes within RADIUS of CENTER."""
    v, u = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    d = np.stack([(u - SIZE / 2) / FOCAL, (v - SIZE / 2) / FOCAL, np.ones_like(u)], axis=-1) @ c2w[:3, :3].T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    to_center = CENTER - c2w[:3, 3]
    along = d @ to_center
    return np.linalg.norm(to_center) ** 2 - along**2 <= RADIUS**2


def sphere_views(n: int = 12) -> Silhouettes:
    c2ws = ring(n)
    return Silhouettes([sphere_silhouette(c) for c in c2ws], np.tile([FOCAL, FOCAL, SIZE / 2, SIZE / 2], (n, 1)), c2ws)
