"""Free space in front of the sparse points: how near a photo's surfaces can be, patch by patch.

Structure from motion's points lie on the surfaces the photos show. Where a patch of a photo sees points,
nothing opaque stands between the camera and the nearest of them, or that point would be hidden: the
photo's rays through the patch cross empty space up to there. That is the reasoning of space carving
(Kutulakos and Seitz 2000) with the sparse points as the surfaces, and what lets a radiance field leave the
space in front of a photo's walls empty rather than fill it with whatever lowers the training loss (the
"floaters" and near-bound screens of a scene seen from inside: docs/benchmarks.md).

Points are few, and a surface without texture holds none: ``least_depths`` takes the least depth over a
patch's 3 x 3 neighbourhood of cells (cells of a sixteenth of the photo's longer side), and the user of it
keeps only a fraction of that depth (``MarchingConfig.carve``).
"""

from __future__ import annotations

import cv2
import numpy as np

from nerfpipe.geometry.cameras import CameraSet, Frame
from nerfpipe.geometry.normalize import project

CELLS = 16  # cells along a photo's longer side


def grid_shape(width: float, height: float, cells: int = CELLS) -> tuple[int, int]:
    """(rows, columns) of square cells, ``cells`` along the longer side of a ``width`` x ``height`` photo."""
    side = max(width, height) / cells
    return max(1, int(np.ceil(height / side - 1e-9))), max(1, int(np.ceil(width / side - 1e-9)))


def least_depths(uv: np.ndarray, depth: np.ndarray, width: float, height: float, shape: tuple[int, int]) -> np.ndarray:
    """The least depth of the points over each cell's 3 x 3 neighbourhood, the photo cut into ``shape`` cells.

    Args:
        uv: (M, 2) pixel positions (pixel edges at integers: the photo spans [0, width] x [0, height]).
        depth: (M,) their depths along the optical axis; points at or behind the camera (<= 0) or off the
            photo are left out.
        shape: (rows, columns) of cells (``grid_shape``).
    Returns:
        (rows, columns) float64: per cell the least depth in its neighbourhood; a cell with no point there takes
        the least of its eight neighbours' (once), and is inf where they have none either.
    """
    rows, cols = shape
    grid = np.full((rows, cols), np.inf, dtype=np.float32)
    keep = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= width) & (uv[:, 1] >= 0) & (uv[:, 1] <= height)
    col = np.minimum((uv[keep, 0] * (cols / width)).astype(np.int64), cols - 1)
    row = np.minimum((uv[keep, 1] * (rows / height)).astype(np.int64), rows - 1)
    np.minimum.at(grid, (row, col), depth[keep].astype(np.float32))
    square = np.ones((3, 3), np.uint8)
    least = cv2.erode(grid, square, borderType=cv2.BORDER_CONSTANT, borderValue=np.inf)  # a 3 x 3 minimum
    least = np.where(np.isfinite(least), least, cv2.erode(least, square, borderType=cv2.BORDER_CONSTANT, borderValue=np.inf))
    return least.astype(np.float64)


def frame_least_depths(world: CameraSet, frames: list[Frame], cells: int = CELLS) -> np.ndarray | None:
    """``least_depths`` of the points each of ``frames`` observes (``Points.visible``), in its own camera.

    Returns:
        (I, rows, columns) over each frame's photo (``grid_shape`` of the first frame's photo; a photo of another
        shape has its cells stretched to as many), inf where a cell has no point near it;
        None where the camera set has no points or no record of which frame sees which.
    """
    points = world.points
    if points is None or len(points.visible) != len(world.frames) or not len(points.xyz):
        return None
    index = {frame.name: i for i, frame in enumerate(world.frames)}
    first = world.camera_of(frames[0])
    rows, cols = grid_shape(first.width, first.height, cells)
    out = np.full((len(frames), rows, cols), np.inf)
    for i, frame in enumerate(frames):
        camera = world.camera_of(frame)
        uv, z = project(frame.c2w, camera.K(), points.xyz[points.visible[index[frame.name]]])
        out[i] = least_depths(uv, z, camera.width, camera.height, (rows, cols))
    return out
