"""Export benchmark: are the point cloud and the mesh of a trained lego where the object is?

Run by hand from the repository root, with ../shared beside it:

    python scripts/bench_export.py                  # fast preset, lego at 100x100, all exports
    python scripts/bench_export.py --run-dir /tmp/lego-export --set export_mesh.method=tsdf

Trains lego's train split with the train stage (as ``bench_train.py``), runs export_depth at full
(100 px) resolution, export_points and export_mesh, then prints:

- points in masks: of all (point, training view) pairs where the exported point projects inside the
  image, the share that lands inside that view's alpha mask (alpha >= 0.5);
- mesh depth against NeRF depth: the mesh (back in the normalized world) is ray-cast with Open3D at every
  held-out view, and its depth compared with the exported NeRF depth over pixels where both exist
  (NeRF opacity >= 0.5 and a mesh hit); the median absolute difference as a share of the scene box
  diagonal;
- the time each stage took.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from nerfpipe import Pipeline, default_stages
from nerfpipe.artifacts import Bounds, ViewSplit, frame_image_path
from nerfpipe.export.depth import DepthIndex
from nerfpipe.export.mesh import read_mesh, transformed
from nerfpipe.export.points import read_ply
from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.geometry.normalize import Similarity
from nerfpipe.imaging.png import read_png
from nerfpipe.pipeline.params import parse_assignments

REPO = Path(__file__).resolve().parents[1]
LEGO = REPO.parent / "shared" / "data" / "nerf_synthetic_lego_400"


def points_in_masks(points: np.ndarray, world: CameraSet, masks: dict[str, np.ndarray]) -> tuple[float, int]:
    """Share of (point, view) pairs projecting inside the image that land in the view's mask; pair count."""
    inside_mask = total = 0
    for frame in world.frames:
        if frame.name not in masks:
            continue
        camera = world.camera_of(frame)
        w2c = np.linalg.inv(np.asarray(frame.c2w))
        cam = points @ w2c[:3, :3].T + w2c[:3, 3]
        front = cam[:, 2] > 1e-6
        u = camera.fx * cam[front, 0] / cam[front, 2] + camera.cx
        v = camera.fy * cam[front, 1] / cam[front, 2] + camera.cy
        mask = masks[frame.name]
        h, w = mask.shape
        ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        total += int(ok.sum())
        inside_mask += int(mask[v[ok].astype(int), u[ok].astype(int)].sum())
    return inside_mask / max(total, 1), total


def mesh_depth(mesh_world, K: np.ndarray, c2w: np.ndarray, width: int, height: int) -> np.ndarray:
    """Depth along the camera axis of the first mesh hit per pixel centre (inf: no hit)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh_world.vertices.astype(np.float32)),
                        o3d.core.Tensor(mesh_world.triangles.astype(np.uint32)))
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    dirs_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1).reshape(-1, 3)
    dirs = dirs_cam @ np.asarray(c2w)[:3, :3].T  # unit z in the camera: t is the depth along its axis
    origins = np.broadcast_to(np.asarray(c2w)[:3, 3], dirs.shape)
    rays = o3d.core.Tensor(np.concatenate([origins, dirs], axis=1).astype(np.float32))
    return scene.cast_rays(rays)["t_hit"].numpy().reshape(height, width)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--size", type=int, default=100, help="longest image side")
    parser.add_argument("--set", action="append", default=[], help="STAGE.PARAM=VALUE, as for nerfpipe run")
    parser.add_argument("--run-dir", type=Path, default=None, help="keep the run here (default: a temporary folder)")
    args = parser.parse_args()
    if not LEGO.is_dir():
        sys.exit(f"lego not found at {LEGO}: put ../shared beside the checkout")
    overrides = parse_assignments([f"ingest.max_size={args.size}", "train.eval_stride=4", "export_depth.scale=1",
                                   *args.set])
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = args.run_dir or Path(tmp) / "lego"
        pipe = Pipeline(default_stages(), LEGO, run_dir, args.preset, overrides)
        outcomes = pipe.run(until="export_mesh")
        print(f"preset {args.preset}, lego {args.size}px, run directory {run_dir}")
        print("\n| stage | time |\n|---|---:|")
        for o in outcomes:
            seconds = o.seconds if o.action == "ran" else pipe.result(o.name).manifest["timings"]["seconds"]
            print(f"| {o.name} | {seconds:.0f} s{'' if o.action == 'ran' else ' (cached)'} |")

        bounds = Bounds.load(pipe.stage_inputs("export_points")["bounds"])
        to_world = np.asarray(bounds.to_world)
        lo, hi = bounds.box()
        diagonal = float(np.linalg.norm(hi - lo))
        train_inputs = pipe.stage_inputs("train")
        world = CameraSet.load(train_inputs["world"])
        roots = CameraSet.load(train_inputs["pinhole"]).extra.get("image_roots", {})
        views = ViewSplit.load(pipe.result("train").path / "views.json")
        masks = {}
        for name in views.train:
            pixels = read_png(frame_image_path(name, roots.get(name, "ingest"), train_inputs["images"],
                                               train_inputs["undistorted_images"]))
            if pixels.ndim != 3 or pixels.shape[-1] != 4:
                sys.exit(f"{name} has no alpha channel to test against")
            masks[name] = pixels[..., 3] >= (0.5 * (65535 if pixels.dtype == np.uint16 else 255))

        points = read_ply(pipe.result("export_points").path / "points.ply")
        share, pairs = points_in_masks(Similarity.from_matrix(to_world).apply_points(points.xyz), world, masks)
        print(f"\npoints: {len(points.xyz)}; {100 * share:.2f} % of {pairs} (point, training view) pairs inside the image "
              f"land inside the view's alpha mask (target >= 95 %)")

        mesh = transformed(read_mesh(pipe.result("export_mesh").path / "mesh.ply"), to_world)
        depth_result = pipe.result("export_depth")
        index = DepthIndex.load(depth_result.path / "depth.json")
        differences = []
        for view in index.views:
            if view.role != "heldout":
                continue
            nerf = np.load(depth_result.path / "depth" / f"{view.stem}.depth.npy")
            acc = np.load(depth_result.path / "depth" / f"{view.stem}.acc.npy")
            hit = mesh_depth(mesh, view.K(), np.asarray(view.c2w), view.width, view.height)
            both = (acc >= 0.5) & np.isfinite(hit)
            differences.append(np.abs(hit[both] - nerf[both]))
        diff = np.concatenate(differences)
        print(f"mesh: {mesh.faces} triangles; mesh depth vs NeRF depth at {len(differences)} held-out views over "
              f"{len(diff)} pixels: median |difference| {np.median(diff):.4f} = {100 * np.median(diff) / diagonal:.2f} % "
              f"of the scene box diagonal {diagonal:.3f} (target <= 2 %); 90th percentile "
              f"{100 * np.percentile(diff, 90) / diagonal:.2f} %")


if __name__ == "__main__":
    main()
