"""What every pose importer shares: the ingested photos by name, a table of distinct cameras, and checks of
what a pose file says (a rotation that is one, numbers that parse, a camera the size of its photo) that name
the file and line."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from nerfpipe.artifacts import PhotoRecord, output_names
from nerfpipe.geometry.cameras import Camera
from nerfpipe.pipeline.errors import InputError
from nerfpipe.poses.layout import CaptureLayout

ROTATION_TOLERANCE = 1e-3  # max |R^T R - I| and |det R - 1| before a matrix is refused as a rotation


ASPECT_TOLERANCE = 0.01  # relative aspect-ratio mismatch between a pose file's camera and the photo


class Photos:
    """Maps the photos pose files name to their images.json records and ingest names."""

    def __init__(self, layout: CaptureLayout, records: list[PhotoRecord]) -> None:
        self.capture = layout.capture
        self._by_source = {r.source: r for r in records}
        self._by_resolved = {(self.capture / r.source).resolve(): r for r in records}
        self._names = output_names([self.relpath(p) for p in layout.photos])

    def relpath(self, path: Path) -> str:
        return path.relative_to(self.capture).as_posix()

    def record(self, path: Path) -> PhotoRecord | None:
        record = self._by_source.get(self.relpath(path))
        return record if record is not None else self._by_resolved.get(path.resolve())

    def name(self, path: Path) -> str:
        record = self.record(path)
        if record is not None:
            return record.name
        return self._names.get(self.relpath(path), self.relpath(path))


class CameraTable:
    """Camera ids, one per distinct (key, camera); ``key`` keeps cameras a pose file separates apart."""

    def __init__(self) -> None:
        self.cameras: dict[int, Camera] = {}
        self._ids: dict[tuple[Any, Camera], int] = {}

    def add(self, camera: Camera, key: Any = None) -> int:
        if (key, camera) not in self._ids:
            self._ids[(key, camera)] = len(self.cameras) + 1
            self.cameras[len(self.cameras) + 1] = camera
        return self._ids[(key, camera)]


def to_ingested_size(camera: Camera, record: PhotoRecord[str, Any], pose_file: Path, where: str) -> Camera:
    """``camera`` (for the original photo) scaled to the photo's ingested size ``record["width"/"height"]``.

    A camera whose aspect ratio is not the photo's (after EXIF orientation) describes other images.
    """
    src_w, src_h = record.source_width, record.source_height
    if abs(src_w * camera.height - src_h * camera.width) > ASPECT_TOLERANCE * src_h * camera.width:
        raise InputError(pose_file, f"{where}: the camera is {camera.width}x{camera.height} but the photo "
                         f"{record.source} is {src_w}x{src_h}",
                         "the pose file must describe these photos, in the same orientation and aspect ratio")
    width, height = record.width, record.height
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


MAX_COORDINATE = 1e9  # a camera farther out than this from the origin, in any unit, is a broken pose file


def checked_position(t: np.ndarray, pose_file: Path, where: str) -> np.ndarray:
    """``t`` (3,), a pose's translation, if finite and within ``MAX_COORDINATE`` (1e300 is finite, but its
    square, in any distance computed later, is not)."""
    if not np.all(np.isfinite(t)):
        raise InputError(pose_file, f"{where}: the pose holds a non-finite value", "fix or regenerate the pose file")
    if np.abs(t).max() > MAX_COORDINATE:
        raise InputError(pose_file, f"{where}: the translation {np.abs(t).max():.3g} lies beyond any real scene "
                         f"(|t| <= {MAX_COORDINATE:.0e})", "fix or regenerate the pose file")
    return t


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


def relative_names(layout: CaptureLayout, paths: list[Path]) -> list[str]:
    return [p.relative_to(layout.capture).as_posix() if p.is_relative_to(layout.capture) else str(p) for p in paths]
