"""How a textured mesh scores against held-out photos, beside the field that made it.

Each held-out photo is compared with the mesh rendered from its camera (``nerfpipe.export.texture.render``):
PSNR over the whole view (what the mesh shows where it covers nothing counts too, as the background), PSNR
over the pixels it covers, the share of pixels it covers, and its mean colour there as a share of the
photo's, channel by channel (a texture baked too dark or too bright shows as a ratio off 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from nerfpipe.export.texture import TexturedMesh, render


@dataclass(frozen=True)
class HeldoutView:
    """A photo the field did not train on: (H, W, 3) in [0, 1], its camera (K (3, 3), c2w (4, 4), OpenCV
    axes) and the PSNR the field scored on it."""

    photo: np.ndarray
    K: np.ndarray
    c2w: np.ndarray
    field_psnr: float


def psnr(rendered: np.ndarray, photo: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB of two images in [0, 1] (kornia's, as the field's scores; at most
    100 dB, for identical ones)."""
    import kornia
    import torch

    error = kornia.metrics.psnr(torch.as_tensor(np.asarray(rendered, dtype=np.float64)),
                                torch.as_tensor(np.asarray(photo, dtype=np.float64)), 1.0)
    return float(min(error, 100.0))


def score_views(mesh: TexturedMesh, views: Sequence[HeldoutView],
                background: Sequence[float] = (0.0, 0.0, 0.0)) -> dict[str, Any] | None:
    """``mesh_psnr``, ``covered_psnr``, ``coverage`` and ``field_psnr`` averaged over ``views``, and
    ``colour_ratio`` (3,): the mesh's summed colour over the pixels it covers in all views over the photos'
    there. None without views."""
    if not views:
        return None
    mesh_psnr, covered_psnr, coverage, covered, seen = [], [], [], [], []
    for view in views:
        height, width = view.photo.shape[:2]
        rgb, hit = render(mesh, view.K, view.c2w, width, height, background)
        mesh_psnr.append(psnr(rgb, view.photo))
        covered_psnr.append(psnr(rgb[hit], view.photo[hit]) if hit.any() else 0.0)
        coverage.append(float(hit.mean()))
        covered.append(rgb[hit].sum(axis=0))
        seen.append(view.photo[hit].sum(axis=0))
    ratio = np.sum(covered, axis=0) / np.maximum(np.sum(seen, axis=0), 1e-9)
    return {"mesh_psnr": round(float(np.mean(mesh_psnr)), 3),
            "field_psnr": round(float(np.mean([v.field_psnr for v in views])), 3),
            "covered_psnr": round(float(np.mean(covered_psnr)), 3), "coverage": round(float(np.mean(coverage)), 4),
            "views": len(views), "colour_ratio": [round(float(r), 4) for r in ratio]}
