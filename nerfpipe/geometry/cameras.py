"""Cameras, registered frames and sparse points: the contract between sfm, undistort and bounds.

Conventions, the same everywhere in nerfpipe:

- Intrinsics use COLMAP's camera models and parameter order (``CAMERA_MODELS``) and COLMAP's pixel
  convention: the centre of the top-left pixel is at (0.5, 0.5).
- ``c2w`` is a 4x4 camera-to-world matrix in the OpenCV camera convention: x right, y down, the camera
  looks along +z. Importers of other conventions (OpenGL/Blender, LLFF) convert on the way in.
- A frame's ``name`` is the ingest output name of its image (``images/<name>`` in the ingest stage).

On disk: ``cameras.json`` (cameras, frames, provenance) and ``points3d.npz`` (xyz, rgb, reprojection
error, and which points each frame observes, as CSR arrays ``vis_offsets`` / ``vis_points``).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

# COLMAP camera models: parameter names in COLMAP's order.
CAMERA_MODELS: dict[str, tuple[str, ...]] = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
    "SIMPLE_RADIAL_FISHEYE": ("f", "cx", "cy", "k1"),
    "RADIAL_FISHEYE": ("f", "cx", "cy", "k1", "k2"),
}
FISHEYE_MODELS = frozenset({"OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"})


@dataclass(frozen=True)
class Camera:
    """Intrinsics of one physical camera (``params`` in COLMAP order for ``model``)."""

    model: str
    width: int
    height: int
    params: tuple[float, ...]

    def __post_init__(self) -> None:
        if self.model not in CAMERA_MODELS:
            raise ValueError(f"unknown camera model {self.model!r}")
        if len(self.params) != len(CAMERA_MODELS[self.model]):
            raise ValueError(f"{self.model} takes {len(CAMERA_MODELS[self.model])} parameters, got {len(self.params)}")

    def param(self, name: str, default: float = 0.0) -> float:
        names = CAMERA_MODELS[self.model]
        return float(self.params[names.index(name)]) if name in names else default

    @property
    def fx(self) -> float:
        return self.param("fx", self.param("f"))

    @property
    def fy(self) -> float:
        return self.param("fy", self.param("f"))

    @property
    def cx(self) -> float:
        return self.param("cx")

    @property
    def cy(self) -> float:
        return self.param("cy")

    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy): what a pinhole render of this camera takes."""
        return self.fx, self.fy, self.cx, self.cy

    @property
    def is_fisheye(self) -> bool:
        return self.model in FISHEYE_MODELS

    def K(self) -> np.ndarray:
        """(3, 3) calibration matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def distortion(self) -> np.ndarray:
        """OpenCV distortion coefficients: (k1, k2, p1, p2, k3, k4, k5, k6), or (k1..k4) for fisheye models."""
        if self.is_fisheye:
            return np.array([self.param(n) for n in ("k1", "k2", "k3", "k4")])
        return np.array([self.param(n) for n in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")])

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.distortion() != 0.0))

    def scaled(self, sx: float, sy: float | None = None) -> "Camera":
        """The same camera for an image resized by (sx, sy); distortion is unchanged (it acts on normalized coordinates)."""
        sy = sx if sy is None else sy
        width, height = round(self.width * sx), round(self.height * sy)
        scale = {"f": (sx + sy) / 2, "fx": sx, "fy": sy, "cx": sx, "cy": sy}
        params = tuple(p * scale.get(n, 1.0) for n, p in zip(CAMERA_MODELS[self.model], self.params))
        return Camera(self.model, width, height, params)

    @staticmethod
    def pinhole(fx: float, fy: float, cx: float, cy: float, width: int, height: int) -> "Camera":
        return Camera("PINHOLE", width, height, (fx, fy, cx, cy))

    def to_json(self) -> dict[str, Any]:
        return {"model": self.model, "width": self.width, "height": self.height, "params": list(map(float, self.params))}

    @staticmethod
    def from_json(d: dict[str, Any]) -> "Camera":
        return Camera(d["model"], int(d["width"]), int(d["height"]), tuple(float(p) for p in d["params"]))


@dataclass
class Frame:
    """One registered image: its ingest name, its camera, and its camera-to-world pose (OpenCV convention)."""

    name: str
    camera_id: int
    c2w: np.ndarray  # (4, 4) float64
    split: str | None = None  # "train" / "val" / "test" where the capture defines splits

    @property
    def center(self) -> np.ndarray:
        return self.c2w[:3, 3]

    @property
    def w2c(self) -> np.ndarray:
        return invert_pose(self.c2w)


@dataclass
class Points:
    """Sparse 3D points (N) and, per frame, the indices of the points that frame observes."""

    xyz: np.ndarray  # (N, 3) float64
    rgb: np.ndarray  # (N, 3) uint8
    error: np.ndarray  # (N,) float64, mean reprojection error in pixels
    visible: list[np.ndarray] = field(default_factory=list)  # per frame: (n_i,) int64 indices into xyz

    def save(self, path: Path) -> None:
        offsets = np.cumsum([0] + [len(v) for v in self.visible]).astype(np.int64)
        flat = np.concatenate(self.visible).astype(np.int64) if self.visible else np.zeros(0, np.int64)
        np.savez(path, xyz=self.xyz, rgb=self.rgb, error=self.error, vis_offsets=offsets, vis_points=flat)

    @staticmethod
    def load(path: Path) -> "Points":
        with np.load(path) as z:
            offsets, flat = z["vis_offsets"], z["vis_points"]
            visible = [flat[offsets[i] : offsets[i + 1]] for i in range(len(offsets) - 1)]
            return Points(z["xyz"], z["rgb"], z["error"], visible)


@dataclass
class PoseHints:
    """What a camera set carries beside its cameras, frames and points, for the stages after the one that
    made it. Saved in cameras.json under ``extra``; only what is set is written.

    pose_files: the capture's pose files the poses came from (relative to the capture).
    aabb_scale: instant-ngp's scene extent in units of the cameras' cube (transforms.json).
    llff_bounds: {image name: [near, far]} from LLFF's poses_bounds.npy.
    sfm: COLMAP's statistics of the model it made; triangulation: what triangulating the given poses found.
    image_roots: {frame name: "ingest" or "undistort"}, the folder holding each frame's image (undistort).
    undistortion: {camera id: how far its distortion moved pixels, and whether it was resampled} (undistort).
    per_image: {frame name: the pose correction and exposure training learned} (train).
    """

    pose_files: list[str] = field(default_factory=list)
    aabb_scale: float | None = None
    llff_bounds: dict[str, list[float]] | None = None
    sfm: dict[str, Any] | None = None
    triangulation: dict[str, Any] | None = None
    image_roots: dict[str, str] = field(default_factory=dict)
    undistortion: dict[str, Any] | None = None
    per_image: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in dataclasses.asdict(self).items() if v not in (None, [], {})}

    @staticmethod
    def from_json(doc: dict[str, Any]) -> "PoseHints":
        known = {f.name for f in dataclasses.fields(PoseHints)}
        return PoseHints(**{k: v for k, v in doc.items() if k in known})


@dataclass
class CameraSet:
    """Everything sfm (or a pose importer) hands on: cameras, registered frames, optional sparse points."""

    cameras: dict[int, Camera]
    frames: list[Frame]
    points: Points | None = None
    source: str = ""  # "colmap_sfm", "colmap_model", "transforms_json", "llff", "middlebury"
    unregistered: list[str] = field(default_factory=list)
    hints: PoseHints = field(default_factory=PoseHints)

    def camera_of(self, frame: Frame) -> Camera:
        return self.cameras[frame.camera_id]

    def centers(self) -> np.ndarray:
        return np.array([f.center for f in self.frames]).reshape(-1, 3)

    def save(self, folder: Path) -> None:
        doc = {
            "convention": "opencv c2w (x right, y down, z forward); COLMAP intrinsics, pixel centres at +0.5",
            "source": self.source,
            "cameras": {str(k): c.to_json() for k, c in sorted(self.cameras.items())},
            "frames": [
                {"name": f.name, "camera_id": f.camera_id, "split": f.split, "c2w": f.c2w.tolist()} for f in self.frames
            ],
            "unregistered": self.unregistered,
            "extra": self.hints.to_json(),
        }
        (folder / "cameras.json").write_text(json.dumps(doc, indent=1))
        if self.points is not None:
            self.points.save(folder / "points3d.npz")

    @staticmethod
    def load(folder: Path) -> "CameraSet":
        doc = json.loads((folder / "cameras.json").read_text())
        cameras = {int(k): Camera.from_json(v) for k, v in doc["cameras"].items()}
        frames = [Frame(f["name"], int(f["camera_id"]), np.array(f["c2w"], dtype=np.float64), f.get("split")) for f in doc["frames"]]
        points = Points.load(folder / "points3d.npz") if (folder / "points3d.npz").exists() else None
        return CameraSet(cameras, frames, points, doc.get("source", ""), doc.get("unregistered", []),
                         PoseHints.from_json(doc.get("extra", {})))


def invert_pose(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform [R | t] -> [R^T | -R^T t]."""
    out = np.eye(4)
    out[:3, :3] = pose[:3, :3].T
    out[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return out


def pose_from_rt(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 from a (3, 3) rotation and a (3,) translation."""
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = t
    return out


# OpenGL / Blender cameras (x right, y up, looking down -z) to OpenCV (x right, y down, looking down +z).
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def look_at(eye: np.ndarray, target: np.ndarray, down: np.ndarray) -> np.ndarray:
    """OpenCV c2w (4, 4) at ``eye`` (3,) with +z towards ``target`` (3,) and +y as close to ``down`` (3,) as
    a right-handed orthonormal frame allows (y is ``down`` made perpendicular to z).

    Raises ``ValueError`` when ``down`` is parallel to the viewing axis (the roll is then undefined).
    """
    z = np.asarray(target, dtype=np.float64) - np.asarray(eye, dtype=np.float64)
    z_norm = np.linalg.norm(z)
    if z_norm == 0.0:
        raise ValueError("look_at: eye and target coincide")
    z /= z_norm
    x = np.cross(np.asarray(down, dtype=np.float64), z)  # down x forward = right, as y x z = x
    x_norm = np.linalg.norm(x)
    if x_norm < 1e-9:
        raise ValueError("look_at: the down vector is parallel to the viewing axis")
    x /= x_norm
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    pose[:3, 3] = eye
    return pose


def mean_camera(c2ws: np.ndarray) -> np.ndarray:
    """The average pose (OpenCV): mean centre, mean viewing axis, mean down axis made orthonormal."""
    z = c2ws[:, :3, 2].mean(axis=0)
    z /= np.linalg.norm(z)
    y = c2ws[:, :3, 1].mean(axis=0)
    x = np.cross(y, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, y, z], axis=1)
    pose[:3, 3] = c2ws[:, :3, 3].mean(axis=0)
    return pose
