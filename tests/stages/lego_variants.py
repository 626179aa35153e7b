"""Lego captures made harder on purpose: training photos re-exposed (with EXIF that says so) and training
poses perturbed, for the appearance and camera-refinement tests (and ``scripts/bench_per_image.py``).

Each writes a capture folder in the layout of ``nerf_synthetic_lego_400`` (transforms_*.json, train/,
val/), downscaled to ``size`` px so that ingest has less to do; the val photos and poses stay as they are.
"""

from __future__ import annotations

import json
import math
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from nerfpipe.imaging.exif import TAG_EXPOSURE_TIME, TAG_F_NUMBER, TAG_ISO
from tests.helpers import shared
from tests.imaging import photos

LEGO = shared("nerf_synthetic_lego_400")


def _downscaled(path: Path, size: int) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA) if image.shape[0] != size else image


def _copy_split(capture: Path, split: str, size: int, frames: list[dict] | None = None) -> dict:
    doc = json.loads((LEGO / f"transforms_{split}.json").read_text())
    if frames is not None:
        doc["frames"] = frames
    (capture / split).mkdir(parents=True, exist_ok=True)
    for frame in doc["frames"]:
        name = Path(frame["file_path"]).name + ".png"
        cv2.imwrite(str(capture / split / name), _downscaled(LEGO / split / name, size))
    (capture / f"transforms_{split}.json").write_text(json.dumps(doc))
    return doc


def _srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x > 0.04045, ((x + 0.055) / 1.055) ** 2.4, x / 12.92)


def _linear_to_srgb(x: np.ndarray) -> np.ndarray:
    return np.where(x > 0.0031308, 1.055 * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - 0.055, 12.92 * x)


def reexpose(bgra: np.ndarray, stops: float) -> np.ndarray:
    """An 8-bit BGRA photo as a camera exposing ``stops`` more would have taken it: linear light times
    2^stops, clipped at white; alpha unchanged (the transparent backdrop is not light the camera saw)."""
    out = bgra.copy()
    light = _srgb_to_linear(bgra[..., :3].astype(np.float64) / 255.0) * 2.0**stops
    out[..., :3] = np.round(_linear_to_srgb(np.clip(light, 0.0, 1.0)) * 255.0).astype(np.uint8)
    return out


def exif_exposure(stops: float) -> Image.Exif:
    """EXIF saying exposure time 1/100 s x 2^stops at f/8, ISO 100."""
    micro = int(round(1e4 * 2.0**stops))  # seconds x 1e6
    return photos.exif(photo={TAG_EXPOSURE_TIME: Fraction(micro, 1_000_000), TAG_F_NUMBER: Fraction(8), TAG_ISO: 100})


def reexposed_lego(capture: Path, size: int = 100, seed: int = 0, spread: float = 1.0) -> dict[str, float]:
    """Lego with each training photo re-exposed by a random ``[-spread, spread]`` stops and EXIF saying by how
    much; returns {photo name: stops}."""
    _copy_split(capture, "val", size)
    doc = _copy_split(capture, "train", size)
    rng = np.random.default_rng(seed)
    stops = {}
    for frame in doc["frames"]:
        name = Path(frame["file_path"]).name + ".png"
        s = float(rng.uniform(-spread, spread))
        bgra = reexpose(cv2.imread(str(capture / "train" / name), cv2.IMREAD_UNCHANGED), s)
        (capture / "train" / name).write_bytes(photos.png(bgra[..., [2, 1, 0, 3]], exif_exposure(s)))
        stops[name] = s
    return stops


def _rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = math.radians(degrees)
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * k @ k


def perturbed_lego(capture: Path, size: int = 100, seed: int = 0, degrees: float = 1.0,
                   share: float = 0.01) -> dict[str, np.ndarray]:
    """Lego with every training pose turned by ``degrees`` about a random axis through its centre and its
    centre moved by ``share`` of its distance from the scene centre in a random direction (seeded);
    returns the true camera-to-world poses {photo name: (4, 4)} (Blender convention, as the file has)."""
    _copy_split(capture, "val", size)
    doc = json.loads((LEGO / "transforms_train.json").read_text())
    rng = np.random.default_rng(seed)
    truth, frames = {}, []
    for frame in doc["frames"]:
        pose = np.array(frame["transform_matrix"], dtype=np.float64)
        truth[Path(frame["file_path"]).name + ".png"] = pose.copy()
        direction = rng.normal(size=3)
        pose[:3, :3] = _rotation(rng.normal(size=3), degrees) @ pose[:3, :3]
        pose[:3, 3] += share * np.linalg.norm(pose[:3, 3]) * direction / np.linalg.norm(direction)
        frames.append({**frame, "transform_matrix": pose.tolist()})
    _copy_split(capture, "train", size, frames)
    return truth
