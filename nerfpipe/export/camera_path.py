"""Camera paths made of keyframes: what the web viewer's panel records, and what ``render.path=FILE`` renders.

A ``camera_path.json`` holds keyframes, each a camera-to-world matrix in the run's normalized world (OpenCV
axes: x right, y down, z forward; the world of the train stage's cameras, z up) and a vertical field of view
in degrees, and how many frames to render along them at what rate. The path runs through every keyframe:
positions and fields of view follow a cubic spline over the keyframes' indices, orientations a rotation spline
(scipy's ``CubicSpline`` and ``RotationSpline``, C2-continuous: no jolt at a keyframe), as nerfstudio's
camera-path editor moves. ``loop`` closes the path back to its first keyframe.

The render stage's own ``camera_path.json`` (``frames`` with a ``c2w`` each) loads too, each frame a
keyframe, so a rendered path renders again exactly; and so does nerfstudio's (``camera_path`` with a
``camera_to_world`` and ``fov`` each, as its viewer records and ``ns-render camera-path`` reads), taken in the
SfM frame of the run's exported ``transforms.json``: the render stage writes its path in that schema too
(``camera_path.nerfstudio.json``, ``nerfstudio_path``). A path recorded in nerfstudio's viewer on a model
trained from that ``transforms.json`` is in nerfstudio's own world (its ``dataparser_transforms.json``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nerfpipe.pipeline.errors import InputError
from nerfpipe.poses.photos import checked_position, checked_rotation

FORMAT = "nerfpipe camera path"
NERFSTUDIO_FRAME = "the SfM frame of the run's exports/transforms.json; camera_to_world: OpenGL axes, row-major"
MAX_FRAMES = 100_000
FIX_ADVICE = "record it again in `nerfpipe view RUN --web` (Camera path), or fix the file"


@dataclass(frozen=True)
class Keyframe:
    """A camera on the path: ``c2w`` (4, 4) in the normalized world, OpenCV axes; ``fov`` vertical, degrees."""

    c2w: np.ndarray
    fov: float


@dataclass(frozen=True)
class CameraPath:
    keyframes: tuple[Keyframe, ...]
    frames: int = 120
    fps: float = 24.0
    loop: bool = False
    frame: str = "world"  # where the keyframes' c2w are: the run's normalized "world", or the "sfm" frame

    def __post_init__(self) -> None:
        if not self.keyframes:
            raise ValueError("a camera path needs at least one keyframe")
        if not 1 <= self.frames <= MAX_FRAMES:
            raise ValueError(f"frames must be in 1..{MAX_FRAMES}, got {self.frames}")
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps must be a positive number, got {self.fps}")

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "convention": "c2w: camera-to-world in the run's normalized world, opencv axes (x right, y down, "
                          "z forward); fov: vertical, degrees",
            "frames": self.frames, "fps": self.fps, "loop": self.loop,
            "keyframes": [{"c2w": k.c2w.tolist(), "fov": k.fov} for k in self.keyframes],
        }

    def save(self, path: Path) -> None:
        from nerfpipe.pipeline.store import write_json_atomic

        write_json_atomic(path, self.to_json())

    @staticmethod
    def load(path: Path) -> "CameraPath":
        """The path in ``path``: a keyframe path, or a render's ``camera_path.json``. ``InputError`` names the
        file and what is wrong with it."""
        try:
            doc = json.loads(Path(path).read_text(encoding="utf-8"))
        except OSError as err:
            raise InputError(path, f"cannot be read ({err.strerror or err})", "pass an existing camera_path.json") from None
        except (UnicodeDecodeError, ValueError) as err:
            raise InputError(path, f"is not valid JSON ({err})", FIX_ADVICE) from None
        if not isinstance(doc, dict):
            raise InputError(path, "is not a camera path (a JSON object with keyframes)", FIX_ADVICE)
        if isinstance(doc.get("camera_path"), list):  # nerfstudio's: every entry a frame, in the SfM frame
            keyframes = [_keyframe(_from_nerfstudio(c, path, i), path, f"camera_path[{i}]", None)
                         for i, c in enumerate(doc["camera_path"])]
            seconds = doc.get("seconds")
            fps = doc.get("fps") or (len(keyframes) / seconds if isinstance(seconds, (int, float)) and seconds else 24.0)
            frames = len(keyframes)
            return _checked(path, keyframes, frames, fps, False, "sfm")
        elif isinstance(doc.get("keyframes"), list):
            keyframes = [_keyframe(k, path, f"keyframe {i}", None) for i, k in enumerate(doc["keyframes"])]
            frames, fps, loop = doc.get("frames", 120), doc.get("fps", 24.0), doc.get("loop", False)
        elif isinstance(doc.get("frames"), list) and isinstance(doc.get("camera"), dict):  # a render's own path
            camera = doc["camera"]
            fov = _render_fov(camera, path)
            keyframes = [_keyframe(f, path, f"frame {i}", fov) for i, f in enumerate(doc["frames"])]
            frames, fps, loop = len(keyframes), doc.get("fps", 24.0), False
        else:
            raise InputError(path, "has no keyframes list", FIX_ADVICE)
        return _checked(path, keyframes, frames, fps, loop, "world")

    def sample(self) -> tuple[np.ndarray, np.ndarray]:
        """(``frames``, 4, 4) camera-to-world poses along the path and their (``frames``,) vertical fields of
        view in degrees; the first is the first keyframe, and the last the last keyframe (or, looped, the
        frame before the first again)."""
        from scipy.interpolate import CubicSpline
        from scipy.spatial.transform import Rotation, RotationSpline

        keys = list(self.keyframes) + ([self.keyframes[0]] if self.loop and len(self.keyframes) > 1 else [])
        if len(keys) == 1:
            return np.repeat(keys[0].c2w[None], self.frames, axis=0), np.full(self.frames, keys[0].fov)
        knots = np.arange(len(keys), dtype=np.float64)
        t = np.linspace(0.0, knots[-1], self.frames, endpoint=not self.loop)
        ends = "periodic" if self.loop else "not-a-knot"
        if len(keys) < 4 and not self.loop:
            ends = "natural"  # 'not-a-knot' needs four points
        centres = CubicSpline(knots, np.array([k.c2w[:3, 3] for k in keys]), bc_type=ends)(t)
        fovs = CubicSpline(knots, np.array([k.fov for k in keys]), bc_type=ends)(t)
        rotations = RotationSpline(knots, Rotation.from_matrix(np.array([k.c2w[:3, :3] for k in keys])))(t)
        poses = np.tile(np.eye(4), (self.frames, 1, 1))
        poses[:, :3, :3] = rotations.as_matrix()
        poses[:, :3, 3] = centres
        low, high = min(k.fov for k in keys), max(k.fov for k in keys)
        return poses, np.clip(fovs, low, high)  # a spline may overshoot; a field of view stays within the keys'


def nerfstudio_path(poses_sfm: np.ndarray, fovs: np.ndarray, width: int, height: int, fps: float) -> dict[str, Any]:
    """A rendered path in nerfstudio's camera-path schema (what ``ns-render camera-path`` reads): each frame's
    ``camera_to_world`` (OpenGL axes, row-major, in the SfM frame of the run's ``transforms.json``), vertical
    ``fov`` in degrees and ``aspect``; the render size, ``fps`` and ``seconds``. ``poses_sfm``: (N, 4, 4)
    OpenCV camera-to-world."""
    from nerfpipe.geometry.cameras import OPENGL_TO_OPENCV

    return {
        "camera_type": "perspective", "render_height": int(height), "render_width": int(width),
        "fps": float(fps), "seconds": len(poses_sfm) / float(fps), "smoothness_value": 0.0, "is_cycle": False,
        "crop": None, "keyframes": [], "nerfpipe_frame": NERFSTUDIO_FRAME,
        "camera_path": [{"camera_to_world": (np.asarray(pose) @ OPENGL_TO_OPENCV).reshape(-1).tolist(),
                         "fov": float(fov), "aspect": width / height} for pose, fov in zip(poses_sfm, fovs)],
    }


def _from_nerfstudio(entry: Any, path: Path, i: int) -> dict[str, Any]:
    """A nerfstudio camera-path entry as a keyframe's c2w (OpenCV axes) and fov."""
    from nerfpipe.geometry.cameras import OPENGL_TO_OPENCV

    if not isinstance(entry, dict):
        raise InputError(path, f"camera_path[{i}] is not an object with camera_to_world and fov", FIX_ADVICE)
    try:
        gl = np.array(entry.get("camera_to_world"), dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(path, f"camera_path[{i}]: camera_to_world is not 16 numbers", FIX_ADVICE) from None
    if gl.size not in (12, 16):
        raise InputError(path, f"camera_path[{i}]: camera_to_world is not 16 numbers (a 4x4 matrix)", FIX_ADVICE)
    gl = np.vstack([gl.reshape(-1, 4)[:3], [0.0, 0.0, 0.0, 1.0]])
    return {"c2w": gl @ OPENGL_TO_OPENCV, "fov": entry.get("fov")}


def _checked(path: Path, keyframes: list[Keyframe], frames: Any, fps: Any, loop: Any, frame: str) -> CameraPath:
    if not keyframes:
        raise InputError(path, "has no keyframes", "add at least one keyframe (Add keyframe, in the viewer)")
    if not (isinstance(frames, int) and not isinstance(frames, bool) and 1 <= frames <= MAX_FRAMES):
        raise InputError(path, f"frames is {frames!r}, not a whole number from 1 to {MAX_FRAMES}", FIX_ADVICE)
    if not (isinstance(fps, (int, float)) and not isinstance(fps, bool) and math.isfinite(fps) and fps > 0):
        raise InputError(path, f"fps is {fps!r}, not a positive number", FIX_ADVICE)
    return CameraPath(tuple(keyframes), frames, float(fps), bool(loop), frame)


def _keyframe(entry: Any, path: Path, where: str, fov: float | None) -> Keyframe:
    if not isinstance(entry, dict):
        raise InputError(path, f"{where} is not an object with c2w and fov", FIX_ADVICE)
    try:
        c2w = np.array(entry.get("c2w"), dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(path, f"{where}: c2w is not a matrix of numbers", FIX_ADVICE) from None
    if c2w.shape != (4, 4):
        raise InputError(path, f"{where}: c2w is not a 4x4 matrix", FIX_ADVICE)
    if not np.all(np.isfinite(c2w)) or np.abs(c2w[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-6:
        raise InputError(path, f"{where}: c2w is not a rigid transform (finite, last row 0 0 0 1)", FIX_ADVICE)
    pose = np.eye(4)
    pose[:3, :3] = checked_rotation(c2w[:3, :3], path, where)
    pose[:3, 3] = checked_position(c2w[:3, 3], path, where)
    value = entry.get("fov", fov)
    if not (isinstance(value, (int, float)) and not isinstance(value, bool) and 0 < value < 180):
        raise InputError(path, f"{where}: fov is {value!r}, not a vertical field of view in (0, 180) degrees",
                         FIX_ADVICE)
    return Keyframe(pose, float(value))


def _render_fov(camera: dict[str, Any], path: Path) -> float:
    """The vertical field of view of a render's camera."""
    from nerfpipe.geometry.cameras import Camera

    try:
        camera = Camera.from_json(camera)
        return fov_of(camera.height, camera.fy)
    except (KeyError, TypeError, ValueError, IndexError, ZeroDivisionError):
        raise InputError(path, "has a camera without its height and focal length", FIX_ADVICE) from None


def fov_of(height: int, fy: float) -> float:
    """The vertical field of view, in degrees, of a camera ``height`` pixels tall with focal length ``fy``."""
    return math.degrees(2 * math.atan(0.5 * height / fy))


def focal_of(height: int, fov: float) -> float:
    """The focal length, in pixels, that gives a camera ``height`` pixels tall the vertical ``fov`` (degrees)."""
    return 0.5 * height / math.tan(math.radians(fov) / 2)


def view_range(c2w: np.ndarray, far: float) -> tuple[float, float]:
    """Near and far around the scene from a camera anywhere (a keyframe, the browser's view): the world's
    centre is the scene's, and nothing the photos' cameras saw lay farther from it than their ``far`` bound
    (at least the [-1, 1]^3 box); so the range is the camera's distance from the centre, give or take that."""
    reach = max(math.sqrt(3.0), far)
    distance = float(np.linalg.norm(c2w[:3, 3]))
    return max(1e-2, distance - reach), distance + reach
