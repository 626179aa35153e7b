"""Depth maps of a radiance field, and the files other tools read them from.

Per view: expected depth along the camera axis (sum_i w_i z_i / sum_i w_i, see
``nerf.render.volume.interval_stop_depths``), accumulated opacity and disparity as float32 ``.npy``; depth as
a 16-bit PNG whose sidecar JSON gives the scale (depth = value / scale, 0 = nothing hit); a colour-mapped
preview. Units are those of the normalized scene; ``to_sfm`` (4x4, a similarity) maps them back to the
frame structure from motion worked in.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nerfpipe.pipeline.stage import ArtifactRef

PNG_MAX = 65535


@dataclass(frozen=True)
class DepthView:
    """One exported view: where its files are and the camera that saw it (normalized world, OpenCV)."""

    name: str
    stem: str
    role: str  # "train" or "heldout"
    width: int
    height: int
    intrinsics: tuple[float, float, float, float]  # fx, fy, cx, cy at the exported resolution
    c2w: tuple[tuple[float, ...], ...]
    near: float
    far: float

    def K(self) -> np.ndarray:
        fx, fy, cx, cy = self.intrinsics
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


@dataclass
class DepthIndex:
    """``depth.json``: every exported view, the depth PNG scale, the units and the way back to SfM."""

    views: list[DepthView]
    png_scale: float
    to_sfm: list[list[float]]
    acc_threshold: float
    units: str = "normalized world (see to_sfm)"

    def save(self, path: Path) -> None:
        doc = {**asdict(self), "views": [asdict(v) for v in self.views]}
        path.write_text(json.dumps(doc, indent=1), encoding="utf-8")

    @staticmethod
    def load(path: Path) -> "DepthIndex":
        doc = json.loads(path.read_text(encoding="utf-8"))
        views = [DepthView(**{**v, "intrinsics": tuple(v["intrinsics"]), "c2w": tuple(map(tuple, v["c2w"]))})
                 for v in doc["views"]]
        return DepthIndex(views, doc["png_scale"], doc["to_sfm"], doc["acc_threshold"], doc["units"])


def png_scale_for(far: float) -> float:
    """Counts per unit of depth so that ``far`` fits in 16 bits with a little headroom."""
    return float(PNG_MAX - 1) / (1.02 * far)


def encode_depth_png(depth: np.ndarray, valid: np.ndarray, scale: float) -> np.ndarray:
    """(H, W) depth -> uint16 counts round(depth * scale); 0 where not ``valid`` (and no valid depth is 0)."""
    counts = np.clip(np.round(depth * scale), 1, PNG_MAX)
    return np.where(valid, counts, 0).astype(np.uint16)


def decode_depth_png(counts: np.ndarray, scale: float) -> np.ndarray:
    """uint16 counts -> float32 depth, NaN where the count is 0."""
    depth = counts.astype(np.float32) / np.float32(scale)
    return np.where(counts > 0, depth, np.nan).astype(np.float32)


def depth_preview(depth: np.ndarray, acc: np.ndarray, near: float, far: float, acc_threshold: float = 0.5) -> np.ndarray:
    """(H, W, 3) uint8: disparity between 1/far and 1/near through the turbo map of the videos (near is
    red, far is blue); black where the accumulated opacity is below ``acc_threshold``."""
    from nerfpipe.export.video import colorize_depth

    with np.errstate(divide="ignore"):
        negative_disparity = -1.0 / np.asarray(depth, dtype=np.float64)  # linear in disparity, red when near
    return colorize_depth(negative_disparity, acc, -1.0 / near, -1.0 / far, acc_threshold)


def write_view(folder: Path, view: DepthView, rendered: dict[str, np.ndarray], png_scale: float, acc_threshold: float,
               to_sfm: list[list[float]]) -> None:
    """Write one view's ``.depth.npy``, ``.acc.npy``, ``.disparity.npy``, ``.depth.png`` + ``.depth.json``,
    ``.preview.png`` and ``.rgb.png`` (the rendered colour, 8-bit, as trained: linear for RAW scenes)."""
    import cv2

    stem = folder / view.stem
    depth = rendered["depth"].astype(np.float32)
    acc = rendered["acc"].astype(np.float32)
    np.save(f"{stem}.depth.npy", depth)
    np.save(f"{stem}.acc.npy", acc)
    np.save(f"{stem}.disparity.npy", rendered["disparity"].astype(np.float32))
    valid = acc >= acc_threshold
    cv2.imwrite(f"{stem}.depth.png", encode_depth_png(depth, valid, png_scale))
    sidecar = {
        "depth_png": f"{view.stem}.depth.png",
        "scale": png_scale,
        "meaning": "depth along the camera axis = value / scale; 0 where accumulated opacity < acc_threshold",
        "acc_threshold": acc_threshold,
        "units": "normalized world",
        "to_sfm": to_sfm,
    }
    Path(f"{stem}.depth.json").write_text(json.dumps(sidecar, indent=1), encoding="utf-8")
    preview = depth_preview(depth, acc, view.near, view.far, acc_threshold)
    cv2.imwrite(f"{stem}.preview.png", preview[..., ::-1])
    rgb = np.round(np.clip(rendered["rgb"], 0.0, 1.0) * 255).astype(np.uint8)
    cv2.imwrite(f"{stem}.rgb.png", rgb[..., ::-1])


def read_view(folder: Path, view: DepthView) -> dict[str, np.ndarray]:
    """depth, acc, disparity (H, W) float32 and rgb (H, W, 3) float32 in [0, 1] of an exported view."""
    import cv2

    stem = folder / view.stem
    rgb = cv2.imread(f"{stem}.rgb.png", cv2.IMREAD_COLOR)
    if rgb is None:
        raise FileNotFoundError(f"{stem}.rgb.png")
    out: dict[str, Any] = {key: np.load(f"{stem}.{key}.npy") for key in ("depth", "acc", "disparity")}
    out["rgb"] = rgb[..., ::-1].astype(np.float32) / 255.0
    return out


def depth_in_frame(folder: Path, index: DepthIndex) -> float:
    """Turn a copy of the depth maps in ``folder`` (from the normalized world ``index`` describes) into the SfM
    frame, where every other export is: ``.depth.npy`` times the similarity's scale s, ``.disparity.npy``
    divided by it, each ``.depth.json`` sidecar's PNG scale divided by it (the PNGs' values stay), and
    ``index.json``: the views with their cameras, near and far in that frame. Returns what a PNG value
    multiplies to give depth in SfM units (nerfstudio's ``depth_unit_scale_factor``)."""
    from nerfpipe.geometry.normalize import Similarity
    from nerfpipe.pipeline.store import write_json_atomic

    move = Similarity.from_matrix(np.asarray(index.to_sfm))
    s = move.scale
    units = "the SfM frame's (the exported cameras' and transforms.json's)"
    for view in index.views:
        stem = folder / view.stem
        for name, power in (("depth", 1.0), ("disparity", -1.0)):
            path = Path(f"{stem}.{name}.npy")
            if path.is_file():
                np.save(path, (np.load(path) * s ** power).astype(np.float32))
        sidecar = Path(f"{stem}.depth.json")
        if sidecar.is_file():
            doc = json.loads(sidecar.read_text(encoding="utf-8"))
            doc.update({"scale": doc["scale"] / s, "units": units, "to_sfm": np.eye(4).tolist()})
            write_json_atomic(sidecar, doc)
    views = [DepthView(v.name, v.stem, v.role, v.width, v.height, v.intrinsics,
                       tuple(map(tuple, move.apply_c2w(np.asarray(v.c2w)).tolist())), v.near * s, v.far * s)
             for v in index.views]
    DepthIndex(views, index.png_scale / s, np.eye(4).tolist(), index.acc_threshold, units).save(folder / "index.json")
    return s / index.png_scale


DEPTH_INDEX = ArtifactRef("depth_index", DepthIndex.load)  # export_depth's depth.json, typed
