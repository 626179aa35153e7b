"""Held-out accuracy of a trained model: PSNR and SSIM on views it did not train on, as the paper reports."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

import kornia
import numpy as np
import torch

from nerfpipe.artifacts import view_file_stem
from nerfpipe.geometry.cameras import Frame
from nerfpipe.imaging.png import srgb_encode, write_png
from nerfpipe.nerf.images import ImageLoader
from nerfpipe.nerf.model import RadianceModel


def evaluate(model: RadianceModel, loader: ImageLoader, frames: list[Frame], folder: Path | None, chunk: int,
             advance: Callable[..., None] | None = None) -> dict[str, Any]:
    """Render each view of ``frames``; PSNR and SSIM (kornia.metrics, 11x11 Gaussian window) against its image,
    averaged over views as the paper does.

    With a ``folder``, writes ``<view>.render.png`` beside ``<view>.gt.png`` (sRGB-encoded when the model
    trained on linear RAW values). ``advance(1, info=...)`` is called after each view (a progress bar's).
    Returns ``psnr``, ``ssim`` (None without views), ``views`` (name, psnr, ssim each) and ``seconds``.
    """
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    linear = model.info.get("photometric") == "linear_raw"
    views = []
    for frame in frames:
        gt = loader.image(frame)
        camera = loader.world.camera_of(frame)
        near, far = loader.near_far[frame.name]
        out = model.render_image(loader.intrinsics(frame), frame.c2w, camera.width, camera.height, near, far, chunk)
        render = out["rgb"].clamp(0.0, 1.0)
        target = torch.from_numpy(gt)
        psnr = float(kornia.metrics.psnr(render, target, 1.0))
        ssim = float(kornia.metrics.ssim(render.permute(2, 0, 1)[None], target.permute(2, 0, 1)[None], 11).mean())
        if folder is not None:
            stem = view_file_stem(frame.name)
            for suffix, pixels in (("render", render.numpy()), ("gt", gt)):
                shown = srgb_encode(pixels) if linear else pixels
                write_png(folder / f"{stem}.{suffix}.png", np.round(np.clip(shown, 0, 1) * 255).astype(np.uint8))
        views.append({"name": frame.name, "psnr": round(psnr, 4), "ssim": round(ssim, 5)})
        if advance is not None:
            advance(1, info=f"{frame.name}: {psnr:.2f} dB")
    if not views:
        return {"psnr": None, "ssim": None, "views": [], "seconds": 0.0}
    return {
        "psnr": round(float(np.mean([v["psnr"] for v in views])), 4),
        "ssim": round(float(np.mean([v["ssim"] for v in views])), 5),
        "views": views,
        "seconds": round(time.perf_counter() - started, 2),
    }
