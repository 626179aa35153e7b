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

Everything is in the SfM frame, as the stages write it (the GLB alone is +Y up). The files are copies of the
results, never links: editing or deleting one cannot reach the cache. ``collect`` writes the folder anew, so it
always holds the latest run's results, and only inside a run directory nerfpipe made.

``copy_exports`` (``nerfpipe export --to``) writes a folder of the user's choosing, and so overwrites only what
an earlier export wrote there (``.nerfpipe-export.json`` lists it, with each file's sha256).
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nerfpipe.geometry.cameras import OPENGL_TO_OPENCV, CameraSet
from nerfpipe.pipeline.errors import InputError
from nerfpipe.pipeline.hashing import sha256_file
from nerfpipe.pipeline.store import RUN_MARKER, is_run_dir, require_run_dir, write_json_atomic

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
    require_run_dir(run_dir, "exports/")
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
        _copy(source, staging / name)
        names.append(name)
    for source in extra:
        _copy(source, staging / source.name)
        names.append(source.name)
    if cameras is not None and cameras.frames:
        paths = {}
        for frame in cameras.frames:
            _copy(images[frame.name], staging / "images" / frame.name)
            paths[frame.name] = f"images/{frame.name}"
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


EXPORT_LIST = ".nerfpipe-export.json"
# what marks a folder as a capture, which an export must not write into (its photos would change how it is read)
_CAPTURE_FILES = ("transforms.json", "poses_bounds.npy", "sparse", "images")
_PHOTO_SUFFIXES = {".jpg", ".jpeg", ".jpe", ".jfif", ".png", ".tif", ".tiff", ".dng", ".cr2", ".cr3", ".nef", ".arw",
                   ".raf", ".orf", ".rw2", ".mp4", ".mov"}


def check_export_target(folder: Path, target: Path, run_dir: Path) -> dict[str, str]:
    """Raise ``InputError`` for a ``target`` an export of ``folder`` may not write: a file, a folder inside
    the run directory, a capture (photos or pose files), or a folder holding a file the export would replace
    but did not write. Returns what earlier exports wrote there (name -> sha256)."""
    if target.exists() and not target.is_dir():
        raise InputError(target, "is a file, not a folder", "pass --to a new folder, or one an earlier export made")
    where, run = target.resolve(), run_dir.resolve()
    if where == run or run in where.parents:
        raise InputError(target, f"lies inside the run directory {run_dir}, which the next run rewrites",
                         "pass --to a folder outside it")
    if is_run_dir(target):
        raise InputError(target, f"is a nerfpipe run directory ({RUN_MARKER})", "pass --to a folder outside any run")
    if not target.is_dir():
        return {}
    written = _export_list(target)
    entries = {p.name for p in target.iterdir()}
    if not written and (entries & set(_CAPTURE_FILES) or any(Path(n).suffix.lower() in _PHOTO_SUFFIXES for n in entries)):
        raise InputError(target, "holds photos or pose files: exporting there would change how that capture is read",
                         "pass --to a new folder")
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder).as_posix()
        there = target / rel
        if path.is_file() and there.exists() and (rel not in written or not there.is_file()
                                                  or sha256_file(there) != written[rel]):
            raise InputError(there, "exists and was not written by an earlier `nerfpipe export` (or was changed since)",
                             "move it away, or pass --to a new folder")
    if not os.access(target, os.W_OK | os.X_OK):
        raise InputError(target, "cannot be written to (permission denied)", "pass --to a folder you may write to")
    return written


def copy_exports(folder: Path, target: Path, run_dir: Path) -> int:
    """Copy an exports folder to ``target`` (created), checked first by ``check_export_target``: files an
    earlier export wrote are replaced, nothing else is. Returns the bytes copied."""
    written = check_export_target(folder, target, run_dir)
    files = [p for p in sorted(folder.rglob("*")) if p.is_file()]
    if not files:
        raise InputError(folder, "holds no exports yet", "run `nerfpipe run` to the end first")
    target.mkdir(parents=True, exist_ok=True)
    copied = 0
    for path in files:
        rel = path.relative_to(folder).as_posix()
        destination = target / rel
        destination.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, destination)
        written[rel] = sha256_file(destination)
        copied += path.stat().st_size
        write_json_atomic(target / EXPORT_LIST, {"files": written})  # after each file: an interrupted copy is known
    return copied


def _export_list(target: Path) -> dict[str, str]:
    try:
        files = json.loads((target / EXPORT_LIST).read_text(encoding="utf-8"))["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return {}
    return {k: v for k, v in files.items() if isinstance(k, str) and isinstance(v, str)} if isinstance(files, dict) else {}


def _copy(source: Path, target: Path) -> None:
    """A copy, never a link: an edit of the export must not reach the cached result."""
    target.parent.mkdir(parents=True, exist_ok=True)
    if source.is_dir():
        for path in sorted(source.rglob("*")):
            if path.is_file():
                _copy(path, target / path.relative_to(source))
        return
    shutil.copyfile(source, target)
