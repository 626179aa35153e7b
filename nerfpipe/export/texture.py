"""A texture for the mesh from the training photos, and the textured mesh rendered, to score it against photos.

Baking (``bake``): the mesh is simplified to ``faces`` triangles, unwrapped into a texture atlas by UVAtlas
(Open3D's ``compute_uvatlas``), and the photos are projected onto it by Open3D's
``project_images_to_albedo``, which tests each texel's visibility from each camera by ray casting and blends
the cameras that see it, weighted by how squarely they see it. The colours are the photos' own, not the
field's seen from where no camera stood (vertex colours from the field came out about 30 % dark).

Rendering (``render``): one ray per pixel cast at the mesh (Open3D's ``RaycastingScene``); a hit takes the
texture's colour at its interpolated texture coordinate, a miss the background. The export_mesh stage scores
the mesh this way on the held-out views, beside the field's score.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from nerfpipe.export.mesh import Mesh
from nerfpipe.export.o3d import open3d

SMALLEST_PIECE = 20  # triangles: smaller pieces are dropped before charting
# the least share of the photos' blend (of 255) a texel is coloured from: below it, 8-bit rounding of the
# blend costs more than 12 % of the colour, and the texel is filled from its neighbours instead
MIN_SHARE = 8


@dataclass(frozen=True)
class TexturedMesh:
    """vertices (V, 3); triangles (F, 3); ``uvs`` (F, 3, 2) texture coordinates of each triangle's corners
    in [0, 1] (u right, v up from the texture's bottom-left: Open3D's, OBJ's and trimesh's convention, while
    row 0 of ``texture`` is its top); ``texture`` (S, S, 3) uint8 sRGB."""

    vertices: np.ndarray
    triangles: np.ndarray
    uvs: np.ndarray
    texture: np.ndarray

    @property
    def faces(self) -> int:
        return len(self.triangles)


@dataclass(frozen=True)
class Photo:
    """A photo to bake from: ``rgb`` (H, W, 3) uint8 sRGB, ``K`` (3, 3) pinhole intrinsics (pixel centres at
    +0.5), ``c2w`` (4, 4) camera-to-world, OpenCV axes, in the mesh's frame."""

    rgb: np.ndarray
    K: np.ndarray
    c2w: np.ndarray


class UnchartableMeshError(Exception):
    """The mesh cannot be laid out on a texture (UVAtlas fails on degenerate meshes)."""


def bake(mesh: Mesh, photos: Sequence[Photo], faces: int, size: int) -> TexturedMesh:
    """The mesh, simplified to at most ``faces`` triangles, with a ``size`` x ``size`` texture from ``photos``."""
    o3d = open3d()

    legacy = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices),
                                       o3d.utility.Vector3iVector(mesh.triangles))
    if len(mesh.triangles) > faces:
        legacy = legacy.simplify_quadric_decimation(faces)
    solid = o3d.t.geometry.TriangleMesh.from_legacy(manifold(legacy))
    try:
        solid.compute_uvatlas(size=size, parallel_partitions=4)  # UVAtlas charts the parts in parallel (measured fastest)
    except (IndexError, RuntimeError) as err:  # UVAtlas gives up on degenerate meshes (slivers of a short training)
        raise UnchartableMeshError(f"Open3D's UVAtlas could not chart its {len(legacy.triangles)} triangles ({err})") from None
    images = [o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(p.rgb[..., :3]))) for p in photos]
    # Open3D's pinhole model puts pixel centres at integers: half a pixel off ours
    intrinsics = [o3d.core.Tensor(p.K - np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])) for p in photos]
    extrinsics = [o3d.core.Tensor(np.linalg.inv(p.c2w)) for p in photos]

    def project(images: list) -> np.ndarray:
        albedo = solid.project_images_to_albedo(images, intrinsics, extrinsics, tex_size=size, update_material=False)
        return albedo.as_tensor().numpy()[..., :3].astype(np.float64)

    # Open3D blends the photos by a softmax of each one's footprint on the texel (cosine over squared distance,
    # scaled by the nearest vertex's squared distance to a camera), and a photo that does not see the texel
    # still takes part, black, at the weight of a zero footprint. Texels several times farther from the
    # cameras than that nearest vertex (most of a scene, all of one with a floater near a camera) come out
    # darker by the share of photos that miss them. The same blend of white photos measures that share, and
    # it is divided out (at the texture's own size: measured on a texture half the size, beer's mesh scored 1.8
    # dB lower along the charts' borders).
    colour = project(images)
    share = project([o3d.t.geometry.Image(o3d.core.Tensor(np.full((p.rgb.shape[0], p.rgb.shape[1], 3), 255, np.uint8)))
                     for p in photos])[..., :1]
    seen = share[..., 0] >= MIN_SHARE
    texture = np.where(seen[..., None], np.clip(np.round(255 * colour / np.maximum(share, 1)), 0, 255), 0).astype(np.uint8)
    return TexturedMesh(solid.vertex.positions.numpy().astype(np.float64),
                        solid.triangle.indices.numpy().astype(np.int64),
                        solid.triangle.texture_uvs.numpy().astype(np.float64),
                        fill_gaps(texture, seen))


def manifold(mesh: Any, smallest: int = SMALLEST_PIECE) -> Any:
    """The Open3D ``mesh`` made edge-manifold, as UVAtlas needs: decimation and Poisson or TSDF surfaces can
    fold an edge over, and a few of the triangles there are removed. Pieces of fewer than ``smallest``
    triangles, which that leaves behind and which UVAtlas refuses to chart, are dropped too."""
    mesh.remove_degenerate_triangles()
    mesh.remove_duplicated_triangles()
    mesh.remove_non_manifold_edges()
    piece, sizes, _ = mesh.cluster_connected_triangles()
    mesh.remove_triangles_by_mask(np.asarray(sizes)[np.asarray(piece)] < smallest)
    mesh.remove_unreferenced_vertices()
    return mesh


def fill_gaps(texture: np.ndarray, known: np.ndarray) -> np.ndarray:
    """``texture`` (S, S, 3) uint8 with the texels outside ``known`` (S, S) filled from their neighbourhood,
    by push-pull: the known texels averaged down a pyramid, then each unknown texel takes the value of the
    finest level that knows its area. Texels no photo saw, and the margins of the atlas's charts (where
    bilinear filtering and mipmaps reach across a seam), get the colours around them, not black."""
    import cv2

    levels = [(texture.astype(np.float32) * known[..., None], known.astype(np.float32))]
    while min(levels[-1][1].shape) > 1:
        colour, weight = levels[-1]
        half = (max(1, colour.shape[1] // 2), max(1, colour.shape[0] // 2))
        levels.append((cv2.resize(colour, half, interpolation=cv2.INTER_AREA),
                       cv2.resize(weight, half, interpolation=cv2.INTER_AREA)))
    colour, weight = levels[-1]
    filled = colour / np.maximum(weight, 1e-6)[..., None]
    for colour, weight in reversed(levels[:-1]):
        up = cv2.resize(filled, (colour.shape[1], colour.shape[0]), interpolation=cv2.INTER_LINEAR)
        mean = colour / np.maximum(weight, 1e-6)[..., None]
        share = np.clip(weight, 0.0, 1.0)[..., None]  # a partly known coarse texel mixes in its known part
        filled = share * mean + (1 - share) * up
    return np.where(known[..., None], texture, np.clip(np.round(filled), 0, 255).astype(np.uint8))


def render(mesh: TexturedMesh, K: np.ndarray, c2w: np.ndarray, width: int, height: int,
           background: Sequence[float] = (0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) float colours in [0, 1] (sRGB, as the texture holds them) and the (H, W) bool mask of pixels
    that hit the mesh, seen by the pinhole camera ``K`` at ``c2w`` (OpenCV axes)."""
    o3d = open3d()

    scene = _scene(mesh)
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    directions = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    directions = directions @ c2w[:3, :3].T
    origins = np.broadcast_to(c2w[:3, 3], directions.shape)
    rays = np.concatenate([origins, directions], axis=-1).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))
    triangle = hit["primitive_ids"].numpy().astype(np.int64)
    hits = triangle != scene.INVALID_ID
    rgb = np.broadcast_to(np.asarray(background, dtype=np.float64), (height, width, 3)).copy()
    rgb[hits] = _texture_at(mesh, triangle[hits], hit["primitive_uvs"].numpy()[hits])
    return rgb, hits


def _scene(mesh: TexturedMesh):
    o3d = open3d()

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                        o3d.core.Tensor(mesh.triangles.astype(np.uint32)))
    return scene


def _texture_at(mesh: TexturedMesh, triangle: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """(N, 3) texture colours in [0, 1] at points given by their triangle (N,) and the weights (N, 2) of its
    corners 1 and 2 (Open3D's ``primitive_uvs``)."""
    corners = mesh.uvs[triangle]  # (N, 3, 2)
    b1, b2 = barycentric[:, 0:1], barycentric[:, 1:2]
    return sample(mesh.texture, (1 - b1 - b2) * corners[:, 0] + b1 * corners[:, 1] + b2 * corners[:, 2])


def colours_at(mesh: TexturedMesh, points: np.ndarray) -> np.ndarray:
    """(N, 3) colours in [0, 1]: the texture at the point of ``mesh`` closest to each of ``points`` (N, 3),
    e.g. the vertices of the full mesh the textured one was simplified from."""
    o3d = open3d()

    closest = _scene(mesh).compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))
    return _texture_at(mesh, closest["primitive_ids"].numpy().astype(np.int64), closest["primitive_uvs"].numpy())


def sample(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N, 3) colours in [0, 1] of ``texture`` (S, S, 3) uint8 at ``uv`` (N, 2; v up from the bottom row),
    bilinearly (cv2.remap)."""
    import cv2

    size, count = texture.shape[0], len(uv)
    rows = -(-count // 1024)  # remap's maps are images (under 32767 a side): 1024 samples a row
    x, y = (np.zeros(rows * 1024, np.float32) for _ in range(2))
    x[:count], y[:count] = uv[:, 0] * size - 0.5, (1.0 - uv[:, 1]) * size - 0.5
    colours = cv2.remap(texture, x.reshape(rows, 1024), y.reshape(rows, 1024), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
    return colours.reshape(-1, 3)[:count].astype(np.float64) / 255.0


def _textured_trimesh(mesh: TexturedMesh, similarity: np.ndarray, material: Any) -> Any:
    """A trimesh of ``mesh`` under the 4x4 similarity, with ``material``, its texture coordinates, and vertex
    normals: the welded mesh's (trimesh's, weighted by the corners' angles), so that the seams of the atlas,
    where a vertex is one per chart, shade smooth."""
    import trimesh

    from nerfpipe.export.mesh import Mesh, vertex_normals
    from nerfpipe.geometry.normalize import Similarity

    # glTF and OBJ's per-vertex texture coordinates: a vertex at a seam of the atlas is one per chart
    corners = np.concatenate([mesh.triangles.reshape(-1, 1).astype(np.float64), mesh.uvs.reshape(-1, 2)], axis=1)
    unique, inverse = np.unique(corners, axis=0, return_inverse=True)
    welded = unique[:, 0].astype(np.int64)
    move = Similarity.from_matrix(np.asarray(similarity))
    normals = vertex_normals(Mesh(mesh.vertices, mesh.triangles))[welded] @ move.rotation.T
    return trimesh.Trimesh(move.apply_points(mesh.vertices[welded]), inverse.reshape(-1, 3), vertex_normals=normals,
                           visual=trimesh.visual.TextureVisuals(uv=unique[:, 1:], material=material), process=False)


def write_textured_glb(path: Path, mesh: TexturedMesh, to_gltf: np.ndarray, units: str) -> None:
    """The textured mesh as a GLB: the texture as its PBR material's ``baseColorTexture`` (sRGB, as glTF
    defines it), metallic 0, roughness ``GLB_ROUGHNESS``, with ``NORMAL``s, under the 4x4 similarity
    ``to_gltf``."""
    import trimesh
    from PIL import Image

    from nerfpipe.export.mesh import GLB_ROUGHNESS

    material = trimesh.visual.material.PBRMaterial(name="nerfpipe", baseColorTexture=Image.fromarray(mesh.texture),
                                                   metallicFactor=0.0, roughnessFactor=GLB_ROUGHNESS, doubleSided=True)
    solid = _textured_trimesh(mesh, to_gltf, material)
    solid.metadata.update({"units": units, "up": "+y", "generator": "nerfpipe"})
    solid.export(path, file_type="glb", include_normals=True)


OBJ_TEXTURE = "mesh_texture"  # the OBJ's material, and its texture's file name (``mesh_texture.png``)


def write_textured_obj(path: Path, mesh: TexturedMesh, similarity: np.ndarray) -> list[Path]:
    """The textured mesh as Wavefront OBJ under the 4x4 similarity: ``path`` (positions, texture coordinates,
    normals), its material library beside it (``path`` with ``.mtl``: a white diffuse colour, so the texture
    shows as baked, no specular) and the texture ``mesh_texture.png``. Returns the files written."""
    import trimesh
    from PIL import Image

    material = trimesh.visual.material.SimpleMaterial(image=Image.fromarray(mesh.texture), name=OBJ_TEXTURE,
                                                      diffuse=[255, 255, 255, 255], ambient=[255, 255, 255, 255],
                                                      specular=[0, 0, 0, 255], glossiness=1.0)
    mtl = path.with_suffix(".mtl")
    _textured_trimesh(mesh, similarity, material).export(path, file_type="obj", mtl_name=mtl.name, include_normals=True)
    return [path, mtl, path.parent / f"{OBJ_TEXTURE}.png"]


def spread(names: list[str], count: int) -> list[str]:
    """At most ``count`` of ``names`` (all where ``count`` is 0), evenly spaced along them: photos in capture
    order, of which neighbours see much the same, so the texture loses little and bakes in a share of the time."""
    if count <= 0 or len(names) <= count:
        return names
    return [names[i] for i in np.unique(np.linspace(0, len(names) - 1, count).round().astype(int))]
