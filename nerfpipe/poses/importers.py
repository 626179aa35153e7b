"""Pose-file importers: a capture's own poses as a ``CameraSet``, in nerfpipe's conventions.

``import_poses(layout, records)`` reads the pose files ``detect_layout`` found and returns cameras,
frames (OpenCV ``c2w``) and, for COLMAP models, sparse points. Formats:

- ``colmap``: a COLMAP sparse model (``.bin`` or ``.txt``), read with pycolmap. Camera models and
  parameters are kept; ``c2w = inverse(cam_from_world)``.
- ``transforms``: NeRF / instant-ngp / nerfstudio ``transforms*.json``. ``transform_matrix`` is an
  OpenGL c2w, so ``c2w = transform_matrix @ OPENGL_TO_OPENCV``; ``f = 0.5 w / tan(0.5 camera_angle_x)``.
  instant-ngp's ``aabb_scale`` (how many times the cameras' unit cube the scene extends) goes to
  ``hints.aabb_scale``, a hint for the later stages.
- ``llff``: ``poses_bounds.npy`` (N, 17): a 3x5 ``[R | t | hwf]`` c2w whose columns are LLFF's
  [down, right, backwards]; OpenCV's [right, down, forward] is ``[c1, c0, -c2]``. Rows follow the sorted
  image names. Near/far go to ``hints.llff_bounds``.
- ``middlebury``: ``*_par.txt``, ``name K(9) R(9) t(3)`` per line with ``P = K [R | t]`` (world to camera,
  OpenCV), so ``c2w = [R^T | -R^T t]``.

Intrinsics in pose files describe the original photos; they are scaled to the ingested size of each
photo (``records`` are the ``images.json`` records of ingest). Frames are named by their ingest name.
Photos a pose file names but ingest skipped, and (COLMAP) photos the model did not register, are listed
in ``CameraSet.unregistered``. Anything wrong in a pose file raises ``InputError`` naming the file and
the line, row or frame.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from nerfpipe.artifacts import PHOTO_SUBFOLDER, PhotoRecord
from nerfpipe.geometry.cameras import (
    CAMERA_MODELS,
    OPENGL_TO_OPENCV,
    Camera,
    CameraSet,
    Frame,
    Points,
    PoseHints,
    invert_pose,
    pose_from_rt,
)
from nerfpipe.pipeline.errors import InputError
from nerfpipe.poses.colmap_files import check_binary_model, check_text_images
from nerfpipe.poses.layout import IMAGE_SUFFIXES, CaptureLayout, _read_json, resolve_inside
from nerfpipe.poses.llff import import_llff
from nerfpipe.poses.middlebury import import_middlebury
from nerfpipe.poses.photos import (
    CameraTable,
    Photos,
    checked_position,
    checked_rotation,
    relative_names,
    to_ingested_size,
)


def import_poses(layout: CaptureLayout, records: list[PhotoRecord]) -> CameraSet:
    """The poses of ``layout.pose_files`` for the ingested photos ``records`` (images.json ``images``)."""
    if layout.kind == "folder":
        raise ValueError(f"{layout.capture} has no pose files to import; its poses come from SfM")
    importer = IMPORTERS.get(layout.kind)
    if importer is None:
        raise ValueError(f"no pose importer for layout {layout.kind!r}")
    return importer(layout, Photos(layout, records))


# ---------------------------------------------------------------------------------------------------
# Shared pieces


# ---------------------------------------------------------------------------------------------------
# COLMAP sparse model


def import_colmap(layout: CaptureLayout, photos: Photos) -> CameraSet:
    model_dir = layout.pose_files[0].parent
    images_file = next((p for p in layout.pose_files if p.stem == "images"), layout.pose_files[0])
    rec = read_colmap_model(model_dir)
    if not rec.images:
        raise InputError(images_file, "holds no images", "re-export the model from COLMAP, or remove it to let SfM "
                         "compute the poses")

    table = CameraTable()
    frames: list[Frame] = []
    frame_of_image: dict[int, int] = {}
    unregistered: set[str] = set()
    seen: set[str] = set()
    for image in sorted(rec.images.values(), key=lambda im: im.name):
        path = resolve_inside(layout.capture, f"{PHOTO_SUBFOLDER}/{image.name}", images_file)
        seen.add(photos.relpath(path))
        record = photos.record(path)
        if record is None or not image.has_pose:
            unregistered.add(photos.name(path))
            continue
        where = f"image {image.name!r}"
        camera = rec.cameras[image.camera_id]
        model = camera.model.name
        if model not in CAMERA_MODELS:
            raise InputError(images_file, f"{where} uses the COLMAP camera model {model}, which nerfpipe does not support",
                             f"use one of {', '.join(CAMERA_MODELS)} (or undistort the images first)")
        cam = Camera(model, int(camera.width), int(camera.height), tuple(float(p) for p in camera.params))
        if not (cam.fx > 0 and cam.fy > 0 and math.isfinite(cam.fx * cam.fy) and cam.width > 0 and cam.height > 0):
            raise InputError(images_file.with_name(f"cameras{images_file.suffix}"),
                             f"camera {image.camera_id} has focal length {cam.fx:g} x {cam.fy:g} px at "
                             f"{cam.width}x{cam.height}; a focal length is a positive number of pixels",
                             "fix the camera, or remove the model to let SfM compute the poses")
        w2c = np.vstack([np.asarray(image.cam_from_world().matrix(), dtype=np.float64), [0.0, 0.0, 0.0, 1.0]])
        if not np.all(np.isfinite(w2c)):
            raise InputError(images_file, f"{where}: the pose holds a non-finite value", "re-run or re-export the model")
        R = checked_rotation(w2c[:3, :3], images_file, where)
        camera_id = table.add(to_ingested_size(cam, record, images_file, where), key=image.camera_id)
        frame_of_image[image.image_id] = len(frames)
        frames.append(Frame(record.name, camera_id, invert_pose(pose_from_rt(R, checked_position(w2c[:3, 3],
                                                                                                     images_file, where)))))
    unregistered.update(photos.name(p) for p in layout.photos if photos.relpath(p) not in seen)

    return CameraSet(table.cameras, frames, colmap_points(rec, frame_of_image, len(frames)), "colmap_model",
                     sorted(unregistered), PoseHints(relative_names(layout, layout.pose_files)))


def read_colmap_model(model_dir: Path) -> Any:
    """``pycolmap.Reconstruction`` of ``model_dir``; a model without points3D reads as one with no points."""
    import pycolmap

    def read(folder: Path) -> Any:
        try:
            return pycolmap.Reconstruction(str(folder))
        except Exception as err:  # pycolmap raises ValueError, IndexError, RuntimeError... on bad files
            raise InputError(model_dir, f"could not be read as a COLMAP model ({err})",
                             "re-export the model from COLMAP, or remove it to let SfM compute the poses") from None

    ext = ".bin" if (model_dir / "images.bin").is_file() else ".txt"
    if ext == ".bin":
        check_binary_model(model_dir)  # counts pycolmap would trust, checked against the files' sizes
    elif (model_dir / "images.txt").is_file():
        check_text_images(model_dir / "images.txt")  # zero quaternions, which pycolmap reads as the identity
    if (model_dir / f"points3D{ext}").is_file():
        return read(model_dir)
    with tempfile.TemporaryDirectory() as tmp:  # cameras + images with known poses and no points yet
        for stem in ("cameras", "images", "rigs", "frames"):
            if (model_dir / f"{stem}{ext}").is_file():
                (Path(tmp) / f"{stem}{ext}").write_bytes((model_dir / f"{stem}{ext}").read_bytes())
        (Path(tmp) / f"points3D{ext}").write_bytes(bytes(8) if ext == ".bin" else b"")
        return read(Path(tmp))


def colmap_points(rec: Any, frame_of_image: dict[int, int], n_frames: int) -> Points | None:
    """The model's points, and per frame the indices of the points it observes."""
    ids = sorted(rec.points3D)
    if not ids:
        return None
    points = [rec.points3D[i] for i in ids]
    xyz = np.array([p.xyz for p in points], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in points], dtype=np.uint8).reshape(-1, 3)
    error = np.array([p.error for p in points], dtype=np.float64)
    observed: list[list[int]] = [[] for _ in range(n_frames)]
    for index, point in enumerate(points):
        for element in point.track.elements:
            frame = frame_of_image.get(element.image_id)
            if frame is not None:
                observed[frame].append(index)
    visible = [np.unique(np.array(v, dtype=np.int64)) for v in observed]
    return Points(xyz, rgb, error, visible)


# ---------------------------------------------------------------------------------------------------
# transforms.json (NeRF, instant-ngp, nerfstudio)

INTRINSIC_KEYS = ("camera_angle_x", "camera_angle_y", "fl_x", "fl_y", "cx", "cy", "w", "h",
                  "k1", "k2", "k3", "k4", "p1", "p2", "camera_model", "is_fisheye")


def import_transforms(layout: CaptureLayout, photos: Photos) -> CameraSet:
    table = CameraTable()
    frames: list[Frame] = []
    unregistered: list[str] = []
    seen: dict[str, np.ndarray] = {}  # each photo's transform_matrix, as first given
    hints = PoseHints(relative_names(layout, layout.pose_files))
    for pose_file in layout.pose_files:
        doc = _read_json(pose_file)
        if "aabb_scale" in doc:  # several files (splits) with different scales: the largest box covers all
            hints.aabb_scale = max(aabb_scale(doc["aabb_scale"], pose_file), hints.aabb_scale or 0.0)
        shared = {k: doc[k] for k in INTRINSIC_KEYS if k in doc}
        for i, entry in enumerate(doc["frames"]):
            path = resolve_inside(layout.capture, entry["file_path"], pose_file, IMAGE_SUFFIXES)
            relpath = photos.relpath(path)
            where = f"frame {i} ({entry['file_path']})"
            c2w_gl = transform_matrix(entry, pose_file, where)
            if relpath in seen:  # the same photo twice: the first wins, as in layout.splits, if the poses agree
                if not np.allclose(seen[relpath], c2w_gl, atol=1e-6):
                    raise InputError(pose_file, f"{where} repeats {relpath} with another pose than before",
                                     "keep one frame per photo")
                continue
            seen[relpath] = c2w_gl
            record = photos.record(path)
            if record is None:
                unregistered.append(photos.name(path))
                continue
            values = {**shared, **{k: entry[k] for k in INTRINSIC_KEYS if k in entry}}
            camera = to_ingested_size(transforms_camera(values, record, pose_file, where), record, pose_file, where)
            c2w = c2w_gl @ OPENGL_TO_OPENCV
            frames.append(Frame(record.name, table.add(camera), c2w, layout.splits.get(relpath)))
    return CameraSet(table.cameras, frames, None, "transforms_json", sorted(unregistered), hints)


def aabb_scale(value: Any, pose_file: Path) -> float:
    """instant-ngp's ``aabb_scale``, checked: a positive number (instant-ngp uses powers of two, 1 to 128).

    instant-ngp fits the cameras into the unit cube and marches rays through a cube ``aabb_scale`` times
    as large around the same centre: 1 for an object inside the camera ring (NeRF's synthetic scenes),
    up to 128 for a background far beyond the cameras.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise InputError(pose_file, f"aabb_scale is {value!r}, not a positive number",
                         "instant-ngp's aabb_scale is a power of two from 1 to 128; fix or remove it")
    return float(value)


def transform_matrix(entry: dict[str, Any], pose_file: Path, where: str) -> np.ndarray:
    """The frame's 4x4 c2w (OpenGL), checked; a 3x4 matrix gets its [0 0 0 1] row."""
    if "transform_matrix" not in entry:
        raise InputError(pose_file, f"{where} has no transform_matrix", "every frame needs its 4x4 camera-to-world matrix")
    try:
        matrix = np.array(entry["transform_matrix"], dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(pose_file, f"{where}: transform_matrix is not a matrix of numbers",
                         "every frame needs its 4x4 camera-to-world matrix") from None
    if matrix.shape not in ((4, 4), (3, 4)):
        shape = "x".join(map(str, matrix.shape)) or "a single number"
        raise InputError(pose_file, f"{where}: transform_matrix is {shape}, not 4x4",
                         "every frame needs its 4x4 camera-to-world matrix")
    if not np.all(np.isfinite(matrix)):
        raise InputError(pose_file, f"{where}: transform_matrix holds a non-finite value", "fix or regenerate the pose file")
    if matrix.shape == (4, 4) and np.abs(matrix[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-6:
        raise InputError(pose_file, f"{where}: the last row of transform_matrix is {matrix[3].tolist()}, not [0, 0, 0, 1]",
                         "a camera-to-world matrix is a rigid transform; fix or regenerate the pose file")
    return pose_from_rt(checked_rotation(matrix[:3, :3], pose_file, where), checked_position(matrix[:3, 3], pose_file,
                                                                                            where))


def transforms_camera(values: dict[str, Any], record: PhotoRecord[str, Any], pose_file: Path, where: str) -> Camera:
    """The camera of a frame at the size the pose file states (or, without w/h, the photo's source size)."""

    def number(key: str, default: float | None = None, positive: bool = False) -> float | None:
        if key not in values:
            return default
        value = values[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise InputError(pose_file, f"{where}: {key} is {value!r}, not a finite number", "fix or regenerate the pose file")
        if positive and value <= 0:
            raise InputError(pose_file, f"{where}: {key} is {value!r}, it must be positive", "fix or regenerate the pose file")
        return float(value)

    width = round(number("w", record.source_width, positive=True))
    height = round(number("h", record.source_height, positive=True))

    def focal_from_fov(key: str, size: int) -> float | None:
        angle = number(key, positive=True)
        if angle is not None and angle >= math.pi:
            raise InputError(pose_file, f"{where}: {key} is {angle}, a field of view must be below pi radians",
                             "camera_angle_x/y are in radians")
        return None if angle is None else 0.5 * size / math.tan(0.5 * angle)

    fx = number("fl_x", positive=True) or focal_from_fov("camera_angle_x", width)
    fy = number("fl_y", positive=True) or focal_from_fov("camera_angle_y", height)
    if fx is None and fy is None:
        raise InputError(pose_file, f"{where} has no focal length (fl_x or camera_angle_x)",
                         "add fl_x (pixels) or camera_angle_x (radians) to the file or the frame")
    fx = fy if fx is None else fx
    fy = fx if fy is None else fy
    cx, cy = number("cx", width / 2), number("cy", height / 2)
    k1, k2, k3, k4, p1, p2 = (number(k, 0.0) for k in ("k1", "k2", "k3", "k4", "p1", "p2"))

    model = values.get("camera_model", "OPENCV")
    if not isinstance(model, str) or model.upper() not in ("OPENCV", "OPENCV_FISHEYE", "PINHOLE", "SIMPLE_PINHOLE", "FULL_OPENCV"):
        raise InputError(pose_file, f"{where}: camera_model {model!r} is not supported",
                         "use PINHOLE, SIMPLE_PINHOLE, OPENCV, FULL_OPENCV or OPENCV_FISHEYE")
    if model.upper() == "OPENCV_FISHEYE" or values.get("is_fisheye") is True:
        return Camera("OPENCV_FISHEYE", width, height, (fx, fy, cx, cy, k1, k2, k3, k4))
    if k3 or k4:
        return Camera("FULL_OPENCV", width, height, (fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, 0.0, 0.0))
    if k1 or k2 or p1 or p2:
        return Camera("OPENCV", width, height, (fx, fy, cx, cy, k1, k2, p1, p2))
    return Camera.pinhole(fx, fy, cx, cy, width, height)


# ---------------------------------------------------------------------------------------------------
# LLFF poses_bounds.npy


# ---------------------------------------------------------------------------------------------------
# Middlebury *_par.txt


IMPORTERS: dict[str, Callable[[CaptureLayout, Photos], CameraSet]] = {
    "colmap": import_colmap,
    "transforms": import_transforms,
    "llff": import_llff,
    "middlebury": import_middlebury,
}
