"""The texture baked from photos: on a cube whose faces have known colours, photographed by ray casting, the
baked mesh renders a view no photo was taken from as the truth does, in the right colours; gaps are filled
from their surroundings; the GLB carries the texture in a dielectric material."""

from __future__ import annotations

import numpy as np
import pytest

from nerfpipe.export.mesh import Mesh
from nerfpipe.export.texture import Photo, bake, colours_at, fill_gaps, render, write_textured_glb, write_textured_obj
from tests.helpers import look_at

# the colour of each face of the cube, by its outward normal: +x, -x, +y, -y, +z, -z
FACE_COLOURS = np.array([[230, 40, 40], [40, 200, 60], [50, 70, 220], [240, 200, 40], [200, 60, 200], [60, 200, 200]],
                        dtype=np.uint8)
K = np.array([[80.0, 0.0, 48.0], [0.0, 80.0, 36.0], [0.0, 0.0, 1.0]])
WIDTH, HEIGHT = 96, 72


def cube() -> Mesh:
    """A unit cube about the origin, each face split into 8 x 8 squares (a mesh to simplify and unwrap)."""
    import open3d as o3d

    box = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0).translate((-0.5, -0.5, -0.5))
    box = box.subdivide_midpoint(3)
    return Mesh(np.asarray(box.vertices), np.asarray(box.triangles))


def truth(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) uint8 photo of the cube (its face colours on black) and its (H, W) hit mask, by ray casting."""
    import open3d as o3d

    mesh = cube()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.triangles.astype(np.uint32)))
    u, v = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
    directions = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1) @ c2w[:3, :3].T
    rays = np.concatenate([np.broadcast_to(c2w[:3, 3], directions.shape), directions], -1).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))
    normals = hit["primitive_normals"].numpy()
    hits = hit["primitive_ids"].numpy() != scene.INVALID_ID
    axis = np.abs(normals).argmax(-1)
    face = 2 * axis + (np.take_along_axis(normals, axis[..., None], -1)[..., 0] < 0)
    photo = np.where(hits[..., None], FACE_COLOURS[face], 0).astype(np.uint8)
    return photo, hits


def around(n: int, height: float, offset: float = 0.0) -> list[np.ndarray]:
    return [look_at(np.array([3 * np.cos(a + offset), 3 * np.sin(a + offset), height]), np.zeros(3))
            for a in np.linspace(0, 2 * np.pi, n, endpoint=False)]


@pytest.fixture(scope="module")
def baked():
    photos = [Photo(truth(c2w)[0], K, c2w) for c2w in around(8, 1.5) + around(8, -1.5, 0.3)]
    return bake(cube(), photos, faces=2000, size=256)


def test_a_view_no_photo_was_taken_from_renders_as_the_truth(baked):
    c2w = look_at(np.array([2.2, -1.7, 1.2]), np.zeros(3))
    rgb, hit = render(baked, K, c2w, WIDTH, HEIGHT)
    photo, truth_hit = truth(c2w)
    assert (hit == truth_hit).mean() > 0.99
    inner = truth_hit & hit
    error = np.abs(rgb[inner] - photo[inner] / 255.0).max(axis=-1)
    # the faces come out in their colours (measured: half the pixels within 1/255, 89 % within 10/255); the
    # pixels along the cube's edges, where texels of two faces blend, are off
    assert np.median(error) <= 2 / 255 and (error < 10 / 255).mean() > 0.85
    ratio = rgb[inner].mean(axis=0) / (photo[inner].mean(axis=0) / 255.0)
    assert np.all(np.abs(ratio - 1) < 0.05), ratio


def test_photos_that_miss_a_face_do_not_darken_it():
    """Open3D blends the photos by a softmax of their footprints, scaled by the nearest vertex's distance to a
    camera, and a photo that misses a texel takes part in it, black. With one photo taken close to a face,
    every other photo's footprint weighs about as little as a miss: the faces still come out in their colours
    (measured before the blend was corrected: 0.47 to 0.49 of them)."""
    close = look_at(np.array([0.9, 0.05, 0.1]), np.zeros(3))
    photos = [Photo(truth(c2w)[0], K, c2w) for c2w in around(8, 1.5) + around(8, -1.5, 0.3) + [close]]
    textured = bake(cube(), photos, faces=2000, size=256)
    c2w = look_at(np.array([2.2, -1.7, 1.2]), np.zeros(3))
    rgb, hit = render(textured, K, c2w, WIDTH, HEIGHT)
    photo, truth_hit = truth(c2w)
    inner = truth_hit & hit
    ratio = rgb[inner].mean(axis=0) / (photo[inner].mean(axis=0) / 255.0)
    assert np.all(np.abs(ratio - 1) < 0.05), ratio


def test_vertex_colours_read_off_the_texture(baked):
    centres = np.array([[0.5, 0.1, -0.2], [-0.5, 0.2, 0.1], [0.1, 0.5, 0.2], [0.2, -0.5, -0.1], [0.1, 0.2, 0.5],
                        [-0.2, 0.1, -0.5]])  # a point inside each face, in FACE_COLOURS' order
    assert np.abs(colours_at(baked, centres) * 255 - FACE_COLOURS).max() < 12


def test_gaps_are_filled_from_their_surroundings():
    texture = np.zeros((16, 16, 3), np.uint8)
    texture[:, :8] = (200, 0, 0)
    texture[:, 8:] = (0, 0, 200)
    known = np.ones((16, 16), bool)
    known[4:12, 6:10] = False  # a hole across the edge between the two colours
    filled = fill_gaps(np.where(known[..., None], texture, 0).astype(np.uint8), known)
    assert np.array_equal(filled[known], texture[known])  # what was known stays
    assert filled[8, 6, 0] > 150 and filled[8, 6, 2] < 60 and filled[8, 9, 2] > 150 and filled[8, 9, 0] < 60
    assert filled[~known].min(axis=-1).max() < 110 and filled[~known].max(axis=-1).min() > 90  # no black


def test_the_glb_carries_the_texture_in_a_dielectric_material(baked, tmp_path):
    import trimesh

    to_gltf = np.diag([2.0, 2.0, 2.0, 1.0])
    write_textured_glb(tmp_path / "m.glb", baked, to_gltf, "metres")
    scene = trimesh.load(tmp_path / "m.glb", file_type="glb")
    (solid,) = scene.geometry.values()
    material = solid.visual.material
    assert material.metallicFactor == 0.0 and material.roughnessFactor == 0.8
    assert material.baseColorTexture.size == (256, 256)
    assert np.allclose(solid.bounds, [[-1, -1, -1], [1, 1, 1]], atol=1e-5)  # the cube under to_gltf
    assert len(solid.faces) == baked.faces and solid.metadata["units"] == "metres"
    assert solid.visual.uv.shape == (len(solid.vertices), 2) and 0 <= solid.visual.uv.min() <= solid.visual.uv.max() <= 1
    # NORMAL per vertex (viewers shade it smooth rather than faceted), pointing out of the cube, unit length
    doc = glb_json(tmp_path / "m.glb")
    (primitive,) = doc["meshes"][0]["primitives"]
    assert {"POSITION", "NORMAL", "TEXCOORD_0"} <= set(primitive["attributes"])
    normals = glb_accessor(tmp_path / "m.glb", doc, primitive["attributes"]["NORMAL"])
    positions = glb_accessor(tmp_path / "m.glb", doc, primitive["attributes"]["POSITION"])
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    assert np.all(np.sum(normals * positions, axis=1) > 0)
    # a seam vertex, one per chart, has the same normal in each: the welded mesh's
    first = {}
    for position, normal in zip(np.round(positions, 5).tolist(), normals):
        assert np.allclose(first.setdefault(tuple(position), normal), normal, atol=1e-6)


def glb_json(path):
    """The JSON chunk of a binary glTF file."""
    import json
    import struct

    data = path.read_bytes()
    length, kind = struct.unpack("<I4s", data[12:20])
    assert kind == b"JSON"
    return json.loads(data[20:20 + length])


def glb_accessor(path, doc, index) -> np.ndarray:
    """A float32 VEC3 accessor of a GLB, as an (N, 3) array (the binary chunk after the JSON one)."""
    import struct

    data = path.read_bytes()
    length = struct.unpack("<I", data[12:16])[0]
    binary = data[20 + length + 8:]
    accessor = doc["accessors"][index]
    view = doc["bufferViews"][accessor["bufferView"]]
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    assert accessor["componentType"] == 5126 and accessor["type"] == "VEC3"
    return np.frombuffer(binary, np.float32, accessor["count"] * 3, start).reshape(-1, 3)


def test_the_obj_comes_with_its_material_and_texture(baked, tmp_path):
    import trimesh

    files = write_textured_obj(tmp_path / "mesh.obj", baked, np.diag([2.0, 2.0, 2.0, 1.0]))
    assert [f.name for f in files] == ["mesh.obj", "mesh.mtl", "mesh_texture.png"] and all(f.is_file() for f in files)
    text = (tmp_path / "mesh.obj").read_text()
    assert "mtllib mesh.mtl" in text and "\nvt " in text and "\nvn " in text
    mtl = (tmp_path / "mesh.mtl").read_text()
    assert "map_Kd mesh_texture.png" in mtl and "Kd 1.00000000 1.00000000 1.00000000" in mtl  # the texture as baked
    solid = trimesh.load(tmp_path / "mesh.obj", process=False)
    assert len(solid.faces) == baked.faces and np.allclose(solid.bounds, [[-1, -1, -1], [1, 1, 1]], atol=1e-5)
    assert solid.visual.material.image.size == (256, 256)


def test_a_folded_edge_and_a_loose_sliver_are_cleaned_before_charting():
    """UVAtlas refuses a mesh where three triangles share an edge (as Poisson and TSDF surfaces and their
    decimation can leave) and stray pieces of a few triangles: the cube with a fin on one of its edges and a
    lone triangle beside it still bakes, into a mesh with neither."""
    import open3d as o3d

    box = cube()
    a, b = box.triangles[0, 0], box.triangles[0, 1]  # an edge of the cube: the fin is a third triangle on it
    apex = box.vertices[[a, b]].mean(axis=0) * 1.6
    loose = np.array([[2.0, 0.0, 0.0], [2.1, 0.0, 0.0], [2.0, 0.1, 0.0]])
    v = len(box.vertices)
    finned = Mesh(np.concatenate([box.vertices, apex[None], loose]),
                  np.concatenate([box.triangles, [[a, b, v], [v + 1, v + 2, v + 3]]]))
    legacy = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(finned.vertices),
                                       o3d.utility.Vector3iVector(finned.triangles))
    assert len(np.asarray(legacy.get_non_manifold_edges())) == 1
    photos = [Photo(truth(c2w)[0], K, c2w) for c2w in around(4, 1.5)]
    textured = bake(finned, photos, faces=10_000, size=128)
    out = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(textured.vertices),
                                    o3d.utility.Vector3iVector(textured.triangles))
    assert len(np.asarray(out.get_non_manifold_edges())) == 0
    assert textured.vertices[:, 0].max() < 1.0  # the lone triangle at x = 2 is gone
    assert len(box.triangles) - 2 <= textured.faces <= len(box.triangles)


def test_a_mesh_uvatlas_cannot_chart_is_an_error_of_ours_not_open3ds(monkeypatch) -> None:
    """UVAtlas raised IndexError (`_Map_base::at`) on the slivers of a ten-second training; export_mesh then
    keeps vertex colours instead of failing with Open3D's traceback."""
    import open3d as o3d

    from nerfpipe.export.texture import UnchartableMeshError

    def refuse(self, *args, **kwargs):
        raise IndexError("_Map_base::at")

    monkeypatch.setattr(o3d.t.geometry.TriangleMesh, "compute_uvatlas", refuse)
    photos = [Photo(np.zeros((16, 16, 3), np.uint8), np.eye(3), c2w) for c2w in around(2, 0.5)]
    with pytest.raises(UnchartableMeshError, match=r"UVAtlas could not chart its 768 triangles \(_Map_base::at\)"):
        bake(cube(), photos, 1000, 64)
