"""Pose-file importers: a capture's own poses as a ``CameraSet``, in nerfpipe's conventions.

``import_poses(layout, records)`` reads the pose files ``detect_layout`` found and returns cameras,
frames (OpenCV ``c2w``) and, for COLMAP models, sparse points. Formats:

- ``colmap``: a COLMAP sparse model (``.bin`` or ``.txt``), read with pycolmap. Camera models and
  parameters are kept; ``c2w = inverse(cam_from_world)``.
- ``transforms``: NeRF / instant-ngp / nerfstudio ``transforms*.json``. ``transform_matrix`` is an
  OpenGL c2w, so ``c2w = transform_matrix @ OPENGL_TO_OPENCV``; ``f = 0.5 w / tan(0.5 camera_angle_x)``.
  instant-ngp's ``aabb_scale`` (how many times the cameras' unit cube the scene extends) goes to
  ``extra["aabb_scale"]``, a hint for the later stages.
- ``llff``: ``poses_bounds.npy`` (N, 17): a 3x5 ``[R | t | hwf]`` c2w whose columns are LLFF's
  [down, right, backwards]; OpenCV's [right, down, forward] is ``[c1, c0, -c2]``. Rows follow the sorted
  image names. Near/far go to ``extra["llff_bounds"]``.
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
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from nerfpipe.artifacts import PHOTO_SUBFOLDER, output_names
from nerfpipe.geometry.cameras import (
    CAMERA_MODELS,
    OPENGL_TO_OPENCV,
    Camera,
    CameraSet,
    Frame,
    Points,
    invert_pose,
    pose_from_rt,
)
from nerfpipe.pipeline.errors import InputError
from nerfpipe.poses.layout import IMAGE_SUFFIXES, CaptureLayout, _read_json, resolve_inside

ROTATION_TOLERANCE = 1e-3  # max |R^T R - I| and |det R - 1| before a matrix is refused as a rotation
ASPECT_TOLERANCE = 0.01  # relative aspect-ratio mismatch between a pose file's camera and the photo

# LLFF columns [down, right, backwards] -> OpenCV [right, down, forward] = [c1, c0, -c2].
LLFF_TO_OPENCV = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def import_poses(layout: CaptureLayout, records: list[dict[str, Any]]) -> CameraSet:
    """The poses of ``layout.pose_files`` for the ingested photos ``records`` (images.json ``images``)."""
    if layout.kind == "folder":
        raise ValueError(f"{layout.capture} has no pose files to import; its poses come from SfM")
    importer = IMPORTERS.get(layout.kind)
    if importer is None:
        raise ValueError(f"no pose importer for layout {layout.kind!r}")
    return importer(layout, _Photos(layout, records))


# ---------------------------------------------------------------------------------------------------
# Shared pieces


class _Photos:
    """Maps the photos pose files name to their images.json records and ingest names."""

    def __init__(self, layout: CaptureLayout, records: list[dict[str, Any]]) -> None:
        self.capture = layout.capture
        self._by_source = {r["source"]: r for r in records}
        self._by_resolved = {(self.capture / r["source"]).resolve(): r for r in records}
        self._names = output_names([self.relpath(p) for p in layout.photos])

    def relpath(self, path: Path) -> str:
        return path.relative_to(self.capture).as_posix()

    def record(self, path: Path) -> dict[str, Any] | None:
        record = self._by_source.get(self.relpath(path))
        return record if record is not None else self._by_resolved.get(path.resolve())

    def name(self, path: Path) -> str:
        record = self.record(path)
        if record is not None:
            return record["name"]
        return self._names.get(self.relpath(path), self.relpath(path))


class _CameraTable:
    """Camera ids, one per distinct (key, camera); ``key`` keeps cameras a pose file separates apart."""

    def __init__(self) -> None:
        self.cameras: dict[int, Camera] = {}
        self._ids: dict[tuple[Any, Camera], int] = {}

    def add(self, camera: Camera, key: Any = None) -> int:
        if (key, camera) not in self._ids:
            self._ids[(key, camera)] = len(self.cameras) + 1
            self.cameras[len(self.cameras) + 1] = camera
        return self._ids[(key, camera)]


def to_ingested_size(camera: Camera, record: dict[str, Any], pose_file: Path, where: str) -> Camera:
    """``camera`` (for the original photo) scaled to the photo's ingested size ``record["width"/"height"]``.

    A camera whose aspect ratio is not the photo's (after EXIF orientation) describes other images.
    """
    src_w, src_h = record["source_width"], record["source_height"]
    if abs(src_w * camera.height - src_h * camera.width) > ASPECT_TOLERANCE * src_h * camera.width:
        raise InputError(pose_file, f"{where}: the camera is {camera.width}x{camera.height} but the photo "
                         f"{record['source']} is {src_w}x{src_h}",
                         "the pose file must describe these photos, in the same orientation and aspect ratio")
    width, height = record["width"], record["height"]
    return replace(camera.scaled(width / camera.width, height / camera.height), width=width, height=height)


def checked_rotation(R: np.ndarray, pose_file: Path, where: str) -> np.ndarray:
    """The nearest exact rotation to ``R`` (3, 3); ``InputError`` unless R is one within ROTATION_TOLERANCE."""
    if not np.all(np.isfinite(R)):
        raise InputError(pose_file, f"{where}: the pose holds a non-finite value", "fix or regenerate the pose file")
    det = float(np.linalg.det(R))
    error = float(np.abs(R.T @ R - np.eye(3)).max())
    if abs(det - 1.0) > ROTATION_TOLERANCE or error > ROTATION_TOLERANCE:
        raise InputError(pose_file, f"{where}: the rotation is not a rotation (det {det:.6g}, |R^T R - I| = {error:.3g})",
                         "the 3x3 part of a pose must be orthonormal with determinant +1; fix or regenerate the pose file")
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def parse_numbers(tokens: list[str], pose_file: Path, line_no: int) -> np.ndarray:
    values = []
    for token in tokens:
        try:
            value = float(token)
        except ValueError:
            raise InputError(pose_file, f"malformed number {token!r} on line {line_no}",
                             "fix the line or regenerate the pose file") from None
        if not math.isfinite(value):
            raise InputError(pose_file, f"non-finite number {token!r} on line {line_no}",
                             "fix the line or regenerate the pose file")
        values.append(value)
    return np.array(values)


def _rel(layout: CaptureLayout, paths: list[Path]) -> list[str]:
    return [p.relative_to(layout.capture).as_posix() if p.is_relative_to(layout.capture) else str(p) for p in paths]


# ---------------------------------------------------------------------------------------------------
# COLMAP sparse model


def import_colmap(layout: CaptureLayout, photos: _Photos) -> CameraSet:
    model_dir = layout.pose_files[0].parent
    images_file = next((p for p in layout.pose_files if p.stem == "images"), layout.pose_files[0])
    rec = read_colmap_model(model_dir)

    table = _CameraTable()
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
        w2c = np.vstack([np.asarray(image.cam_from_world().matrix(), dtype=np.float64), [0.0, 0.0, 0.0, 1.0]])
        if not np.all(np.isfinite(w2c)):
            raise InputError(images_file, f"{where}: the pose holds a non-finite value", "re-run or re-export the model")
        R = checked_rotation(w2c[:3, :3], images_file, where)
        camera_id = table.add(to_ingested_size(cam, record, images_file, where), key=image.camera_id)
        frame_of_image[image.image_id] = len(frames)
        frames.append(Frame(record["name"], camera_id, invert_pose(pose_from_rt(R, w2c[:3, 3]))))
    unregistered.update(photos.name(p) for p in layout.photos if photos.relpath(p) not in seen)

    return CameraSet(table.cameras, frames, colmap_points(rec, frame_of_image, len(frames)), "colmap_model",
                     sorted(unregistered), {"pose_files": _rel(layout, layout.pose_files)})


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


def import_transforms(layout: CaptureLayout, photos: _Photos) -> CameraSet:
    table = _CameraTable()
    frames: list[Frame] = []
    unregistered: list[str] = []
    seen: set[str] = set()
    extra: dict[str, Any] = {"pose_files": _rel(layout, layout.pose_files)}
    for pose_file in layout.pose_files:
        doc = _read_json(pose_file)
        if "aabb_scale" in doc:  # several files (splits) with different scales: the largest box covers all
            extra["aabb_scale"] = max(aabb_scale(doc["aabb_scale"], pose_file), extra.get("aabb_scale", 0.0))
        shared = {k: doc[k] for k in INTRINSIC_KEYS if k in doc}
        for i, entry in enumerate(doc["frames"]):
            path = resolve_inside(layout.capture, entry["file_path"], pose_file, IMAGE_SUFFIXES)
            relpath = photos.relpath(path)
            if relpath in seen:  # the same photo in two files: the first wins, as in layout.splits
                continue
            seen.add(relpath)
            where = f"frame {i} ({entry['file_path']})"
            c2w_gl = transform_matrix(entry, pose_file, where)
            record = photos.record(path)
            if record is None:
                unregistered.append(photos.name(path))
                continue
            values = {**shared, **{k: entry[k] for k in INTRINSIC_KEYS if k in entry}}
            camera = to_ingested_size(transforms_camera(values, record, pose_file, where), record, pose_file, where)
            c2w = c2w_gl @ OPENGL_TO_OPENCV
            frames.append(Frame(record["name"], table.add(camera), c2w, layout.splits.get(relpath)))
    return CameraSet(table.cameras, frames, None, "transforms_json", sorted(unregistered), extra)


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
    return pose_from_rt(checked_rotation(matrix[:3, :3], pose_file, where), matrix[:3, 3])


def transforms_camera(values: dict[str, Any], record: dict[str, Any], pose_file: Path, where: str) -> Camera:
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

    width = round(number("w", record["source_width"], positive=True))
    height = round(number("h", record["source_height"], positive=True))

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


NPY_MAGIC = b"\x93NUMPY"  # the first bytes of every .npy file (NEP 1)


def import_llff(layout: CaptureLayout, photos: _Photos) -> CameraSet:
    pose_file = layout.pose_files[0]
    with open(pose_file, "rb") as f:
        magic = f.read(len(NPY_MAGIC))
    if magic != NPY_MAGIC:
        # np.load would try to read it as a pickle and say so, hinting at allow_pickle: never for a pose file
        raise InputError(pose_file, "is not a NumPy .npy file (it does not start with the .npy signature)",
                         "regenerate it with LLFF's imgs2poses, or remove it to let SfM compute the poses")
    try:
        array = np.load(pose_file, allow_pickle=False)
    except (OSError, ValueError, EOFError) as err:
        problem = "holds Python objects, not numbers" if "pickle" in str(err) else f"is not a readable .npy array ({err})"
        raise InputError(pose_file, problem, "regenerate it with LLFF's imgs2poses") from None
    if array.ndim != 2 or array.shape[1] != 17 or not np.issubdtype(array.dtype, np.number):
        raise InputError(pose_file, f"has shape {array.shape} ({array.dtype}); poses_bounds.npy must be (N, 17): "
                         "a 3x5 [R | t | hwf] pose and near, far per image", "regenerate it with LLFF's imgs2poses")
    # rows follow COLMAP/LLFF name order: lexicographic, as sorted(os.listdir("images"))
    images = sorted((p for p in layout.photos if p.parent == layout.capture / PHOTO_SUBFOLDER), key=lambda p: p.name)
    if len(array) != len(images):
        raise InputError(pose_file, f"has {len(array)} rows but {PHOTO_SUBFOLDER}/ holds {len(images)} photos",
                         "rows follow the sorted image names: keep exactly the photos the poses were computed for")

    table = _CameraTable()
    frames: list[Frame] = []
    unregistered: list[str] = []
    bounds: dict[str, list[float]] = {}
    for row, (values, path) in enumerate(zip(array.astype(np.float64), images)):
        where = f"row {row} ({path.name})"
        if not np.all(np.isfinite(values)):
            raise InputError(pose_file, f"{where} holds a non-finite value", "regenerate it with LLFF's imgs2poses")
        pose = values[:15].reshape(3, 5)
        R = checked_rotation(pose[:, :3] @ LLFF_TO_OPENCV, pose_file, where)
        (height, width, focal), (near, far) = map(float, pose[:, 4]), map(float, values[15:])
        if min(height, width, focal) <= 0 or not 0 < near <= far:
            raise InputError(pose_file, f"{where}: needs positive h, w, focal and 0 < near <= far, "
                             f"got hwf ({height:g}, {width:g}, {focal:g}) and bounds ({near:g}, {far:g})",
                             "regenerate it with LLFF's imgs2poses")
        record = photos.record(path)
        if record is None:
            unregistered.append(photos.name(path))
            continue
        camera = Camera.pinhole(focal, focal, width / 2, height / 2, round(width), round(height))
        camera_id = table.add(to_ingested_size(camera, record, pose_file, where))
        frames.append(Frame(record["name"], camera_id, pose_from_rt(R, pose[:, 3])))
        bounds[record["name"]] = [near, far]
    return CameraSet(table.cameras, frames, None, "llff", sorted(unregistered),
                     {"pose_files": _rel(layout, layout.pose_files), "llff_bounds": bounds})


# ---------------------------------------------------------------------------------------------------
# Middlebury *_par.txt

PAR_FIELDS = 22  # name, K (9), R (9), t (3)


def import_middlebury(layout: CaptureLayout, photos: _Photos) -> CameraSet:
    table = _CameraTable()
    frames: list[Frame] = []
    unregistered: list[str] = []
    for pose_file in layout.pose_files:
        for line_no, name, K, R, t in read_par_file(pose_file):
            path = resolve_inside(layout.capture, name, pose_file)
            record = photos.record(path)
            if record is None:
                unregistered.append(photos.name(path))
                continue
            fx, fy, cx, cy = (float(v) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
            camera = Camera.pinhole(fx, fy, cx, cy, record["source_width"], record["source_height"])
            camera_id = table.add(to_ingested_size(camera, record, pose_file, f"line {line_no}"))
            frames.append(Frame(record["name"], camera_id, invert_pose(pose_from_rt(R, t))))
    return CameraSet(table.cameras, frames, None, "middlebury", sorted(unregistered),
                     {"pose_files": _rel(layout, layout.pose_files)})


def read_par_file(pose_file: Path) -> list[tuple[int, str, np.ndarray, np.ndarray, np.ndarray]]:
    """(line number, image name, K, R, t) per image of a Middlebury ``*_par.txt``, with ``x_cam = R X + t``."""
    lines = pose_file.read_text(encoding="utf-8", errors="replace").splitlines()
    advice = "line 1 is the image count, then one line per image: name k11..k33 r11..r33 t1 t2 t3"
    if not lines or not lines[0].strip():
        raise InputError(pose_file, "is empty or does not start with the image count", advice)
    try:
        count = int(lines[0].split()[0])
    except ValueError:
        raise InputError(pose_file, f"line 1 should be the image count, not {lines[0].strip()!r}", advice) from None
    entries = [(i + 1, line.split()) for i, line in enumerate(lines) if i > 0 and line.strip()]
    if count != len(entries):
        raise InputError(pose_file, f"says {count} images on line 1 but lists {len(entries)}", advice)
    out = []
    for line_no, fields in entries:
        if len(fields) != PAR_FIELDS:
            raise InputError(pose_file, f"line {line_no} has {len(fields)} fields, not {PAR_FIELDS}", advice)
        numbers = parse_numbers(fields[1:], pose_file, line_no)
        K, R, t = numbers[:9].reshape(3, 3), numbers[9:18].reshape(3, 3), numbers[18:]
        if np.abs(K[2] - [0.0, 0.0, 1.0]).max() > 1e-9 or abs(K[1, 0]) > 1e-9 or abs(K[0, 1]) > 1e-6 * abs(K[0, 0]):
            raise InputError(pose_file, f"line {line_no}: K is not a pinhole calibration matrix [fx 0 cx; 0 fy cy; 0 0 1]",
                             "nerfpipe cannot represent skew or an unnormalised K")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError(pose_file, f"line {line_no}: the focal lengths must be positive", advice)
        out.append((line_no, fields[0], K, checked_rotation(R, pose_file, f"line {line_no}"), t))
    return out


IMPORTERS: dict[str, Callable[[CaptureLayout, _Photos], CameraSet]] = {
    "colmap": import_colmap,
    "transforms": import_transforms,
    "llff": import_llff,
    "middlebury": import_middlebury,
}
