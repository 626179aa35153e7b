"""LLFF's poses_bounds.npy: a 3x5 pose and height, width, focal per image, and each image's near/far, in LLFF's
axes (down, right, backwards)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nerfpipe.artifacts import PHOTO_SUBFOLDER
from nerfpipe.geometry.cameras import Camera, CameraSet, Frame, PoseHints, pose_from_rt
from nerfpipe.pipeline.errors import InputError
from nerfpipe.poses.layout import CaptureLayout
from nerfpipe.poses.photos import (
    CameraTable,
    Photos,
    checked_position,
    checked_rotation,
    relative_names,
    to_ingested_size,
)

# LLFF columns [down, right, backwards] -> OpenCV [right, down, forward] = [c1, c0, -c2].
LLFF_TO_OPENCV = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


NPY_MAGIC = b"\x93NUMPY"  # the first bytes of every .npy file (NEP 1)


def import_llff(layout: CaptureLayout, photos: Photos) -> CameraSet:
    pose_file = layout.pose_files[0]
    with open(pose_file, "rb") as f:
        magic = f.read(len(NPY_MAGIC))
    if magic != NPY_MAGIC:
        # np.load would try to read it as a pickle and say so, hinting at allow_pickle: never for a pose file
        raise InputError(pose_file, "is not a NumPy .npy file (it does not start with the .npy signature)",
                         "regenerate it with LLFF's imgs2poses, or remove it to let SfM compute the poses")
    check_npy_header(pose_file)
    try:
        array = np.load(pose_file, allow_pickle=False)
    except (OSError, ValueError, EOFError) as err:
        problem = "holds Python objects, not numbers" if "pickle" in str(err) else f"is not a readable .npy array ({err})"
        raise InputError(pose_file, problem, "regenerate it with LLFF's imgs2poses") from None
    if array.dtype.kind not in "fiu":  # integers or floats: not complex numbers, strings or records
        raise InputError(pose_file, f"holds {array.dtype} values, not real numbers", "regenerate it with LLFF's imgs2poses")
    if array.ndim != 2 or array.shape[1] != 17:
        raise InputError(pose_file, f"has shape {array.shape} ({array.dtype}); poses_bounds.npy must be (N, 17): "
                         "a 3x5 [R | t | hwf] pose and near, far per image", "regenerate it with LLFF's imgs2poses")
    # rows follow COLMAP/LLFF name order: lexicographic, as sorted(os.listdir("images"))
    images = sorted((p for p in layout.photos if p.parent == layout.capture / PHOTO_SUBFOLDER), key=lambda p: p.name)
    if len(array) != len(images):
        raise InputError(pose_file, f"has {len(array)} rows but {PHOTO_SUBFOLDER}/ holds {len(images)} photos",
                         "rows follow the sorted image names: keep exactly the photos the poses were computed for")

    table = CameraTable()
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
        frames.append(Frame(record.name, camera_id, pose_from_rt(R, checked_position(pose[:, 3], pose_file, where))))
        bounds[record.name] = [near, far]
    return CameraSet(table.cameras, frames, None, "llff", sorted(unregistered),
                     PoseHints(relative_names(layout, layout.pose_files), llff_bounds=bounds))


def check_npy_header(pose_file: Path) -> None:
    """Raise ``InputError`` for a ``.npy`` whose header promises another shape than (N, 17) or more data than the
    file holds: ``np.load`` would allocate what the header says before reading (10^9 rows: 127 GiB)."""
    from numpy.lib import format as npy

    try:
        with open(pose_file, "rb") as f:
            version = npy.read_magic(f)
            read_header = {(1, 0): npy.read_array_header_1_0, (2, 0): npy.read_array_header_2_0}.get(version)
            if read_header is None:
                raise ValueError(f"format version {version} is not one of a plain number array")
            shape, _, dtype = read_header(f)
            offset = f.tell()
    except (OSError, ValueError, SyntaxError) as err:
        raise InputError(pose_file, f"has a damaged .npy header ({err})", "regenerate it with LLFF's imgs2poses") from None
    if len(shape) != 2 or shape[1] != 17:
        raise InputError(pose_file, f"has shape {shape}; poses_bounds.npy must be (N, 17): a 3x5 [R | t | hwf] pose "
                         "and near, far per image", "regenerate it with LLFF's imgs2poses")
    needed = shape[0] * shape[1] * dtype.itemsize
    if offset + needed > pose_file.stat().st_size:
        raise InputError(pose_file, f"claims {shape[0]} rows, more than its {pose_file.stat().st_size} bytes hold",
                         "copy it again, or regenerate it with LLFF's imgs2poses")
