"""export_mesh: a coloured triangle mesh of the trained field, as PLY and OBJ in the original SfM frame and
as a textured GLB (+Y up).

Methods:

- ``auto`` (default): ``marching_cubes`` for an object the photos show on a backdrop (the scene stage's
  background decision is ``alpha`` or ``color``), ``poisson`` for a scene (background ``none``). A scene's
  field holds its floor and walls as a thin fog more than as a sharp shell, so a density level set breaks
  them into fragments, while depth maps that several views agree on hold them well.
- ``marching_cubes``: the surface where the density crosses ``density_threshold``, on a grid of
  ``resolution`` voxels along the longest side of the scene box (of the NDC cube for forward-facing
  captures), evaluated block by block so memory stays bounded; vertex colours are rendered from the
  field, looking at each vertex against its normal, where no texture is baked.
- ``poisson``: a screened Poisson surface (Kazhdan and Hoppe 2013) of the exported point cloud, whose
  points are those neighbouring views' depth maps agree on, over the scene box: the region the cameras
  look at.
- ``tsdf``: TSDF fusion of the rendered depth and colour of the training views (Open3D).

With ``texture`` (the default), the mesh is simplified to ``texture_faces`` triangles and textured from the
training photos at their trained poses (``nerfpipe.export.texture``): that is the GLB, and the vertex
colours of the PLY and OBJ are read off it. The textured mesh is rendered at the held-out views and scored
against the same photos as the field, and its mean colour against theirs.

With ``poisson_too``, a Poisson surface of the point cloud is also written beside another method's mesh
(``mesh_poisson.*``). Every mesh loses its small disconnected pieces and is simplified to ``target_faces``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from nerfpipe.artifacts import BOUNDS, CAMERAS, SCENE, VIEWS, Bounds, SceneDecisions
from nerfpipe.pipeline.budget import check_affordable
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.resources import check_memory
from nerfpipe.pipeline.summary import Summary
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs

FORMATS = (".ply", ".obj", ".glb")


@dataclass(frozen=True)
class ExportMeshParams:
    method: Literal["auto", "marching_cubes", "poisson", "tsdf"] = field(default="auto", metadata={"help": "auto: marching cubes for an object on a backdrop, poisson for a scene; marching cubes on the density, a Poisson surface of the point cloud, or TSDF fusion of the rendered depth"})
    resolution: int = field(default=256, metadata={"bounds": (8, 2048), "help": "voxels along the longest side of the box (both methods)"})
    density_threshold: float = field(default=25.0, metadata={"bounds": (0.0, 1000000.0), "help": "marching cubes: the density of the surface (per normalized unit)"})
    block: int = field(default=64, metadata={"bounds": (8, 512), "help": "marching cubes: voxels per block side; memory grows with its cube, not the resolution's"})
    truncation: float = field(default=4.0, metadata={"bounds": (0.1, 100.0), "help": "tsdf: truncation distance in voxels"})
    acc_threshold: float = field(default=0.9, metadata={"bounds": (0.0, 1.0), "help": "tsdf: fuse pixels whose accumulated opacity reaches this"})
    poisson_too: bool = field(default=False, metadata={"help": "also a screened Poisson surface of the point cloud (mesh_poisson.*) beside another method's mesh"})
    poisson_depth: int = field(default=7, metadata={"bounds": (1, 11), "help": "poisson: octree depth, cells of 1/2^depth of the box's side (7 fills more of a noisy scene cloud than 8, in 0.4 the time)"})
    min_component: float = field(default=0.05, metadata={"bounds": (0.0, 1.0), "help": "drop connected pieces with fewer triangles than this fraction of the largest"})
    region: Literal["box", "all"] = field(default="box", metadata={"help": "contracted scenes: mesh the scene box, or all of space out to where the contraction ends"})
    target_faces: int = field(default=200_000, metadata={"bounds": (0, 100_000_000), "help": "simplify to at most this many triangles (0: keep all)"})
    watertight: bool = field(default=False, metadata={"help": "also a closed, manifold remesh of the solid (mesh_watertight.*), for printing: tunnels closed, hollows filled, the largest piece kept"})
    close_voxels: int = field(default=4, metadata={"bounds": (0, 64), "help": "watertight: close tunnels and gaps up to about twice this many voxels wide"})
    texture: int = field(default=1024, metadata={"bounds": (0, 8192), "help": "texture size in texels a side, baked from the training photos into mesh.glb (and the vertex colours); 0: vertex colours from the field"})
    texture_faces: int = field(default=50_000, metadata={"bounds": (1, 10_000_000), "help": "triangles of the textured mesh (the photos' detail is in the texture)"})
    texture_photos: int = field(default=24, metadata={"bounds": (0, 10_000), "help": "bake from at most this many training photos, spread evenly over them (0: all); each costs about 0.8 s at 1024 texels"})
    device: Literal["auto", "cpu", "cuda"] = field(default="auto", metadata={"keyed": False, "help": "auto: CUDA when present, else CPU"})

    def __post_init__(self) -> None:
        for name in ("resolution", "block", "poisson_depth"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("density_threshold", "truncation", "min_component", "target_faces", "texture", "texture_faces", "texture_photos",
                     "close_voxels"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not 0 <= self.acc_threshold <= 1:
            raise ValueError(f"acc_threshold must be in [0, 1], got {self.acc_threshold}")
        check_memory("texture", "the texture's texels, with the photos' sums baked into them", TEXEL_BYTES * self.texture**2)


@dataclass(frozen=True)
class ExportMeshSummary(Summary):
    """The mesh: its method, size and pieces; the texture and how the textured mesh scored on the held-out
    views (``nerfpipe.export.mesh_score``); the watertight remesh and the Poisson surface, where made."""

    method: str = ""
    faces: int = 0
    vertices: int = 0
    voxel: float = 0.0
    components: int = 0
    components_kept: int = 0
    faces_before_cleaning: int = 0
    poisson_faces: int | None = None
    texture: dict[str, Any] | None = None  # {"size", "faces", "photos", "seconds"}
    heldout: dict[str, Any] | None = None  # ``score_views``
    watertight: dict[str, Any] | None = None  # ``nerfpipe.export.solid.closure``
    seconds: float = 0.0

    def describe(self) -> list[str]:
        if not self.faces:
            return []
        lines = [f"{self.method}: {self.faces} triangles, {self.vertices} vertices ({self.components_kept} of "
                 f"{self.components} pieces kept) at voxel {self.voxel:.4g}, {self.seconds:.0f} s"]
        if self.texture is not None:
            t = self.texture
            lines.append(f"texture: {t['size']} x {t['size']} texels on {t['faces']} triangles, from {t['photos']} "
                         f"training photos in {t['seconds']:.0f} s (mesh.glb)")
        if self.heldout is not None:
            h = self.heldout
            lines.append(f"held-out views: the textured mesh {h['mesh_psnr']:.2f} dB ({h['covered_psnr']:.2f} dB over "
                         f"the {100 * h['coverage']:.0f} % of the pixels it covers), the field {h['field_psnr']:.2f} dB; "
                         f"mean colour {100 * float(np.mean(h['colour_ratio'])):.0f} % of the photos'")
        if self.poisson_faces is not None:
            lines.append(f"poisson: {self.poisson_faces} triangles")
        return lines


class ExportMeshStage(Stage):
    """Triangle mesh (marching cubes, a Poisson surface of the points, or TSDF fusion) as PLY, OBJ and GLB in
    the SfM frame."""

    name = "export_mesh"
    version = 5  # 5: the OBJ textured (mesh.mtl, mesh_texture.png), the GLB with normals; 4: a scene by Poisson, the blend of the photos corrected for those missing a texel; 3: a texture from the photos, scored on the held-out views; 2: the GLB +Y up, PBR, linear colours
    Params = ExportMeshParams
    Summary = ExportMeshSummary
    presets = {
        "preview": {"resolution": 128, "target_faces": 50_000},
        "fine": {"resolution": 512, "target_faces": 1_000_000},
        "tsdf": {"method": "tsdf"},
        "poisson": {"method": "poisson"},
    }
    requires = ("model", "model_json", "bounds", "depth", "depth_index", "points", "cameras", "views", "metrics", "eval",
                "images", "undistorted_images", "pinhole", "scene")
    provides = {"mesh": "mesh.ply", "mesh_obj": "mesh.obj", "mesh_glb": "mesh.glb"}
    budget_share = 0.12  # reserved under a job budget: the surface and the texture (temple: 38 s of 200; beer: 49 s of 442)
    optional = True
    libraries = ("torch", "numpy", "open3d", "trimesh")
    accelerated = True

    def run(self, inputs: StageInputs, out: Path, params: ExportMeshParams, ctx: StageContext) -> ExportMeshSummary:
        from nerfpipe.nerf.device import rendering_device

        # the bar: the surface, cleaned, coloured (textured and scored), written, and the optional meshes
        steps = 4 + bool(params.watertight) + bool(params.poisson_too)
        with rendering_device(params.device, "export_mesh.device") as device, ctx.progress(steps, "export mesh") as advance:
            return self._run(inputs, out, params, ctx, device, advance)

    def _run(self, inputs: StageInputs, out: Path, params: ExportMeshParams, ctx: StageContext,
             device, advance) -> ExportMeshSummary:
        import torch

        from nerfpipe.export import points as point_clouds
        from nerfpipe.export.depth import DEPTH_INDEX, read_view
        from nerfpipe.export.mesh import (
            Grid,
            clean,
            evaluate_density,
            gltf_frame,
            marching_cubes,
            poisson,
            surface_colors,
            transformed,
            tsdf_fusion,
            vertex_normals,
            write_mesh,
        )
        from nerfpipe.export.texture import UnchartableMeshError, colours_at, write_textured_glb, write_textured_obj
        from nerfpipe.nerf.kernels import for_rendering
        from nerfpipe.nerf.model import RadianceModel

        started = time.perf_counter()
        bounds = inputs.load(BOUNDS)
        lo, hi = bounds.box()
        model = RadianceModel.load(inputs["model"].parent, device)
        far = max(f.far for f in bounds.frames)
        scene = inputs.load(SCENE)
        method = chosen_method(params.method, scene)
        if method == "marching_cubes":
            box = model.ray_space.mesh_box(far, (tuple(lo), tuple(hi)), params.region)
            grid = Grid.over(box[0], box[1], params.resolution)
            field = for_rendering(model.fine if model.fine is not None else model.coarse)  # compiled where that pays
            predicted = timed(lambda pts: evaluate_density(field.query_density, pts, device=device), box, grid.voxel,
                              PROBE_POINTS) * float(np.prod(grid.cells)) / PROBE_POINTS
            ctx.log.info("export_mesh: marching cubes on %s voxels of %.4g at density %g, about %.0f s of density",
                         "x".join(map(str, grid.cells)), grid.voxel, params.density_threshold, predicted)
            check_affordable(ctx.allotment, predicted, f"export_mesh: marching cubes at resolution {params.resolution}",
                             "lower export_mesh.resolution")
            mesh = marching_cubes(field.query_density, grid, params.density_threshold, params.block, device=device)
            mesh.vertices = model.ray_space.from_field(torch.as_tensor(mesh.vertices)).numpy()
            voxel = model.ray_space.world_voxel(grid.voxel, params.resolution, (tuple(lo), tuple(hi)))
        elif method == "poisson":
            points = agreed_points(inputs, bounds)
            box = (lo, hi) if scene.layout.value != "forward" else (points.xyz.min(axis=0), points.xyz.max(axis=0))
            voxel = float((box[1] - box[0]).max()) / 2 ** params.poisson_depth
            ctx.log.info("export_mesh: a Poisson surface of %d points at octree depth %d (cells of %.4g)", len(points),
                         params.poisson_depth, voxel)
            mesh = poisson(point_clouds.to_open3d(points), params.poisson_depth, box=box)
        else:
            index = inputs.load(DEPTH_INDEX)
            views = [(read_view(inputs["depth"], v), v.K(), np.asarray(v.c2w)) for v in index.views if v.role == "train"]
            voxel = float((hi - lo).max()) / params.resolution
            ctx.log.info("export_mesh: TSDF fusion of %d views at voxel %.4g", len(views), voxel)
            mesh = tsdf_fusion(views, (lo, hi), voxel, params.truncation * voxel, params.acc_threshold, far)
        if mesh.faces == 0:
            raise StageError(f"export_mesh: {method} found no surface; " + NO_SURFACE[method] + " or train longer")
        advance(1, f"{method.replace('_', ' ')}: {mesh.faces:,} triangles")
        mesh, report = clean(mesh, params.min_component, params.target_faces)
        advance(1, f"cleaned: {mesh.faces:,} triangles")
        textured, scores = None, {}
        if params.texture:
            try:
                textured, scores = bake_and_score(inputs, mesh, params, ctx)
                mesh.colors = colours_at(textured, mesh.vertices)
            except UnchartableMeshError as err:
                ctx.log.warning("export_mesh: no texture: %s; the mesh keeps vertex colours", err)
        if textured is None and method == "marching_cubes":
            normals = vertex_normals(mesh)
            probe = slice(0, min(PROBE_POINTS // 16, len(mesh.vertices)))
            began = time.perf_counter()
            first = surface_colors(model, mesh.vertices[probe], normals[probe], 2 * voxel)
            ctx.log.info("export_mesh: colouring %d vertices from the field, about %.0f s", len(mesh.vertices),
                         (time.perf_counter() - began) * len(mesh.vertices) / max(len(first), 1))
            rest = [surface_colors(model, mesh.vertices[probe.stop:], normals[probe.stop:], 2 * voxel)] \
                if probe.stop < len(mesh.vertices) else []
            mesh.colors = np.concatenate([first, *rest])
        advance(1, "textured" if textured is not None else "coloured")
        in_sfm = transformed(mesh, bounds.to_sfm)
        to_gltf = gltf_frame(bounds.to_world) @ np.asarray(bounds.to_sfm)  # from the world the mesh is in
        for suffix in FORMATS:
            if suffix == ".glb" and textured is not None:
                write_textured_glb(out / "mesh.glb", textured, to_gltf, GLB_UNITS)
            elif suffix == ".obj" and textured is not None:  # with mesh.mtl and mesh_texture.png
                write_textured_obj(out / "mesh.obj", textured, np.asarray(bounds.to_sfm))
            else:
                write_mesh(in_sfm if suffix != ".glb" else transformed(mesh, to_gltf), out / f"mesh{suffix}")
        advance(1, "written")
        summary: dict[str, Any] = {
            "method": method, "faces": mesh.faces, "vertices": len(mesh.vertices), "voxel": voxel,
            "components": report.components, "components_kept": report.components_kept,
            "faces_before_cleaning": report.faces_before, **scores,
        }
        if params.watertight:
            grid = Grid.over(*model.ray_space.mesh_box(far, (tuple(lo), tuple(hi)), params.region), params.resolution)
            summary["watertight"] = write_watertight(out, model, grid, params, device, textured, bounds, to_gltf)
            ctx.log.info("export_mesh: a watertight remesh of %(faces)d triangles, Euler number %(euler)d, watertight "
                         "%(watertight)s, edge-manifold %(edge_manifold)s -> mesh_watertight.ply, .glb",
                         summary["watertight"])
            advance(1, "watertight remesh")
        if params.poisson_too and method != "poisson":
            surface = poisson(point_clouds.to_open3d(agreed_points(inputs, bounds)), params.poisson_depth, box=(lo, hi))
            surface, _ = clean(surface, params.min_component, params.target_faces)
            surface = transformed(surface, bounds.to_sfm)
            for suffix in FORMATS:
                write_mesh(surface if suffix != ".glb" else transformed(surface, gltf_frame(bounds.to_world)),
                           out / f"mesh_poisson{suffix}")
            summary["poisson_faces"] = surface.faces
            advance(1, "Poisson surface")
        summary["seconds"] = round(time.perf_counter() - started, 2)
        ctx.log.info("export_mesh: %d triangles, %d vertices -> mesh.ply, mesh.obj%s (SfM frame), mesh.glb (+Y up)",
                     mesh.faces, len(mesh.vertices), " with mesh.mtl and mesh_texture.png" if textured is not None else "")
        return ExportMeshSummary(**summary)


GLB_UNITS = "arbitrary (the SfM frame's)"
NO_SURFACE = {"marching_cubes": "lower export_mesh.density_threshold", "tsdf": "lower export_mesh.acc_threshold",
              "poisson": "export_points kept no point (see its log)"}


def agreed_points(inputs: StageInputs, bounds: Bounds) -> Any:
    """The export_points stage's cloud (the points neighbouring views' depth maps agree on) in the
    normalized world. Raises ``StageError`` when it holds no point."""
    from nerfpipe.export import points as point_clouds

    points = point_clouds.transformed(point_clouds.read_ply(inputs["points"]), bounds.to_world)
    if not len(points):
        raise StageError("export_mesh: the point cloud is empty, so there is no Poisson surface; see "
                         "export_points' log, or set export_mesh.method=marching_cubes")
    return points


def chosen_method(method: str, scene: SceneDecisions) -> str:
    """The mesh method ``auto`` stands for: marching cubes on the density for an object on a backdrop (the
    background decision ``alpha`` or ``color``), a Poisson surface of the agreed points for a scene."""
    if method != "auto":
        return method
    return "poisson" if scene.background.value == "none" else "marching_cubes"


def write_watertight(out: Path, model: Any, grid: Any, params: ExportMeshParams, device: Any, textured: Any,
                     bounds: Bounds, to_gltf: np.ndarray) -> dict[str, Any]:
    """``mesh_watertight.ply`` (SfM frame) and ``.glb`` (+Y up): the closed, manifold remesh of where the
    density reaches the threshold (``nerfpipe.export.solid``), coloured from the texture if there is one;
    returns what trimesh and Open3D say of it."""
    import torch

    from nerfpipe.export.mesh import transformed, write_mesh
    from nerfpipe.export.solid import closure, watertight
    from nerfpipe.export.texture import colours_at
    from nerfpipe.nerf.kernels import for_rendering

    field = for_rendering(model.fine if model.fine is not None else model.coarse)  # compiled where that pays
    try:
        mesh = watertight(field.query_density, grid, params.density_threshold, params.block, device, params.close_voxels)
    except ValueError:
        raise StageError("export_mesh: the watertight remesh found no solid; lower export_mesh.density_threshold") from None
    mesh.vertices = model.ray_space.from_field(torch.as_tensor(mesh.vertices)).numpy()
    if textured is not None:
        mesh.colors = colours_at(textured, mesh.vertices)
    write_mesh(transformed(mesh, bounds.to_sfm), out / "mesh_watertight.ply")
    write_mesh(transformed(mesh, to_gltf), out / "mesh_watertight.glb")
    return closure(mesh)


def bake_and_score(inputs: StageInputs, mesh: Any, params: ExportMeshParams, ctx: StageContext) -> tuple[Any, dict]:
    """The mesh (normalized world) textured from the training photos at their trained poses
    (``nerfpipe.export.texture.bake``), and how its renders score on the held-out views beside the field's
    (``nerfpipe.export.mesh_score``): against the same photos the train stage scored on."""
    from nerfpipe.artifacts import view_file_stem
    from nerfpipe.export.mesh_score import HeldoutView, score_views
    from nerfpipe.export.texture import Photo, bake, spread
    from nerfpipe.imaging.png import read_png
    from nerfpipe.nerf.train.images import ImageLoader

    began = time.perf_counter()
    cameras = inputs.load(CAMERAS)
    loader = ImageLoader(inputs["images"], inputs["undistorted_images"], inputs["pinhole"], cameras,
                         inputs.load(BOUNDS), inputs.load(SCENE))
    frames = {f.name: f for f in cameras.frames}

    def intrinsics(camera: Any) -> np.ndarray:
        return np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]])

    names = spread([n for n in inputs.load(VIEWS).train if n in frames], params.texture_photos)
    photos = [Photo(np.round(np.clip(loader.image(frames[n]), 0, 1) * 255).astype(np.uint8),
                    intrinsics(cameras.camera_of(frames[n])), np.asarray(frames[n].c2w)) for n in names]
    textured = bake(mesh, photos, params.texture_faces, params.texture)
    seconds = time.perf_counter() - began
    ctx.log.info("export_mesh: a %d x %d texture on %d triangles from %d training photos in %.0f s", params.texture,
                 params.texture, textured.faces, len(photos), seconds)
    views = []
    for view in json.loads(inputs["metrics"].read_text(encoding="utf-8")).get("views", []):
        truth = inputs["eval"] / f"{view_file_stem(view['name'])}.gt.png"
        if view["name"] not in frames or not truth.exists():
            continue
        photo = read_png(truth)[..., :3].astype(np.float64) / 255.0
        camera = cameras.camera_of(frames[view["name"]])
        camera = camera.scaled(photo.shape[1] / camera.width, photo.shape[0] / camera.height)
        views.append(HeldoutView(photo, intrinsics(camera), np.asarray(frames[view["name"]].c2w), float(view["psnr"])))
    scores: dict[str, Any] = {"texture": {"size": params.texture, "faces": textured.faces, "photos": len(photos),
                                          "seconds": round(seconds, 1)}}
    heldout = score_views(textured, views, loader.background)
    if heldout is not None:
        scores["heldout"] = heldout
        ratio = heldout["colour_ratio"]
        ctx.log.info("export_mesh: the textured mesh on %d held-out views: PSNR %.2f dB (the field: %.2f dB); over the "
                     "%.0f %% of the pixels it covers %.2f dB, its mean colour there %.0f %% of the photos' (r, g, b: %s)",
                     len(views), heldout["mesh_psnr"], heldout["field_psnr"], 100 * heldout["coverage"],
                     heldout["covered_psnr"], 100 * float(np.mean(ratio)), ", ".join(f"{r:.3f}" for r in ratio))
    return textured, scores


TEXEL_BYTES = 64  # a texel's colour sums, weights and best view while baking, in float32 and float64
PROBE_POINTS = 65_536  # density queries timed to predict what marching cubes costs (a sixteenth of them: colours)


def timed(query, box, spacing: float, count: int) -> float:
    """Seconds ``query`` takes on a block of about ``count`` grid points ``spacing`` apart at the centre of
    ``box`` (in the order marching cubes visits its blocks), after one warm-up call."""
    side = round(count ** (1 / 3))
    centre = (np.asarray(box[0], dtype=np.float64) + np.asarray(box[1], dtype=np.float64)) / 2
    axes = [c + (np.arange(side) - side / 2) * spacing for c in centre]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3).astype(np.float32)
    query(points[:256])
    began = time.perf_counter()
    query(points)
    return time.perf_counter() - began
