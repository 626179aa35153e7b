"""Foreground masks of photos taken in front of a constant backdrop (a black cloth, a white sweep).

Two steps. ``backdrop_mask``: a pixel is certainly backdrop when its colour is within ``tolerance`` of the
backdrop colour (the largest per-channel difference, as the scene analysis measures the image border) AND it
is joined to the image border through such pixels (4-connected). A backdrop-coloured region the object
encloses (a shadow, a dark patch, a hole seen through the object) stays foreground: from one view it cannot
be told from the object. ``object_mask`` then settles what lies in between: a real backdrop is not one
colour (a cloth's lit folds, a sweep's shading), so pixels a little farther from its colour are given to
OpenCV's GrabCut (Rother et al. 2004: colour mixture models of backdrop and object, and a graph cut), which
decides each by the colours around it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def _float_rgb(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) float64 in [0, 1] from uint8, uint16 or float pixels; (H, W, 4) loses its alpha."""
    if rgb.ndim != 3 or rgb.shape[2] not in (3, 4):
        raise ValueError(f"expected (H, W, 3) or (H, W, 4) pixels, got shape {rgb.shape}")
    scale = float(np.iinfo(rgb.dtype).max) if rgb.dtype.kind in "ui" else 1.0
    return rgb[..., :3].astype(np.float64) / scale


def backdrop_colored(rgb: np.ndarray, color: Sequence[float], tolerance: float) -> np.ndarray:
    """(H, W) bool: pixels whose every channel lies within ``tolerance`` of ``color``.

    rgb: (H, W, 3 or 4) uint8, uint16 or float in [0, 1]; color: (3,) in [0, 1]; ``|rgb - color|_inf <= tolerance``.
    """
    distance = np.abs(_float_rgb(rgb) - np.asarray(color, dtype=np.float64)).max(axis=-1)
    # 1e-9: a tolerance written in decimals (0.1) must admit the 8-bit level it names (25.5 / 255 rounds either way)
    return distance <= tolerance + 1e-9


def backdrop_mask(rgb: np.ndarray, color: Sequence[float], tolerance: float) -> np.ndarray:
    """(H, W) bool: backdrop pixels, the backdrop-coloured ones 4-connected to the image border through
    backdrop-coloured pixels (``backdrop_colored``)."""
    import cv2

    colored = backdrop_colored(rgb, color, tolerance)
    if not colored.any():
        return colored
    _, labels = cv2.connectedComponents(colored.astype(np.uint8), connectivity=4)
    edge = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])
    touching = np.unique(edge[edge > 0])  # label 0 is everything that is not backdrop-coloured
    return np.isin(labels, touching)


def foreground_mask(rgb: np.ndarray, color: Sequence[float], tolerance: float) -> np.ndarray:
    """(H, W) bool: everything but the backdrop (``backdrop_mask``)."""
    return ~backdrop_mask(rgb, color, tolerance)


def object_mask(rgb: np.ndarray, color: Sequence[float], tolerance: float, object_distance: float | None = None,
                iterations: int = 5, max_side: int = 640) -> np.ndarray:
    """(H, W) bool: the object in front of a constant backdrop, ``backdrop_mask`` refined by GrabCut.

    Seeds: the ``backdrop_mask`` pixels are certainly backdrop; pixels farther than ``object_distance``
    (default 3 x ``tolerance``) from the backdrop colour probably object; the rest probably backdrop.
    GrabCut (``cv2.grabCut``, ``iterations`` rounds) fits a colour mixture to each side and cuts between
    them, so the unlit parts of a backdrop go with it and the object's own shadows, surrounded by object
    colours, stay. It runs on the image scaled to at most ``max_side`` pixels a side; the result is scaled
    back and never includes a ``backdrop_mask`` pixel. Without seeds of both kinds (all backdrop, or nothing
    of it) it returns ``foreground_mask``.
    """
    import cv2

    pixels = _float_rgb(rgb)
    backdrop = backdrop_mask(pixels, color, tolerance)
    far = 3.0 * tolerance if object_distance is None else object_distance
    likely_object = ~backdrop_colored(pixels, color, far)
    if not backdrop.any() or not likely_object.any():
        return ~backdrop
    h, w = backdrop.shape
    scale = min(1.0, max_side / max(h, w))
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    seeds = np.full((h, w), cv2.GC_PR_BGD, np.uint8)
    seeds[likely_object] = cv2.GC_PR_FGD
    seeds[backdrop] = cv2.GC_BGD
    image = np.ascontiguousarray((pixels[..., ::-1] * 255.0).round().astype(np.uint8))  # 8-bit BGR, as GrabCut takes
    if scale < 1.0:
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        seeds = cv2.resize(seeds, size, interpolation=cv2.INTER_NEAREST)
    models = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.grabCut(image, seeds, None, *models, iterations, cv2.GC_INIT_WITH_MASK)
    found = ((seeds == cv2.GC_FGD) | (seeds == cv2.GC_PR_FGD)).astype(np.float32)
    if scale < 1.0:
        found = cv2.resize(found, (w, h), interpolation=cv2.INTER_LINEAR)
    return (found >= 0.5) & ~backdrop


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """(H, W) bool: ``mask`` grown by ``radius`` pixels (a disc of that radius; 0: unchanged)."""
    import cv2

    if radius <= 0:
        return mask.astype(bool)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return cv2.dilate(mask.astype(np.uint8), disc).astype(bool)
