"""A COLMAP binary model's files checked against their record layouts before pycolmap reads them.

COLMAP's readers trust the counts a file states: a ``points3D.bin`` cut short makes pycolmap read a track
length from what lies past its end and reserve memory for it (16.9 GB, then ``std::bad_alloc``, or the OOM
killer with no message on a smaller machine). Each file is walked here record by record, as COLMAP's
``ReadCamerasBinary``, ``ReadImagesBinary`` and ``ReadPoints3DBinary`` (``colmap/scene/reconstruction_io``)
lay them out, and a count or length that runs past the end is one line naming the file.

Layouts (little-endian):

- ``cameras.bin``: u64 count; per camera i32 id, i32 model, u64 width, u64 height, f64 params[model's].
- ``images.bin``: u64 count; per image u32 id, f64 qvec[4], f64 tvec[3], u32 camera id, a NUL-ended name,
  u64 point count, (f64 x, f64 y, i64 point id) per point.
- ``points3D.bin``: u64 count; per point u64 id, f64 xyz[3], u8 rgb[3], f64 error, u64 track length,
  (u32 image id, u32 point index) per track element.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Callable, Sequence

from nerfpipe.pipeline.errors import InputError

# parameters per COLMAP camera model id (colmap/sensor/models.h)
MODEL_PARAMS = {0: 3, 1: 4, 2: 4, 3: 5, 4: 8, 5: 8, 6: 12, 7: 5, 8: 4, 9: 5, 10: 12, 11: 16}

ADVICE = "copy the model again, or re-export it from COLMAP; or remove it to let SfM compute the poses"


class _Cut(Exception):
    """A record runs past the end of the file."""


class _Reader:
    def __init__(self, data: bytes) -> None:
        self.data, self.at = data, 0

    def take(self, fmt: str) -> tuple:
        size = struct.calcsize(fmt)
        if self.at + size > len(self.data):
            raise _Cut
        values = struct.unpack_from(fmt, self.data, self.at)
        self.at += size
        return values

    def skip(self, count: int, size: int) -> None:
        if count < 0 or self.at + count * size > len(self.data):
            raise _Cut
        self.at += count * size

    def name(self) -> None:
        end = self.data.find(b"\0", self.at)
        if end < 0:
            raise _Cut
        self.at = end + 1


def _cameras(r: _Reader) -> str | None:
    for _ in range(r.take("<Q")[0]):
        _, model, _, _ = r.take("<iiQQ")
        if model not in MODEL_PARAMS:
            return f"names camera model id {model}, which COLMAP does not define"
        r.skip(MODEL_PARAMS[model], 8)
    return None


def _images(r: _Reader) -> str | None:
    count = r.take("<Q")[0]
    if count == 0:
        return "holds no images"
    for _ in range(count):
        image_id, *qvec = r.take("<I4d3dI")[:5]
        if problem := quaternion_problem(qvec):
            return f"image {image_id}: {problem}"
        r.name()
        r.skip(r.take("<Q")[0], 24)
    return None


def _points(r: _Reader) -> str | None:
    for _ in range(r.take("<Q")[0]):
        *_, track_length = r.take("<Q3d3BdQ")
        r.skip(track_length, 8)
    return None


WALKS: dict[str, Callable[[_Reader], str | None]] = {"cameras.bin": _cameras, "images.bin": _images,
                                                    "points3D.bin": _points}


def quaternion_problem(qvec: Sequence[float]) -> str | None:
    """Why a COLMAP (qw, qx, qy, qz) is no rotation, or ``None``. pycolmap normalizes what it reads, so a zero
    quaternion would become the identity without a word."""
    norm = math.sqrt(sum(q * q for q in qvec)) if all(math.isfinite(q) for q in qvec) else math.nan
    if not math.isfinite(norm):
        return "its quaternion holds a non-finite value"
    if norm < 1e-6:
        return "its quaternion is zero, which is no rotation"
    return None


def check_text_images(images_txt: Path) -> None:
    """Raise ``InputError`` for an ``images.txt`` line whose quaternion is no rotation (see ``quaternion_problem``)."""
    lines = iter(images_txt.read_text(encoding="utf-8", errors="replace").splitlines())
    for line in lines:  # as COLMAP reads it: an image's line, then the next line whatever it holds (its 2D points)
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        next(lines, None)
        fields = line.split()
        try:
            qvec = [float(v) for v in fields[1:5]]
        except ValueError:
            continue  # pycolmap's reader says what is wrong with the line
        if len(qvec) == 4 and (problem := quaternion_problem(qvec)):
            raise InputError(images_txt, f"image {fields[0]}: {problem}", ADVICE)


def check_binary_model(model_dir: Path) -> None:
    """Raise ``InputError`` naming the first of the model's ``.bin`` files that is empty, cut short, or has
    bytes past its last record; a file the folder lacks is left to the reader."""
    for name, walk in WALKS.items():
        path = model_dir / name
        if not path.is_file():
            continue
        data = path.read_bytes()
        if not data:
            raise InputError(path, "is empty (0 bytes)", ADVICE)
        reader = _Reader(data)
        try:
            problem = walk(reader)
        except _Cut:
            problem = f"is cut short: its records run past its end ({len(data)} bytes)"
        if problem is None and reader.at != len(data):
            problem = f"has {len(data) - reader.at} bytes after its last record"
        if problem is not None:
            raise InputError(path, problem, ADVICE)
