"""Whether the photos have alpha, a constant backdrop (its colour from the images' border pixels) or a
background that is part of the scene."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from nerfpipe.artifacts import PhotoRecord
from nerfpipe.pipeline.errors import StageError


# -- background ------------------------------------------------------------------------------------------
def read_small(path: Path, max_side: int = 128) -> np.ndarray:
    """(h, w, 3 or 4) float RGB(A) in [0, 1], downscaled (area) so the longest side is at most ``max_side``."""
    import cv2

    pixels = cv2.imdecode(np.fromfile(path, np.uint8), cv2.IMREAD_UNCHANGED)
    if pixels is None:
        raise StageError(f"scene: cannot read the image {path}")
    full = np.iinfo(pixels.dtype).max if pixels.dtype.kind in "ui" else 1.0
    if pixels.ndim == 2:
        pixels = pixels[..., None].repeat(3, axis=2)
    h, w = pixels.shape[:2]
    if max(h, w) > max_side:
        s = max_side / max(h, w)
        pixels = cv2.resize(pixels, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    pixels = pixels.astype(np.float64) / full
    order = [2, 1, 0, 3][: pixels.shape[2]]  # BGR(A) -> RGB(A)
    return pixels[..., order]


def border_pixels(rgb: np.ndarray, band: float = 0.03) -> np.ndarray:
    """(K, 3) pixels of the border band (``band`` of the shorter side, at least one pixel) of an (h, w, 3) image."""
    h, w = rgb.shape[:2]
    b = max(1, round(band * min(h, w)))
    mask = np.ones((h, w), bool)
    mask[b : h - b, b : w - b] = False
    return rgb[mask][:, :3]


def decide_background(
    records: list[PhotoRecord], paths: list[Path], params: Any
) -> tuple[str, str, dict[str, Any], tuple[float, float, float] | None]:
    """(value, evidence, measured, border colour) from the alpha flags and the images' border pixels."""
    n = len(records)
    with_alpha = sum(bool(r.has_alpha) for r in records)
    take = np.unique(np.linspace(0, n - 1, min(n, params.background_images)).round().astype(int))
    borders, transparent = [], []
    for i in take:
        pixels = read_small(paths[i])
        if pixels.shape[2] == 4:
            transparent.append(float(np.mean(pixels[..., 3] < 0.5)))
        borders.append(border_pixels(pixels))
    border = np.concatenate(borders)
    color = np.median(border, axis=0)
    distance = np.abs(border - color).max(axis=1)
    within = float(np.mean(distance <= params.background_tolerance))
    measured: dict[str, Any] = {
        "images": n,
        "with_alpha": with_alpha,
        "sampled": len(take),
        "border_color": [round(float(c), 4) for c in color],
        "border_within_tolerance": round(within, 4),
        "border_p90_distance": round(float(np.percentile(distance, 90)), 4),
        "tolerance": params.background_tolerance,  # training masks the backdrop with it (nerfpipe.imaging.masks)
    }
    rgb = tuple(float(c) for c in color)
    border_text = (
        f"median border colour ({', '.join(f'{c:.2f}' for c in color)}) with {100 * within:.1f}% of border pixels "
        f"within {params.background_tolerance:g} of it (90th percentile distance {np.percentile(distance, 90):.3f}) "
        f"over {len(take)} images"
    )
    if transparent:
        measured["transparent_fraction"] = round(float(np.mean(transparent)), 4)
    if with_alpha == n and (not transparent or max(transparent) > 0.001):
        coverage = f", {100 * np.mean(transparent):.1f}% of pixels transparent on average" if transparent else ""
        return "alpha", f"{with_alpha} of {n} images have an alpha channel{coverage}", measured, rgb
    alpha_note = f"{with_alpha} of {n} images have alpha; " if with_alpha else ""
    if within >= params.background_min_fraction:
        return "color", f"{alpha_note}{border_text}: a constant background", measured, rgb
    return "none", f"{alpha_note}{border_text}: the background varies", measured, rgb
