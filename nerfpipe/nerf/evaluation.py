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


def protocol(loader: ImageLoader) -> str:
    """What held-out renders are compared with, in a sentence (metrics.json's ``protocol``); the renders are
    composited onto the scene's background colour (``nerfpipe.nerf.assembly.build_background``)."""
    color = loader.scene.background_color.value
    shown = ", ".join(f"{c:.2f}" for c in color) if color is not None else ""
    if loader.use_alpha and shown:
        return f"renders composited onto ({shown}) against the photos composited onto it by their alpha"
    if loader.backdrop is not None:
        return (f"renders composited onto the backdrop colour ({shown}) against the photos composited onto it by "
                "their backdrop masks, as alpha captures are (psnr_photo: against the photos as taken)")
    return "renders against the original photos"


def _metrics(render: torch.Tensor, target: np.ndarray) -> tuple[float, float]:
    """PSNR and SSIM (11x11 Gaussian window) of render (H, W, 3) against target (H, W, 3), both in [0, 1]."""
    gt = torch.from_numpy(np.ascontiguousarray(target, dtype=np.float32))
    psnr = float(kornia.metrics.psnr(render, gt, 1.0))
    ssim = float(kornia.metrics.ssim(render.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None], 11).mean())
    return psnr, ssim


def evaluate(model: RadianceModel, loader: ImageLoader, frames: list[Frame], folder: Path | None, chunk: int,
             advance: Callable[..., None] | None = None) -> dict[str, Any]:
    """Render each view of ``frames``; PSNR and SSIM (kornia.metrics, 11x11 Gaussian window) against its image,
    averaged over views as the paper does. Against a constant backdrop the image is the photo composited onto
    the backdrop colour by its mask (``ImageLoader.foreground``), what the model is trained to render; each
    view's ``psnr_photo`` and the mean ``psnr_photo`` compare with the photo as taken.

    With a ``folder``, writes ``<view>.render.png`` beside ``<view>.gt.png`` (sRGB-encoded when the model
    trained on linear RAW values). ``advance(1, info=...)`` is called after each view (a progress bar's).
    Returns ``psnr``, ``ssim`` (None without views), ``views`` (name, psnr, ssim each), ``seconds`` and
    ``protocol``, what the renders were compared with (``protocol``); with backdrop masks also ``psnr_photo``.
    """
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    linear = model.info.get("photometric") == "linear_raw"
    views = []
    for frame in frames:
        photo = loader.image(frame)
        mask = loader.foreground(frame, photo)
        gt = photo if mask is None else np.where(mask[..., None], photo, loader.background)
        camera = loader.world.camera_of(frame)
        near, far = loader.near_far[frame.name]
        out = model.render_image(loader.intrinsics(frame), frame.c2w, camera.width, camera.height, near, far, chunk)
        render = out["rgb"].clamp(0.0, 1.0)
        psnr, ssim = _metrics(render, gt)
        view = {"name": frame.name, "psnr": round(psnr, 4), "ssim": round(ssim, 5)}
        if mask is not None:
            view["psnr_photo"] = round(_metrics(render, photo)[0], 4)
        if folder is not None:
            stem = view_file_stem(frame.name)
            for suffix, pixels in (("render", render.numpy()), ("gt", gt)):
                shown = srgb_encode(pixels) if linear else pixels
                write_png(folder / f"{stem}.{suffix}.png", np.round(np.clip(shown, 0, 1) * 255).astype(np.uint8))
        views.append(view)
        if advance is not None:
            advance(1, info=f"{frame.name}: {psnr:.2f} dB")
    if not views:
        return {"psnr": None, "ssim": None, "views": [], "seconds": 0.0, "protocol": protocol(loader)}
    result = {
        "psnr": round(float(np.mean([v["psnr"] for v in views])), 4),
        "ssim": round(float(np.mean([v["ssim"] for v in views])), 5),
        "views": views,
        "seconds": round(time.perf_counter() - started, 2),
        "protocol": protocol(loader),
    }
    if "psnr_photo" in views[0]:
        result["psnr_photo"] = round(float(np.mean([v["psnr_photo"] for v in views])), 4)
    return result
