"""Exports of a field with a known answer: a solid sphere of density 1e3, whose surface, depth maps and
colours are known in closed form, rendered through the same ``RadianceModel`` a trained field uses."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from nerfpipe.export.depth import DepthView, decode_depth_png, read_view, write_view
from nerfpipe.export.mesh import (
    Grid,
    clean,
    marching_cubes,
    read_mesh,
    surface_colors,
    transformed,
    tsdf_fusion,
    vertex_normals,
    write_mesh,
)
from nerfpipe.export.points import clean_cloud, views_to_points
from nerfpipe.export.points import transformed as cloud_transformed
from nerfpipe.imaging.png import srgb_decode
from nerfpipe.nerf.fields.analytic import SphereField
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.spaces.ray_space import BoxSpace
from nerfpipe.nerf.spaces.rays import camera_rays, pixel_centers
from nerfpipe.nerf.samplers.configs import HierarchicalConfig
from nerfpipe.nerf.samplers.hierarchical import HierarchicalSampler
from tests.helpers import look_at

CENTER = np.array([0.05, -0.03, 0.02])
RADIUS = 0.45
DENSITY = 1e3
BOX = ((-0.6, -0.6, -0.6), (0.6, 0.6, 0.6))
NEAR, FAR = 0.6, 3.0
N_COARSE = 64
SIZE, FOCAL = 48, 50.0


def sphere_model(n_fine: int = 0) -> RadianceModel:
    field = SphereField(tuple(CENTER), RADIUS, DENSITY)
    return RadianceModel(field, None, HierarchicalSampler(HierarchicalConfig(n_coarse=N_COARSE, n_fine=n_fine)), BoxSpace(BOX), (1.0, 1.0, 1.0))


def ring_cameras(count: int = 8) -> list[np.ndarray]:
    """Cameras on a ring 1.8 from the origin, 0.5 above it, all looking at the origin."""
    angles = np.linspace(0, 2 * np.pi, count, endpoint=False)
    return [look_at(np.array([1.8 * np.cos(a), 1.8 * np.sin(a), 0.5]), np.zeros(3)) for a in angles]


def render(model: RadianceModel, c2w: np.ndarray) -> dict[str, np.ndarray]:
    out = model.render_image((FOCAL, FOCAL, SIZE / 2, SIZE / 2), c2w, SIZE, SIZE, NEAR, FAR, chunk=4096)
    return {k: v.numpy() for k, v in out.items()}


def analytic_depth(c2w: np.ndarray) -> np.ndarray:
    """Depth along the camera axis where each pixel's ray enters the sphere (inf: it misses)."""
    uv = pixel_centers(SIZE, SIZE)
    k = torch.tensor([FOCAL, FOCAL, SIZE / 2, SIZE / 2]).expand(len(uv), 4)
    origins, directions = camera_rays(uv, k, torch.tensor(c2w, dtype=torch.float32))
    return SphereField(tuple(CENTER), RADIUS).intersect(origins, directions).reshape(SIZE, SIZE).numpy()


def radial_error(points: np.ndarray) -> np.ndarray:
    return np.abs(np.linalg.norm(points - CENTER, axis=1) - RADIUS)


@pytest.fixture(scope="module")
def rendered_views() -> list[tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]]:
    model = sphere_model(n_fine=0)
    K = np.array([[FOCAL, 0, SIZE / 2], [0, FOCAL, SIZE / 2], [0, 0, 1.0]])
    return [(render(model, c2w), K, c2w) for c2w in ring_cameras()]


def test_exported_depth_is_the_ray_sphere_intersection_within_half_a_sample_spacing(rendered_views, tmp_path):
    spacing = (FAR - NEAR) / N_COARSE  # box clipping only shortens rays, so samples are at least this dense
    for rendered, _, c2w in rendered_views[:3]:
        truth = analytic_depth(c2w)
        # rays grazing the sphere cross it in less than a spacing and may miss every sample
        uv = pixel_centers(SIZE, SIZE).reshape(SIZE, SIZE, 2).numpy()
        r_px = np.linalg.norm(uv - SIZE / 2, axis=-1)
        hit = np.isfinite(truth) & (rendered["acc"] > 0.99)
        assert hit.mean() > 0.15
        inner = np.isfinite(truth) & (r_px < 0.8 * r_px[np.isfinite(truth)].max())
        assert hit[inner].all()
        error = rendered["depth"][hit] - (truth[hit] + 1 / DENSITY)
        assert np.abs(error).max() <= spacing / 2 + 1e-4, np.abs(error).max()
        assert np.all(rendered["acc"][~np.isfinite(truth)] < 1e-6)
        assert np.allclose(rendered["rgb"][~np.isfinite(truth)], 1.0)

    # the files round-trip: .npy exactly, the 16-bit PNG to within one count
    rendered, K, c2w = rendered_views[0]
    view = DepthView("a/b.png", "a__b", "train", SIZE, SIZE, (FOCAL, FOCAL, SIZE / 2, SIZE / 2),
                     tuple(map(tuple, c2w.tolist())), NEAR, FAR)
    write_view(tmp_path, view, rendered, png_scale=20000.0, acc_threshold=0.5, to_sfm=np.eye(4).tolist())
    back = read_view(tmp_path, view)
    assert np.array_equal(back["depth"], rendered["depth"].astype(np.float32))
    assert back["depth"].dtype == np.float32 and back["acc"].dtype == np.float32
    import cv2

    counts = cv2.imread(str(tmp_path / "a__b.depth.png"), cv2.IMREAD_UNCHANGED)
    assert counts.dtype == np.uint16
    sidecar = json.loads((tmp_path / "a__b.depth.json").read_text())
    decoded = decode_depth_png(counts, sidecar["scale"])
    valid = rendered["acc"] >= 0.5
    assert np.array_equal(np.isfinite(decoded), valid)
    assert np.abs(decoded[valid] - rendered["depth"][valid]).max() <= 0.5 / sidecar["scale"] + 1e-6
    preview = cv2.imread(str(tmp_path / "a__b.preview.png"))
    assert preview.shape == (SIZE, SIZE, 3) and preview[~valid].max() == 0 and preview[valid].max() > 0


def test_hierarchical_depth_is_closer_still(rendered_views):
    c2w = rendered_views[0][2]
    truth = analytic_depth(c2w)
    coarse, fine = rendered_views[0][0], render(sphere_model(n_fine=64), c2w)
    hit = np.isfinite(truth) & (coarse["acc"] > 0.99) & (fine["acc"] > 0.99)
    e_coarse = np.abs(coarse["depth"][hit] - truth[hit]).mean()
    e_fine = np.abs(fine["depth"][hit] - truth[hit]).mean()
    # Fine samples land in the coarse bin holding the weight, which starts halfway from the previous coarse
    # sample: when the surface lies before that midpoint, the bin is all inside and the error stays. On
    # average they still help.
    assert e_fine < 0.75 * e_coarse


def test_marching_cubes_recovers_the_radius_within_one_voxel():
    model = sphere_model()
    grid = Grid.over(*BOX, resolution=40)
    mesh = marching_cubes(model.coarse.query_density, grid, DENSITY / 2, block=16)  # 3 blocks a side
    assert grid.cells == (40, 40, 40) and grid.voxel == pytest.approx(0.03)
    assert mesh.faces > 1000
    assert radial_error(mesh.vertices).max() <= grid.voxel
    # one closed surface: block seams were welded (every edge shared by exactly two triangles)
    edges = np.sort(np.concatenate([mesh.triangles[:, [0, 1]], mesh.triangles[:, [1, 2]], mesh.triangles[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)
    # triangles face outward
    v, f = mesh.vertices, mesh.triangles
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(np.sum(normals * (v[f].mean(axis=1) - CENTER), axis=1) > 0)
    # the same surface whatever the block size
    whole = marching_cubes(model.coarse.query_density, grid, DENSITY / 2, block=64)
    assert whole.faces == mesh.faces and np.allclose(np.sort(whole.vertices, axis=0), np.sort(mesh.vertices, axis=0))


def test_vertex_colours_are_the_sphere_surface_colour():
    model = sphere_model()
    grid = Grid.over(*BOX, resolution=24)
    mesh = marching_cubes(model.coarse.query_density, grid, DENSITY / 2)
    colors = surface_colors(model, mesh.vertices, vertex_normals(mesh), 2 * grid.voxel)
    # c = (x - center) / (2 r) + 0.5 at the surface point nearest each vertex
    direction = (mesh.vertices - CENTER) / np.linalg.norm(mesh.vertices - CENTER, axis=1, keepdims=True)
    expected = direction * RADIUS / (2 * RADIUS) + 0.5
    assert np.abs(colors - expected).max() < 0.05


def test_every_exported_point_lies_within_one_voxel_of_the_sphere(rendered_views):
    cloud, source = views_to_points(rendered_views, acc_threshold=0.9, box=BOX)
    assert len(cloud) > 1000 and set(source) == set(range(len(rendered_views)))
    voxel = 0.02
    cleaned, report = clean_cloud(cloud, voxel, target_points=0)
    assert 500 < len(cleaned) < len(cloud)
    assert radial_error(cleaned.xyz).max() <= voxel
    # normals face out of the sphere, as the cameras saw it
    outward = (cleaned.xyz - CENTER) / np.linalg.norm(cleaned.xyz - CENTER, axis=1, keepdims=True)
    assert np.median(np.sum(cleaned.normals * outward, axis=1)) > 0.95
    # a target count grows the voxel
    fewer, report = clean_cloud(cloud, voxel, target_points=300)
    assert len(fewer) <= 300 and report.voxel > voxel
    # to the SfM frame and back by a similarity
    to_sfm = np.diag([2.0, 2.0, 2.0, 1.0])
    to_sfm[:3, 3] = (1.0, -2.0, 3.0)
    moved = cloud_transformed(cleaned, to_sfm)
    assert np.allclose(moved.xyz, 2 * cleaned.xyz + (1.0, -2.0, 3.0))
    assert np.allclose(moved.normals, cleaned.normals)


def test_tsdf_fusion_gives_the_same_sphere(rendered_views):
    voxel = 0.03
    mesh = tsdf_fusion(rendered_views, BOX, voxel, truncation=4 * voxel, acc_threshold=0.9, depth_max=FAR)
    mesh, report = clean(mesh, min_component=0.05, target_faces=0)
    assert mesh.faces > 500 and report.components_kept >= 1
    assert np.median(radial_error(mesh.vertices)) <= voxel / 2
    assert radial_error(mesh.vertices).max() <= voxel
    # its colours are the rendered ones: the sphere's colour field
    direction = (mesh.vertices - CENTER) / np.linalg.norm(mesh.vertices - CENTER, axis=1, keepdims=True)
    assert np.median(np.abs(mesh.colors - (direction / 2 + 0.5))) < 0.05


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".glb"])
def test_mesh_files_round_trip(tmp_path, suffix):
    model = sphere_model()
    grid = Grid.over(*BOX, resolution=16)
    mesh = marching_cubes(model.coarse.query_density, grid, DENSITY / 2)
    mesh.colors = np.clip((mesh.vertices - CENTER) + 0.5, 0, 1)
    to_sfm = np.eye(4)
    to_sfm[:3, 3] = (10.0, 0.0, 0.0)
    moved = transformed(mesh, to_sfm)
    write_mesh(moved, tmp_path / f"m{suffix}")
    back = read_mesh(tmp_path / f"m{suffix}")
    assert len(back.triangles) == mesh.faces
    # the vertex sets match (OBJ readers may reorder them)
    order = np.lexsort(back.vertices.T)
    ref = np.lexsort(moved.vertices.T)
    assert np.allclose(back.vertices[order], moved.vertices[ref], atol=1e-5)
    # GLB holds linear 8-bit colours (glTF's COLOR_0): in sRGB a step is up to 13/255 in the darkest tones
    atol = 1 / 255 + 1e-6 if suffix != ".glb" else 13 / 255
    assert back.colors is not None and np.allclose(back.colors[order], moved.colors[ref], atol=atol)


def test_our_glb_opens_in_an_independent_reader(tmp_path):
    """trimesh writes and reads our GLB; Open3D's glTF reader (tinygltf), which shares no code with it, must
    find the same triangles, positions and colours."""
    import open3d as o3d

    model = sphere_model()
    mesh = marching_cubes(model.coarse.query_density, Grid.over(*BOX, resolution=16), DENSITY / 2)
    mesh.colors = np.clip((mesh.vertices - CENTER) + 0.5, 0, 1)
    write_mesh(mesh, tmp_path / "m.glb")
    other = o3d.io.read_triangle_mesh(str(tmp_path / "m.glb"))
    assert len(other.triangles) == mesh.faces and other.has_vertex_colors() and other.has_vertex_normals()
    vertices, colors = np.asarray(other.vertices), np.asarray(other.vertex_colors)
    order, ref = np.lexsort(vertices.T), np.lexsort(mesh.vertices.T)
    assert np.allclose(vertices[order], mesh.vertices[ref], atol=1e-5)
    assert np.allclose(colors[order], srgb_decode(mesh.colors[ref]), atol=0.5 / 255 + 1e-6)  # linear, as glTF says


def test_the_glb_has_a_dielectric_material_linear_colours_and_y_up(tmp_path):
    """glTF's default material is metal (three.js renders it dark); COLOR_0 is linear; +Y is up."""
    import json
    import struct

    from nerfpipe.export.mesh import Mesh, gltf_frame

    mesh = Mesh(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), np.array([[0, 1, 2]]),
                np.array([[0.5, 0.5, 0.5], [1.0, 0.0, 0.0], [0.2, 0.4, 0.8]]))
    write_mesh(mesh, tmp_path / "m.glb")
    data = (tmp_path / "m.glb").read_bytes()
    (length,) = struct.unpack_from("<I", data, 12)
    doc = json.loads(data[20:20 + length])
    (material,) = doc["materials"]
    assert material["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    assert material["pbrMetallicRoughness"]["roughnessFactor"] == 0.8
    primitive = doc["meshes"][0]["primitives"][0]
    assert primitive["material"] == 0 and {"POSITION", "NORMAL", "COLOR_0"} <= set(primitive["attributes"])
    colour = doc["accessors"][primitive["attributes"]["COLOR_0"]]
    # by hand: sRGB 0.5, 0.8, 0.2 are linear 0.214, 0.604, 0.0331: bytes 55, 154, 8
    assert colour["max"][:3] == [255, 55, 154] and colour["min"][:3] == [8, 0, 0]
    assert doc["meshes"][0]["extras"]["up"] == "+y" and "units" in doc["meshes"][0]["extras"]
    # the normalized world's z (up) is the GLB's +Y, at the SfM frame's scale, about the world's centre
    to_world = np.array([[0.0, -2.0, 0.0, 1.0], [2.0, 0.0, 0.0, 0.5], [0.0, 0.0, 2.0, -3.0], [0.0, 0.0, 0.0, 1.0]])
    frame = gltf_frame(to_world)
    up_in_sfm = np.linalg.inv(to_world)[:3, :3] @ [0.0, 0.0, 1.0]
    assert np.allclose(frame[:3, :3] @ up_in_sfm / np.linalg.norm(up_in_sfm), [0.0, 1.0, 0.0])
    assert np.isclose(np.linalg.det(frame[:3, :3]), 1.0)  # a rotation: distances in the capture's units
    centre = np.linalg.inv(to_world) @ [0.0, 0.0, 0.0, 1.0]
    assert np.allclose(frame @ centre, [0.0, 0.0, 0.0, 1.0])


def test_cleaning_drops_small_pieces_and_simplifies():
    model = sphere_model()
    grid = Grid.over(*BOX, resolution=32)
    big = marching_cubes(model.coarse.query_density, grid, DENSITY / 2)
    small = SphereField((0.5, 0.5, 0.5), 0.06, DENSITY)
    speck = marching_cubes(small.query_density, grid, DENSITY / 2)
    assert speck.faces > 0
    from nerfpipe.export.mesh import Mesh

    both = Mesh(np.concatenate([big.vertices, speck.vertices]),
                np.concatenate([big.triangles, speck.triangles + len(big.vertices)]))
    cleaned, report = clean(both, min_component=0.05, target_faces=0)
    assert report.components == 2 and report.components_kept == 1 and cleaned.faces == big.faces
    simplified, report = clean(big, min_component=0.05, target_faces=500)
    assert simplified.faces <= 500 and radial_error(simplified.vertices).max() <= 2 * grid.voxel
