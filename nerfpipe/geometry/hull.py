"""The visual hull: the space every photo's silhouette allows the object to fill (Laurentini 1994).

A point of the object projects onto the object's silhouette in every photo that sees it, so a cell of a
grid that projects onto the backdrop of some photo holds nothing (shape from silhouettes, "space carving").
Where the photos come with silhouettes -- rendered captures with alpha, photos in front of a constant backdrop
-- this bounds the object before any training: ``visual_hull`` carves a grid over a box, and ``hull_box`` is
the box of what is left, which the fields and the occupancy grid then spend their resolution on.

A cell is judged by a sphere around it, not by its centre: it is carved from a photo only when the disc that
sphere projects to (radius ``f r / z`` pixels, plus ``slack_px`` for pose and mask error) holds no silhouette
pixel, looked up in the distance transform of the photo's backdrop (OpenCV). Masks found by colour make
mistakes, so a cell is carved only when more than ``tolerance`` of the photos that see it call it backdrop.
And a cell only a few photos see is not constrained by them: in the narrow view of a camera close to it, it
lies in front of the object (the corners of a box around an object shot with a long lens). The hull keeps
only cells at least ``min_share`` of the photos see, as the object is: what fewer photos see, too few photos
could train either.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from nerfpipe.geometry.normalize import project

Box = tuple[np.ndarray, np.ndarray]


def cell_centers(lo: np.ndarray, hi: np.ndarray, resolution: int) -> np.ndarray:
    """(R^3, 3) centres of a ``resolution``^3 grid over [lo, hi], cell (i, j, k) along x, y, z at row
    (i R + j) R + k (the occupancy grid's order)."""
    axes = [lo[a] + (np.arange(resolution) + 0.5) * (hi[a] - lo[a]) / resolution for a in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def visual_hull(silhouettes: Sequence[np.ndarray], intrinsics: np.ndarray, c2ws: np.ndarray, box: Box,
                resolution: int = 64, tolerance: float = 0.05, min_share: float = 0.1, slack_px: float = 2.0) -> np.ndarray:
    """Cells of a ``resolution``^3 grid over ``box`` that the silhouettes leave standing.

    Args:
        silhouettes: per photo, (H, W) bool, True on the object.
        intrinsics: (I, 4) fx, fy, cx, cy of each photo's pinhole camera (COLMAP pixel convention).
        c2ws: (I, 4, 4) camera-to-world poses, OpenCV convention (looking along +z).
        box: (lo, hi), (3,) corners in world units.
        tolerance: share of the photos seeing a cell that may call it backdrop without carving it.
        min_share: share of the photos (at least 2) that must see a cell for it to stay.
        slack_px: pixels added to each cell's projected radius (pose error, mask edges).
    Returns:
        (R, R, R) bool over x, y, z: False for carved cells and for cells too few photos see.
    """
    lo, hi = (np.asarray(b, dtype=np.float64) for b in box)
    centers = cell_centers(lo, hi, resolution)
    radius = 0.5 * float(np.linalg.norm((hi - lo) / resolution))  # the sphere around a cell
    seen = np.zeros(len(centers), dtype=np.int32)
    misses = np.zeros(len(centers), dtype=np.int32)
    for mask, (fx, fy, cx, cy), c2w in zip(silhouettes, np.asarray(intrinsics, dtype=np.float64), c2ws):
        h, w = mask.shape
        uv, z = project(c2w, np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), centers)
        u, v = uv[:, 0], uv[:, 1]
        inside = (z > 1e-9) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        # pixels to the nearest silhouette pixel (0 on the silhouette); a photo with none carves all it sees
        background = np.ascontiguousarray(~mask, dtype=np.uint8)
        distance = cv2.distanceTransform(background, cv2.DIST_L2, 5) if mask.any() else np.full(mask.shape, np.inf, np.float32)
        col = np.clip(u[inside].astype(np.int64), 0, w - 1)
        row = np.clip(v[inside].astype(np.int64), 0, h - 1)
        reach = max(fx, fy) * radius / z[inside] + slack_px
        seen[inside] += 1
        misses[inside] += distance[row, col] > reach
    enough = max(2, int(np.ceil(min_share * len(silhouettes))))
    return ((seen >= enough) & (misses <= tolerance * seen)).reshape((resolution,) * 3)


def hull_box(hull: np.ndarray, box: Box, margin_cells: float = 1.0) -> Box | None:
    """The box of a hull's cells (each cell whole), grown by ``margin_cells`` cells on every side and kept
    inside ``box``; None for an empty hull.

    hull: (R, R, R) bool over x, y, z of a grid over ``box`` (``visual_hull``)."""
    if not hull.any():
        return None
    lo, hi = (np.asarray(b, dtype=np.float64) for b in box)
    r = np.array(hull.shape, dtype=np.float64)
    occupied = np.argwhere(hull)
    cell = (hi - lo) / r
    new_lo = lo + (occupied.min(axis=0) - margin_cells) * cell
    new_hi = lo + (occupied.max(axis=0) + 1 + margin_cells) * cell
    return np.maximum(new_lo, lo), np.minimum(new_hi, hi)


@dataclass(frozen=True)
class Silhouettes:
    """The object's silhouette in each of a set of photos, with their cameras (``visual_hull``'s arguments).

    masks: per photo (H, W) bool, True on the object; intrinsics: (I, 4) fx, fy, cx, cy; c2ws: (I, 4, 4) OpenCV.
    """

    masks: list[np.ndarray]
    intrinsics: np.ndarray
    c2ws: np.ndarray

    def hull(self, box: Box, resolution: int, tolerance: float) -> np.ndarray:
        """(R, R, R) bool: ``visual_hull`` of these photos over ``box``."""
        return visual_hull(self.masks, self.intrinsics, self.c2ws, box, resolution, tolerance)
