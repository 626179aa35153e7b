"""The watertight remesh: a ball with a thin tunnel through it and a speck beside it becomes one closed,
manifold sphere (Euler number 2) of the ball's volume, facing outward; checked with trimesh and Open3D."""

from __future__ import annotations

import numpy as np
import pytest

from nerfpipe.export.mesh import Grid, to_open3d
from nerfpipe.export.solid import occupancy, solid_surface

N = 64


def ball_with_a_tunnel() -> np.ndarray:
    x = np.linspace(-1, 1, N + 1)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    solid = X**2 + Y**2 + Z**2 < 0.6**2
    solid &= ~((np.abs(X) < 0.04) & (np.abs(Y) < 0.04))  # a tunnel about 3 voxels wide, along z
    solid |= (X - 0.85) ** 2 + Y**2 + Z**2 < 0.06**2  # a speck apart from it
    solid[N // 2, N // 2, N // 2 + 3] = False  # and a hollow voxel inside
    return solid


def test_tunnels_close_and_the_largest_piece_is_a_closed_manifold():
    import trimesh

    mesh = solid_surface(ball_with_a_tunnel(), np.array([-1.0, -1.0, -1.0]), 2 / N, close=2)
    solid = trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False)
    assert solid.is_watertight and solid.is_winding_consistent and solid.euler_number == 2  # a sphere: no handle
    assert solid.volume == pytest.approx(4 / 3 * np.pi * 0.6**3, rel=0.03)  # positive: the triangles face outward
    assert np.linalg.norm(mesh.vertices, axis=1).max() < 0.7  # the speck is gone
    other = to_open3d(mesh)
    assert other.is_edge_manifold() and other.is_vertex_manifold() and other.is_watertight()
    assert not other.is_self_intersecting()


def test_without_closing_the_tunnel_stays_and_nothing_solid_is_nothing():
    import trimesh

    mesh = solid_surface(ball_with_a_tunnel(), np.array([-1.0, -1.0, -1.0]), 2 / N, close=0)
    assert trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False).euler_number == 0  # a torus
    assert solid_surface(np.zeros((8, 8, 8), bool), np.zeros(3), 0.1).faces == 0


def test_occupancy_samples_the_density_at_the_grid_points_block_by_block():
    grid = Grid.over((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), 20)
    ball = occupancy(lambda x: (x.norm(dim=-1) < 0.55).float() * 100, grid, 50.0, block=7)  # no point at 0.55
    x = np.linspace(-1, 1, 21)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    assert np.array_equal(ball, np.sqrt(X**2 + Y**2 + Z**2) < 0.55)


def test_watertight_remeshes_a_density_and_closure_says_so():
    from nerfpipe.export.solid import closure, watertight

    grid = Grid.over(np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]), 32)

    def ball(points):  # density 10 inside a ball of radius 0.5, 0 outside (torch points, as a field takes them)
        return 10.0 * (points.norm(dim=-1) < 0.5).float()

    mesh = watertight(ball, grid, threshold=1.0, close=1)
    assert closure(mesh) == {"faces": mesh.faces, "euler": 2, "watertight": True, "edge_manifold": True}
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert 0.4 < radius.mean() < 0.6
    with pytest.raises(ValueError, match="no point of the grid reaches"):
        watertight(ball, grid, threshold=100.0)
