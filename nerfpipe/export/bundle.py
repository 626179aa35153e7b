"""``RUN_DIR/exports/``: what a user takes away from a run, in one place with stable names, rather than in
the stages' hashed result folders.

- ``mesh.glb``, ``mesh.ply``, ``mesh.obj``: the export_mesh stage's mesh (and ``mesh_watertight.*``,
  ``mesh_poisson.*`` where it made them);
- ``points.ply``: the export_points stage's point cloud;
- ``render.mp4``, ``depth.mp4``: the render stage's videos;
- ``depth/``: the export_depth stage's depth maps (``.npy``, 16-bit PNG, previews);
- ``transforms.json`` and ``images/``: the cameras the field was trained with (refined where pose refinement
  ran), in nerfstudio's and instant-ngp's conventions, with the photos they were trained on;
- ``colmap/``: the same cameras as a COLMAP text model (``cameras.txt``, ``images.txt``, an empty
  ``points3D.txt``).

Everything is in the SfM frame, as the stages write it (the GLB alone is +Y up). The files are hard links
to the results where the filesystem allows (no space taken, and a later ``nerfpipe clean`` cannot break
them), copies otherwise; ``collect`` writes the folder anew, so it always holds the latest run's results.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nerfpipe.geometry.cameras import OPENGL_TO_OPENCV, CameraSet

EXPORTS = "exports"
# (artifact, name in exports/): the files and folders ``collect`` takes from the stages' results
FILES = (("mesh_glb", "mesh.glb"), ("mesh", "mesh.ply"), ("mesh_obj", "mesh.obj"), ("points", "points.ply"),
         ("video", "render.mp4"), ("depth_video", "depth.mp4"), ("depth", "depth"))


@dataclass(frozen=True)
class Exported:
    """What ``collect`` put in the folder: each name (a file or folder under it), and what it left out."""

    folder: Path
    names: tuple[str, ...]
    missing: tuple[str, ...]


def transforms_json(cameras: CameraSet, image_paths: dict[str, str]) -> dict[str, Any]:
    """nerfstudio's / instant-ngp's ``transforms.json`` for ``cameras`` (pinhole, OpenCV c2w in any frame):
    ``transform_matrix`` is the OpenGL camera-to-world (x right, y up, z back), ``fl_x``, ``fl_y``, ``cx``,
    ``cy``, ``w``, ``h`` and zero distortion (the images are undistorted) at the top when every frame shares
    one camera, per frame otherwise. ``image_paths``: frame name -> its ``file_path``."""
    shared = len({f.camera_id for f in cameras.frames}) == 1

    def intrinsics(camera_id: int) -> dict[str, Any]:
        camera = cameras.cameras[camera_id]
        if camera.model != "PINHOLE" and camera.model != "SIMPLE_PINHOLE":
            raise ValueError(f"transforms.json holds pinhole cameras; camera {camera_id} is {camera.model}")
        return {"camera_model": "OPENCV", "fl_x": camera.fx, "fl_y": camera.fy, "cx": camera.cx, "cy": camera.cy,
                "w": camera.width, "h": camera.height, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0}

    frames = []
    for frame in cameras.frames:
        entry: dict[str, Any] = {"file_path": image_paths[frame.name],
                                 "transform_matrix": (np.asarray(frame.c2w) @ OPENGL_TO_OPENCV).tolist()}
        if not shared:
            entry.update(intrinsics(frame.camera_id))
        frames.append(entry)
    doc: dict[str, Any] = intrinsics(cameras.frames[0].camera_id) if shared and cameras.frames else {}
    doc["frames"] = frames
    return doc


def colmap_text(cameras: CameraSet, folder: Path) -> None:
    """``cameras`` (pinhole, OpenCV c2w) as a COLMAP text model in ``folder``: ``cameras.txt`` (PINHOLE),
    ``images.txt`` (world-to-camera as quaternion and translation, no 2D points) and an empty
    ``points3D.txt``, in COLMAP's documented format, as pycolmap and COLMAP read it."""
    from nerfpipe.geometry.cameras import invert_pose

    folder.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
             f"# Number of cameras: {len(cameras.cameras)}"]
    for camera_id, camera in sorted(cameras.cameras.items()):
        lines.append(f"{camera_id} PINHOLE {camera.width} {camera.height} "
                     f"{camera.fx!r} {camera.fy!r} {camera.cx!r} {camera.cy!r}")
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(cameras.frames)}, mean observations per image: 0"]
    for image_id, frame in enumerate(cameras.frames, start=1):
        w2c = invert_pose(np.asarray(frame.c2w))
        qw, qx, qy, qz = quaternion(w2c[:3, :3])
        tx, ty, tz = (float(v) for v in w2c[:3, 3])
        lines += [f"{image_id} {qw!r} {qx!r} {qy!r} {qz!r} {tx!r} {ty!r} {tz!r} {frame.camera_id} {frame.name}", ""]
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    (folder / "points3D.txt").write_text("# 3D point list (none: the cameras only)\n")


def quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation matrix, w >= 0, as COLMAP writes them (scipy's, reordered)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    sign = 1.0 if w >= 0 else -1.0
    return float(sign * w), float(sign * x), float(sign * y), float(sign * z)


def collect(run_dir: Path, artifacts: dict[str, Path | None], cameras: CameraSet | None,
            images: dict[str, Path], extra: tuple[Path, ...] = ()) -> Exported:
    """Write ``run_dir/exports`` anew from ``artifacts`` (name -> path, None where its stage made nothing)
    and the trained ``cameras`` in the SfM frame with each frame's photo (``images``: name -> file); the
    ``extra`` files (optional outputs such as the watertight mesh) under their own names."""
    folder = run_dir / EXPORTS
    staging = run_dir / f".{EXPORTS}.new"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    names, missing = [], []
    for artifact, name in FILES:
        source = artifacts.get(artifact)
        if source is None or not source.exists():
            missing.append(name)
            continue
        _link_or_copy(source, staging / name)
        names.append(name)
    for source in extra:
        _link_or_copy(source, staging / source.name)
        names.append(source.name)
    if cameras is not None and cameras.frames:
        paths = {}
        for frame in cameras.frames:
            _link_or_copy(images[frame.name], staging / "images" / frame.name)
            paths[frame.name] = f"images/{frame.name}"
        from nerfpipe.pipeline.store import write_json_atomic

        write_json_atomic(staging / "transforms.json", transforms_json(cameras, paths))
        colmap_text(cameras, staging / "colmap")
        names += ["transforms.json", "images", "colmap"]
    else:
        missing += ["transforms.json", "images", "colmap"]
    old = run_dir / f".{EXPORTS}.old"
    shutil.rmtree(old, ignore_errors=True)
    if folder.exists():
        os.rename(folder, old)
    os.rename(staging, folder)
    shutil.rmtree(old, ignore_errors=True)
    return Exported(folder, tuple(names), tuple(missing))


def copy_exports(folder: Path, target: Path) -> int:
    """Copy an exports folder to ``target`` (created; files it already holds are replaced), links resolved
    to their files; returns the bytes copied."""
    copied = 0
    for path in sorted(folder.rglob("*")):
        if path.is_file():
            destination = target / path.relative_to(folder)
            destination.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, destination)
            copied += path.stat().st_size
    return copied


def _link_or_copy(source: Path, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    if source.is_dir():
        for path in sorted(source.rglob("*")):
            if path.is_file():
                _link_or_copy(path, target / path.relative_to(source))
        return
    try:
        os.link(source, target)
    except OSError:
        shutil.copyfile(source, target)
