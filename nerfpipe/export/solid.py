"""A watertight, manifold surface of the field, for printing and for tools that need a closed solid.

Marching cubes on the density gives a surface with the field's noise in it: tunnels a voxel wide through
thin walls (the temple's mesh has an Euler number of -1240: some 600 handles) and pieces that cross each
other. Here the solid is remeshed on voxels instead (``solid_surface``): the voxels whose density reaches
the surface's threshold are closed morphologically (tunnels and gaps up to about ``2 * close`` voxels wide
are filled), hollow insides are filled, only the largest piece is kept, and the surface is contoured on the
occupancy smoothed by a Gaussian of one voxel, inside a border of empty voxels. An isosurface of a field that
is empty all round its domain is closed, and the smoothing leaves no voxel-sized configurations in which
marching cubes could pinch an edge: the result is watertight and edge-manifold (checked by the tests with
trimesh and Open3D).
"""

from __future__ import annotations

import numpy as np

from nerfpipe.export.mesh import DensityFn, Grid, Mesh, evaluate_density
from nerfpipe.export.o3d import open3d


def occupancy(density: DensityFn, grid: Grid, threshold: float, block: int = 64, device: object = "cpu") -> np.ndarray:
    """(n0 + 1, n1 + 1, n2 + 1) bool: where the density at the grid points reaches ``threshold``, sampled
    block by block."""
    solid = np.zeros(tuple(c + 1 for c in grid.cells), dtype=bool)
    for start, count in grid.blocks(block):
        values = evaluate_density(density, grid.points(start, count), device=device)
        solid[start[0]:start[0] + count[0] + 1, start[1]:start[1] + count[1] + 1,
              start[2]:start[2] + count[2] + 1] = values >= threshold
    return solid


def solid_surface(solid: np.ndarray, origin: np.ndarray, voxel: float, close: int = 4) -> Mesh:
    """The closed surface of the occupied grid points ``solid`` (a lattice from ``origin`` with spacing
    ``voxel``), its tunnels up to about ``2 * close`` voxels wide closed and its largest piece kept.
    Triangles face outward. An empty ``solid`` gives an empty mesh."""
    o3d = open3d()
    from scipy import ndimage

    pad = close + 3
    volume = np.pad(solid, pad)
    if close > 0:
        volume = ndimage.binary_closing(volume, structure=ndimage.generate_binary_structure(3, 1), iterations=close)
    volume = ndimage.binary_fill_holes(volume)
    labels, count = ndimage.label(volume)
    if count == 0:
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    sizes = np.bincount(labels.ravel())[1:]
    volume = labels == 1 + int(np.argmax(sizes))
    smooth = ndimage.gaussian_filter(volume.astype(np.float32), sigma=1.0)
    surface = o3d.t.geometry.TriangleMesh.create_isosurfaces(o3d.core.Tensor(smooth), [0.5])
    # Open3D returns (k, j, i) lattice coordinates; its triangles face increasing values, i.e. inward
    index = surface.vertex.positions.numpy()[:, ::-1].astype(np.float64)
    triangles = surface.triangle.indices.numpy().astype(np.int64)[:, ::-1]
    return Mesh(np.asarray(origin) + voxel * (index - pad), np.ascontiguousarray(triangles))


def watertight(density: DensityFn, grid: Grid, threshold: float, block: int = 64, device: object = "cpu",
               close: int = 4) -> Mesh:
    """The closed, manifold surface of where ``density`` reaches ``threshold`` on ``grid`` (``occupancy``, then
    ``solid_surface`` with tunnels up to about ``2 * close`` voxels closed), in the grid's coordinates. Raises
    ``ValueError`` when nothing reaches the threshold."""
    mesh = solid_surface(occupancy(density, grid, threshold, block, device), grid.origin, grid.voxel, close)
    if mesh.faces == 0:
        raise ValueError("no point of the grid reaches the density threshold")
    return mesh


def closure(mesh: Mesh) -> dict[str, object]:
    """What trimesh and Open3D say of ``mesh``: its triangles, Euler number (2 for a sphere's topology), whether
    it is watertight and whether every edge joins at most two triangles."""
    import trimesh

    from nerfpipe.export.mesh import to_open3d

    checked = trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False)
    return {"faces": mesh.faces, "euler": int(checked.euler_number), "watertight": bool(checked.is_watertight),
            "edge_manifold": bool(to_open3d(mesh).is_edge_manifold())}
