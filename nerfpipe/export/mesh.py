"""Meshes of a radiance field: marching cubes on its density, TSDF fusion of its depth maps, Poisson
reconstruction from its point cloud; cleaning, simplification, and PLY / OBJ / GLB files."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from nerfpipe.geometry.normalize import Similarity
from nerfpipe.export.o3d import open3d

# (M, 3) float32 tensor of field coordinates -> (M,) density
DensityFn = Callable[[Any], Any]


@dataclass
class Mesh:
    """vertices (V, 3) float64, triangles (F, 3) int64, colours (V, 3) in [0, 1] or None."""

    vertices: np.ndarray
    triangles: np.ndarray
    colors: np.ndarray | None = None

    @property
    def faces(self) -> int:
        return len(self.triangles)


@dataclass(frozen=True)
class Grid:
    """A lattice over a box: ``cells`` voxels of edge ``voxel`` per axis from ``origin``; grid points sit on
    voxel corners, so there are cells + 1 per axis."""

    origin: np.ndarray
    voxel: float
    cells: tuple[int, int, int]

    @staticmethod
    def over(box_min: Sequence[float], box_max: Sequence[float], resolution: int) -> "Grid":
        """Cubic voxels, ``resolution`` of them along the box's longest side."""
        lo, hi = np.asarray(box_min, dtype=np.float64), np.asarray(box_max, dtype=np.float64)
        voxel = float((hi - lo).max()) / resolution
        cells = tuple(max(1, int(math.ceil((h - l) / voxel - 1e-9))) for l, h in zip(lo, hi))
        return Grid(lo, voxel, cells)  # type: ignore[arg-type]

    def blocks(self, size: int) -> Iterator[tuple[tuple[int, int, int], tuple[int, int, int]]]:
        """(start, count) in cells of each block of at most ``size`` cells per axis."""
        for i in range(0, self.cells[0], size):
            for j in range(0, self.cells[1], size):
                for k in range(0, self.cells[2], size):
                    start = (i, j, k)
                    yield start, tuple(min(size, c - s) for c, s in zip(self.cells, start))  # type: ignore[misc]

    def points(self, start: Sequence[int], count: Sequence[int]) -> np.ndarray:
        """(n0 + 1, n1 + 1, n2 + 1, 3) grid point positions of a block."""
        axes = [self.origin[a] + self.voxel * np.arange(start[a], start[a] + count[a] + 1) for a in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def evaluate_density(density: DensityFn, points: np.ndarray, chunk: int = 65536, device: Any = "cpu") -> np.ndarray:
    """``density`` at (..., 3) points, ``chunk`` points at a time, without gradients."""
    import torch

    flat = points.reshape(-1, 3)
    out = np.empty(len(flat), dtype=np.float32)
    with torch.no_grad():
        for s in range(0, len(flat), chunk):
            x = torch.as_tensor(flat[s:s + chunk], dtype=torch.float32, device=device)
            out[s:s + chunk] = density(x).float().cpu().numpy().reshape(-1)
    return out.reshape(points.shape[:-1])


def marching_cubes(density: DensityFn, grid: Grid, threshold: float, block: int = 64, chunk: int = 65536,
                   device: Any = "cpu") -> Mesh:
    """The surface where the density crosses ``threshold``, by marching cubes (Open3D's flying-edges
    implementation) on the density sampled at the grid points.

    The grid is processed in blocks of ``block``^3 voxels, each sampled with one layer of overlap and
    contoured on its own, so memory is bounded by the block, whatever the resolution; vertices on shared
    block faces come out identical in both blocks and are merged. Triangles face outward (away from
    high density).
    """
    o3d = open3d()

    vertices, triangles, offset = [], [], 0
    for start, count in grid.blocks(block):
        values = evaluate_density(density, grid.points(start, count), chunk, device)
        if not ((values >= threshold).any() and (values < threshold).any()):
            continue
        surface = o3d.t.geometry.TriangleMesh.create_isosurfaces(o3d.core.Tensor(values), [float(threshold)])
        if surface.is_empty():
            continue
        # Open3D returns (k, j, i) lattice coordinates; its triangles face increasing values, i.e. inward
        index = surface.vertex.positions.numpy()[:, ::-1].astype(np.float64)
        faces = surface.triangle.indices.numpy().astype(np.int64)[:, ::-1]
        vertices.append(grid.origin + grid.voxel * (index + np.asarray(start)))
        triangles.append(faces + offset)
        offset += len(index)
    if not vertices:
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    return merge_vertices(Mesh(np.concatenate(vertices), np.concatenate(triangles)), grid.voxel * 1e-4)


def merge_vertices(mesh: Mesh, tolerance: float) -> Mesh:
    """Weld vertices closer than ``tolerance`` (quantized to it), dropping triangles that collapse."""
    keys = np.round(mesh.vertices / tolerance).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    triangles = inverse[mesh.triangles]
    ok = (triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2]) & (triangles[:, 0] != triangles[:, 2])
    colors = None if mesh.colors is None else mesh.colors[first]
    return Mesh(mesh.vertices[first], triangles[ok], colors)


def vertex_normals(mesh: Mesh) -> np.ndarray:
    """Vertex normals (V, 3), unit length, trimesh's: the mean of the normals of a vertex's triangles,
    weighted by their angles at it (0 for an isolated vertex)."""
    import trimesh

    if not len(mesh.triangles):
        return np.zeros_like(mesh.vertices, dtype=np.float64)
    solid = trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False)
    normals = np.asarray(solid.vertex_normals, dtype=np.float64)
    used = np.zeros(len(mesh.vertices), dtype=bool)
    used[np.asarray(mesh.triangles).reshape(-1)] = True
    return np.where(used[:, None], normals, 0.0)


def to_open3d(mesh: Mesh) -> Any:
    o3d = open3d()

    out = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices.astype(np.float64)),
                                    o3d.utility.Vector3iVector(mesh.triangles.astype(np.int32)))
    if mesh.colors is not None:
        out.vertex_colors = o3d.utility.Vector3dVector(np.clip(mesh.colors, 0.0, 1.0).astype(np.float64))
    return out


def from_open3d(mesh: Any) -> Mesh:
    colors = np.asarray(mesh.vertex_colors).copy() if mesh.has_vertex_colors() else None
    return Mesh(np.asarray(mesh.vertices).copy(), np.asarray(mesh.triangles).astype(np.int64), colors)


def tsdf_fusion(views: Sequence[tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]],
                box: tuple[Sequence[float], Sequence[float]], voxel: float, truncation: float, acc_threshold: float,
                depth_max: float) -> Mesh:
    """TSDF fusion (Curless and Levoy 1996; Open3D's UniformTSDFVolume over the cube that holds ``box``) of
    rendered depth and colour, then marching cubes on the fused distance.

    Memory grows with the cube of (box side / voxel): about 20 bytes a voxel, 340 MB at 256^3.

    Args:
        views: (rendered {depth, acc (H, W), rgb (H, W, 3) in [0, 1]}, K (3, 3), c2w (4, 4)) per view;
            pixels below ``acc_threshold`` carry no depth.
    """
    o3d = open3d()

    lo, hi = np.asarray(box[0], dtype=np.float64), np.asarray(box[1], dtype=np.float64)
    length = float((hi - lo).max())
    volume = o3d.pipelines.integration.UniformTSDFVolume(
        length=length, resolution=max(2, int(math.ceil(length / voxel))), sdf_trunc=truncation,
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8, origin=lo.reshape(3, 1))
    for rendered, K, c2w in views:
        depth = np.where(rendered["acc"] >= acc_threshold, rendered["depth"], 0.0).astype(np.float32)
        depth = np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)
        h, w = depth.shape
        colour = np.ascontiguousarray(np.round(np.clip(rendered["rgb"], 0, 1) * 255).astype(np.uint8))
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(colour), o3d.geometry.Image(depth), depth_scale=1.0, depth_trunc=depth_max,
            convert_rgb_to_intensity=False)
        intrinsic = o3d.camera.PinholeCameraIntrinsic(w, h, K[0, 0], K[1, 1], K[0, 2] - 0.5, K[1, 2] - 0.5)
        volume.integrate(rgbd, intrinsic, np.linalg.inv(np.asarray(c2w, dtype=np.float64)))
    return from_open3d(volume.extract_triangle_mesh())


def poisson(points: Any, depth: int = 8, density_quantile: float = 0.15,
            box: tuple[Sequence[float], Sequence[float]] | None = None) -> Mesh:
    """Screened Poisson reconstruction (Kazhdan and Hoppe 2013, Open3D) of an oriented point cloud; the
    vertices least supported by points (the lowest ``density_quantile`` of Poisson's density) and those
    outside ``box`` are dropped, as the method closes surfaces the points never showed. On beer's scene cloud
    the lowest 15 % rather than 5 % clears most of the flaps that close the floor over the can (held-out
    pixels covered 32 % -> 28 %, PSNR over them 17.9 -> 18.8 dB; 30 %: 25 %, 19.2 dB, and holes in the floor)."""
    o3d = open3d()

    mesh, support = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(points, depth=depth)
    support = np.asarray(support)
    drop = support < np.quantile(support, density_quantile) if len(support) else np.zeros(0, dtype=bool)
    if box is not None:
        v = np.asarray(mesh.vertices)
        drop |= ~np.all((v >= np.asarray(box[0])) & (v <= np.asarray(box[1])), axis=1)
    mesh.remove_vertices_by_mask(drop)
    return from_open3d(mesh)


@dataclass(frozen=True)
class CleanReport:
    faces_before: int
    components: int
    components_kept: int
    faces_after_cleaning: int
    faces_after_simplification: int


def clean(mesh: Mesh, min_component: float, target_faces: int) -> tuple[Mesh, CleanReport]:
    """Drop connected pieces with fewer than ``min_component`` times the largest piece's triangles, then
    quadric decimation (Garland and Heckbert 1997) down to ``target_faces`` (0: keep all)."""
    o = to_open3d(mesh)
    o.remove_duplicated_vertices()
    o.remove_degenerate_triangles()
    o.remove_unreferenced_vertices()
    before = len(o.triangles)
    components = kept = 0
    if before:
        labels, sizes, _ = o.cluster_connected_triangles()
        labels, sizes = np.asarray(labels), np.asarray(sizes)
        components = len(sizes)
        small = sizes < min_component * sizes.max()
        kept = int((~small).sum())
        o.remove_triangles_by_mask(small[labels])
        o.remove_unreferenced_vertices()
    cleaned = len(o.triangles)
    if target_faces and cleaned > target_faces:
        o = o.simplify_quadric_decimation(target_number_of_triangles=target_faces)
        o.remove_unreferenced_vertices()
    out = from_open3d(o)
    return out, CleanReport(before, components, kept, cleaned, out.faces)


def transformed(mesh: Mesh, similarity: Sequence[Sequence[float]]) -> Mesh:
    """The mesh under a 4x4 similarity (a positive scale keeps the triangles' orientation)."""
    return Mesh(Similarity.from_matrix(np.asarray(similarity)).apply_points(mesh.vertices), mesh.triangles, mesh.colors)


# -- files -------------------------------------------------------------------------------------------
def write_mesh(mesh: Mesh, path: Path) -> None:
    """PLY (binary) or OBJ through Open3D, with vertex colours and normals; GLB with ``write_glb`` (in the
    mesh's coordinates: give it ``gltf_frame``'s)."""
    o3d = open3d()

    if path.suffix.lower() == ".glb":
        write_glb(path, mesh)
        return
    o = to_open3d(mesh)
    o.compute_vertex_normals()
    o.triangle_normals = o3d.utility.Vector3dVector()  # OBJ cannot hold them, and Open3D warns when asked to
    if not o3d.io.write_triangle_mesh(str(path), o, write_ascii=False, write_vertex_colors=mesh.colors is not None):
        raise OSError(f"open3d could not write {path}")


def read_mesh(path: Path) -> Mesh:
    o3d = open3d()

    if path.suffix.lower() == ".glb":
        return read_glb(path)
    return from_open3d(o3d.io.read_triangle_mesh(str(path)))


# glTF's axes: +Y up. A z-up frame turns to them by x -> x, z -> y, y -> -z (a rotation about x).
Z_UP_TO_GLTF = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
GLB_ROUGHNESS = 0.8


def gltf_frame(to_world: Sequence[Sequence[float]]) -> np.ndarray:
    """The 4x4 similarity from the SfM frame to a GLB's: the normalized world's rotation and centre (its z up
    turned to glTF's +Y), at the SfM frame's scale, so distances keep the capture's units."""
    to_world = np.asarray(to_world, dtype=np.float64)
    scale = float(np.cbrt(np.linalg.det(to_world[:3, :3])))
    return Z_UP_TO_GLTF @ np.diag([1 / scale, 1 / scale, 1 / scale, 1.0]) @ to_world


def write_glb(path: Path, mesh: Mesh, units: str = "arbitrary (the SfM frame's)") -> None:
    """A binary glTF 2.0 file with one triangle mesh, as Blender, three.js and most viewers expect it: a PBR
    material (metallic 0, roughness ``GLB_ROUGHNESS``; glTF's default is metal, which renders dark), and
    the vertex colours in ``COLOR_0`` converted to linear, as glTF defines it (sRGB bytes there look washed
    out). ``mesh`` is written in its own coordinates (``gltf_frame`` gives +Y up); ``units`` is stated in the
    mesh's extras. Written by trimesh (Open3D 0.20 writes a GLB its own reader cannot read back)."""
    import trimesh

    from nerfpipe.imaging.png import srgb_decode

    material = trimesh.visual.material.PBRMaterial(name="nerfpipe", baseColorFactor=[255, 255, 255, 255],
                                                   metallicFactor=0.0, roughnessFactor=GLB_ROUGHNESS,
                                                   doubleSided=True)
    visual = trimesh.visual.TextureVisuals(material=material)
    if mesh.colors is not None:
        linear = srgb_decode(np.clip(mesh.colors, 0, 1))
        rgba = np.concatenate([np.round(linear * 255), np.full((len(linear), 1), 255.0)], axis=1)
        visual.vertex_attributes["color"] = rgba.astype(np.uint8)
    solid = trimesh.Trimesh(mesh.vertices, mesh.triangles, vertex_normals=vertex_normals(mesh), visual=visual,
                            process=False)
    solid.metadata.update({"units": units, "up": "+y", "generator": "nerfpipe"})
    solid.export(path, file_type="glb", include_normals=True)


def read_glb(path: Path) -> Mesh:
    """The triangle mesh of a GLB (every primitive, joined), with its vertex colours (sRGB) if it has them."""
    import trimesh

    from nerfpipe.imaging.png import srgb_encode

    scene = trimesh.load(path, file_type="glb", process=False)
    if not isinstance(scene, trimesh.Scene):
        scene = trimesh.Scene(scene)
    vertices, triangles, colors, offset = [], [], [], 0
    for node in scene.graph.nodes_geometry:  # each mesh where the scene graph places it
        transform, name = scene.graph[node]
        part = scene.geometry[name]
        if part.visual.kind == "vertex":
            rgb = np.asarray(part.visual.vertex_colors)[:, :3]
        else:
            attributes = getattr(part.visual, "vertex_attributes", {})
            rgb = np.asarray(attributes["color"])[:, :3] if "color" in attributes else None
        vertices.append(trimesh.transform_points(np.asarray(part.vertices, dtype=np.float64), transform))
        triangles.append(np.asarray(part.faces, dtype=np.int64) + offset)
        colors.append(None if rgb is None else srgb_encode(rgb / 255.0))  # COLOR_0 is linear
        offset += len(part.vertices)
    coloured = all(c is not None for c in colors) and colors
    return Mesh(np.concatenate(vertices), np.concatenate(triangles), np.concatenate(colors) if coloured else None)


def surface_colors(model: Any, vertices: np.ndarray, normals: np.ndarray, offset: float, chunk: int = 8192) -> np.ndarray:
    """The radiance field's colour of each vertex, as seen looking at it against its normal: a short ray
    from ``offset`` outside the surface to ``offset`` inside is rendered and its colour normalized by
    its opacity (the colour a camera there would see). A vertex whose ray stays transparent takes the
    field's colour at the vertex.

    The short rays are rendered as every ray is (``RadianceModel.render``): with the model's own sampler.

    Args:
        model: a ``RadianceModel``; vertices, normals: (V, 3) world coordinates, outward unit normals.
    Returns:
        (V, 3) colours in [0, 1].
    """
    import torch

    device = model.device
    space = model.ray_space
    v = torch.as_tensor(vertices, dtype=torch.float32, device=device)
    n = torch.as_tensor(normals, dtype=torch.float32, device=device)
    count = len(v)
    out = model.render_rays(space.segment_rays(v + offset * n, v - offset * n, -n), chunk, background=None)
    acc = out["acc"].unsqueeze(-1)
    colors = out["rgb"] / acc.clamp_min(1e-6)
    with torch.no_grad():
        field = model.fine if model.fine is not None else model.coarse
        at_vertex = torch.cat([field(space.to_field(v[s:s + chunk]), -n[s:s + chunk])[0] for s in range(0, count, chunk)]) \
            if count else torch.zeros(0, 3, device=device)
    colors = torch.where(acc > 0.05, colors, at_vertex)
    return colors.clamp(0.0, 1.0).cpu().numpy().astype(np.float64)
