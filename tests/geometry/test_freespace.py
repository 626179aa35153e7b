"""The least depth of the sparse points over a photo's cells: hand-computed grids, and the points each frame sees."""

from __future__ import annotations

import numpy as np

from nerfpipe.geometry.cameras import Camera, CameraSet, Frame, Points
from nerfpipe.geometry.freespace import frame_least_depths, grid_shape, least_depths

INF = np.inf


def test_cells_are_square_with_sixteen_along_the_longer_side() -> None:
    assert grid_shape(900, 1600) == (16, 9)
    assert grid_shape(400, 300) == (12, 16)
    assert grid_shape(100, 100, cells=4) == (4, 4)


def test_each_cell_takes_the_least_depth_near_it_and_empty_ones_their_neighbours_once() -> None:
    # a 24 x 4 photo in a row of six 4 x 4 cells; one point in cell 0 at depth 3, one in cell 3 at 7: each holds
    # its cell and the two beside it (cell 1 the lesser, 3), and cell 5, with none near it, cell 4's once filled
    uv = np.array([[1.0, 1.0], [13.0, 2.0], [22.0, 2.0], [30.0, 2.0], [9.0, 2.0]])
    depth = np.array([3.0, 7.0, -1.0, 1.0, 0.0])  # behind the camera, off the photo, at the camera: left out
    assert np.array_equal(least_depths(uv, depth, 24, 4, (1, 6)), [[3.0, 3.0, 7.0, 7.0, 7.0, 7.0]])
    # the first point alone: its 3 x 3 neighbourhood (cells 0, 1), then the empty cells beside those once (cell 2)
    assert np.array_equal(least_depths(uv[:1], depth[:1], 24, 4, (1, 6)), [[3.0, 3.0, 3.0, INF, INF, INF]])
    # two rows: a nearer point below wins in every cell around it, the diagonals included
    two = least_depths(np.array([[1.0, 1.0], [5.0, 6.0]]), np.array([3.0, 2.0]), 16, 8, (2, 4))
    assert np.array_equal(two, [[2.0, 2.0, 2.0, 2.0], [2.0, 2.0, 2.0, 2.0]])
    assert np.array_equal(least_depths(np.zeros((0, 2)), np.zeros(0), 16, 8, (2, 4)), np.full((2, 4), INF))


def test_a_frame_counts_only_the_points_it_observes_in_its_own_camera() -> None:
    camera = Camera.pinhole(100.0, 100.0, 100.0, 50.0, 200, 100)  # a 200 x 100 photo: cells of 12.5 px, 8 rows
    ahead = np.eye(4)
    turned = np.diag([-1.0, 1.0, -1.0, 1.0])  # looking down -z
    xyz = np.array([[0.0, 0.0, 4.0], [0.0, 0.0, 2.0], [0.0, 0.0, -5.0]])
    points = Points(xyz, np.zeros((3, 3), np.uint8), np.zeros(3), [np.array([0]), np.array([0, 1, 2])])
    world = CameraSet({1: camera}, [Frame("a", 1, ahead), Frame("b", 1, turned)], points)
    least = frame_least_depths(world, world.frames)
    assert least.shape == (2, 8, 16)
    # the point at z = 4 projects to the photo's centre (100, 50), the corner of cell (4, 8) it falls in; the
    # 3 x 3 minimum spreads it over rows 3-5 and columns 7-9, and the fill once more over rows 2-6, columns 6-10
    a = np.full((8, 16), INF)
    a[2:7, 6:11] = 4.0
    assert np.array_equal(least[0], a)
    # frame b sees the point at z = 2 behind it (left out) and the one at z = -5 at depth 5 ahead
    b = np.full((8, 16), INF)
    b[2:7, 6:11] = 5.0
    assert np.array_equal(least[1], b)
    assert frame_least_depths(CameraSet({1: camera}, world.frames, None), world.frames) is None
