"""Middlebury's multi-view stereo par files: per image its name, K, R and t (world to camera)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nerfpipe.geometry.cameras import Camera, CameraSet, Frame, PoseHints, invert_pose, pose_from_rt
from nerfpipe.pipeline.errors import InputError
from nerfpipe.poses.layout import CaptureLayout, resolve_inside
from nerfpipe.poses.photos import (
    CameraTable,
    Photos,
    checked_position,
    checked_rotation,
    parse_numbers,
    relative_names,
    to_ingested_size,
)

PAR_FIELDS = 22  # name, K (9), R (9), t (3)


def import_middlebury(layout: CaptureLayout, photos: Photos) -> CameraSet:
    table = CameraTable()
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
            camera = Camera.pinhole(fx, fy, cx, cy, record.source_width, record.source_height)
            camera_id = table.add(to_ingested_size(camera, record, pose_file, f"line {line_no}"))
            t = checked_position(t, pose_file, f"line {line_no}")
            frames.append(Frame(record.name, camera_id, invert_pose(pose_from_rt(R, t))))
    return CameraSet(table.cameras, frames, None, "middlebury", sorted(unregistered),
                     PoseHints(relative_names(layout, layout.pose_files)))


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
