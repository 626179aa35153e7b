"""``RUN_DIR/exports/``: what a user takes away from a run, in one place with stable names, rather than in
the stages' hashed result folders, written as the tools that read them expect.

- ``mesh.glb`` (textured, with normals), ``mesh.ply``, ``mesh.obj`` (with ``mesh.mtl`` and
  ``mesh_texture.png`` where the mesh is textured): the export_mesh stage's mesh (and ``mesh_watertight.*``,
  ``mesh_poisson.*`` where it made them);
- ``points.ply``: the export_points stage's point cloud; ``sparse_pc.ply``: the SfM points;
- ``render.mp4``, ``depth.mp4``, ``camera_path.json`` and ``camera_path.nerfstudio.json``: the render stage's
  videos and the path they follow (ours, and nerfstudio's schema);
- ``depth/``: the export_depth stage's depth maps, in the SfM frame's units (``depth/index.json`` lists the
  views with their cameras in that frame);
- ``transforms.json`` with ``images/`` (and ``masks/`` where the scene has a backdrop or alpha): the cameras
  the field was trained with (refined where pose refinement ran), in nerfstudio's and instant-ngp's
  conventions, with nerfstudio's optional fields: ``ply_file_path``, ``train_filenames``/``val_filenames``,
  ``mask_path`` and ``depth_file_path`` per frame;
- ``sparse/0/``: the same cameras and the SfM points as a COLMAP model (binary and text), written by pycolmap:
  what 3D Gaussian splatting trainers start from.

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

from nerfpipe.export.depth import DepthIndex, depth_in_frame
from nerfpipe.geometry.cameras import OPENGL_TO_OPENCV, CameraSet, Points
from nerfpipe.pipeline.errors import InputError
from nerfpipe.pipeline.hashing import sha256_file
from nerfpipe.pipeline.store import RUN_MARKER, is_run_dir, require_run_dir, write_json_atomic

EXPORTS = "exports"
# (artifact, name in exports/): the files and folders ``collect`` takes from the stages' results
FILES = (("mesh_glb", "mesh.glb"), ("mesh", "mesh.ply"), ("mesh_obj", "mesh.obj"), ("points", "points.ply"),
         ("video", "render.mp4"), ("depth_video", "depth.mp4"), ("depth", "depth"), ("camera_path", "camera_path.json"),
         ("camera_path_nerfstudio", "camera_path.nerfstudio.json"))
CAMERA_FILES = ("transforms.json", "images", "sparse")  # written whenever the trained cameras are known
SPARSE_PLY = "sparse_pc.ply"  # nerfstudio's name for the SfM points beside transforms.json


@dataclass(frozen=True)
class Exported:
    """What ``collect`` put in the folder: each name (a file or folder under it), and what it left out."""

    folder: Path
    names: tuple[str, ...]
    missing: tuple[str, ...]


@dataclass(frozen=True)
class CapturedViews:
    """What the camera exports are made of, in the SfM frame: the trained ``cameras``, each frame's photo
    (``images``: name -> file), the SfM ``points`` (or None), each frame's mask (``masks``: name -> its PNG, one
    channel, 0 where the pixel is ignored; None without masks), the held-out frames' names, and the depth maps'
    index (in the normalized world: its ``to_sfm`` maps it into the SfM frame)."""

    cameras: CameraSet
    images: dict[str, Path]
    points: Points | None = None
    masks: dict[str, Path] | None = None
    heldout: tuple[str, ...] = ()
    depth: DepthIndex | None = None


def in_sfm_frame(trained: CameraSet, to_sfm: Any) -> CameraSet:
    """The trained cameras (normalized world) moved into the SfM frame by the bounds' ``to_sfm``, as every
    export and ``nerfpipe.open`` give them."""
    from nerfpipe.export.paths import transform_poses
    from nerfpipe.geometry.cameras import Frame

    poses = transform_poses(np.array([f.c2w for f in trained.frames]), to_sfm) if trained.frames else []
    frames = [Frame(f.name, f.camera_id, pose, f.split) for f, pose in zip(trained.frames, poses)]
    return CameraSet(trained.cameras, frames, None, trained.source)


def transforms_json(cameras: CameraSet, image_paths: dict[str, str], **optional: Any) -> dict[str, Any]:
    """nerfstudio's / instant-ngp's ``transforms.json`` for ``cameras`` (pinhole, OpenCV c2w in any frame):
    ``transform_matrix`` is the OpenGL camera-to-world (x right, y up, z back), ``fl_x``, ``fl_y``, ``cx``,
    ``cy``, ``w``, ``h`` and zero distortion (the images are undistorted) at the top when every frame shares
    one camera, per frame otherwise. ``image_paths``: frame name -> its ``file_path``.

    ``optional``, nerfstudio's optional fields where there are any: ``ply_file_path`` (str),
    ``train_filenames``, ``val_filenames`` and ``test_filenames`` (lists of file paths), ``mask_path`` and ``depth_file_path``
    (frame name -> path), ``depth_unit_scale_factor`` (depth = PNG value x it, in the frame's units)."""
    shared = len({f.camera_id for f in cameras.frames}) == 1
    per_frame = {key: optional.pop(key) or {} for key in ("mask_path", "depth_file_path") if key in optional}

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
        entry.update({key: paths[frame.name] for key, paths in per_frame.items() if frame.name in paths})
        frames.append(entry)
    doc: dict[str, Any] = intrinsics(cameras.frames[0].camera_id) if shared and cameras.frames else {}
    doc.update({key: value for key, value in optional.items() if value})
    doc["frames"] = frames
    return doc


def colmap_model(cameras: CameraSet, points: Points | None, folder: Path) -> None:
    """``cameras`` (pinhole, OpenCV c2w) and ``points`` as a COLMAP model in ``folder``, written by pycolmap in
    COLMAP's binary and text formats: PINHOLE cameras, each image's world-to-camera pose, and the points with
    their colours (without tracks: the 2D observations are not kept)."""
    import pycolmap

    from nerfpipe.geometry.cameras import invert_pose

    model = pycolmap.Reconstruction()
    for camera_id, camera in sorted(cameras.cameras.items()):
        model.add_camera_with_trivial_rig(pycolmap.Camera(
            camera_id=camera_id, model="PINHOLE", width=camera.width, height=camera.height,
            params=[camera.fx, camera.fy, camera.cx, camera.cy]))
    for image_id, frame in enumerate(cameras.frames, start=1):
        w2c = invert_pose(np.asarray(frame.c2w))
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
        model.add_image_with_trivial_frame(pycolmap.Image(name=frame.name, camera_id=frame.camera_id,
                                                          image_id=image_id), pose)
    if points is not None:
        for xyz, rgb in zip(np.asarray(points.xyz, dtype=np.float64), np.asarray(points.rgb, dtype=np.uint8)):
            model.add_point3D(xyz, pycolmap.Track(), rgb)
    folder.mkdir(parents=True, exist_ok=True)
    model.write_binary(str(folder))
    model.write_text(str(folder))


def _camera_exports(views: CapturedViews, staging: Path, has_depth: bool) -> None:
    """transforms.json with images/, masks/ and sparse_pc.ply where there are any, and sparse/0/."""
    from nerfpipe.export.points import Cloud, write_ply

    frames = views.cameras.frames
    paths, masks = {}, {}
    for frame in frames:
        _copy(views.images[frame.name], staging / "images" / frame.name)
        paths[frame.name] = f"images/{frame.name}"
    # nerfstudio takes masks and depth maps for every frame or for none
    if views.masks is not None and all(f.name in views.masks for f in frames):
        for frame in frames:
            masks[frame.name] = f"masks/{Path(frame.name).stem}.png"
            _copy(views.masks[frame.name], staging / masks[frame.name])
    ply = None
    if views.points is not None and len(views.points.xyz):
        write_ply(staging / SPARSE_PLY, Cloud(views.points.xyz, views.points.rgb / 255.0))
        ply = SPARSE_PLY
    depth_paths, depth_scale = {}, None
    if has_depth and views.depth is not None:
        depth_scale = depth_in_frame(staging / "depth", views.depth)
        depth_paths = {v.name: f"depth/{v.stem}.depth.png" for v in views.depth.views}
        if not all(f.name in depth_paths for f in frames):
            depth_paths = {}
    heldout = set(views.heldout)
    held = [paths[f.name] for f in frames if f.name in heldout]  # nerfstudio evaluates on "val" or "test"
    doc = transforms_json(views.cameras, paths, ply_file_path=ply,
                          train_filenames=[paths[f.name] for f in frames if f.name not in heldout],
                          val_filenames=held, test_filenames=held, mask_path=masks, depth_file_path=depth_paths,
                          depth_unit_scale_factor=depth_scale if depth_paths else None)
    write_json_atomic(staging / "transforms.json", doc)
    colmap_model(views.cameras, views.points, staging / "sparse" / "0")


def collect(run_dir: Path, artifacts: dict[str, Path | None], views: CapturedViews | None,
            extra: tuple[Path, ...] = ()) -> Exported:
    """Write ``run_dir/exports`` anew from ``artifacts`` (name -> path, None where its stage made nothing), the
    camera exports of ``views`` (None before the cameras are known), and the ``extra`` files (optional outputs
    such as the watertight mesh) under their own names."""
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
    if views is not None and views.cameras.frames:
        _camera_exports(views, staging, "depth" in names)
        names += [*CAMERA_FILES, *(n for n in ("masks", SPARSE_PLY) if (staging / n).exists())]
    else:
        missing += CAMERA_FILES
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
