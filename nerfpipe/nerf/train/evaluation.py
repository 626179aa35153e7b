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
from nerfpipe.nerf.appearance import apply_gains, fit_gains
from nerfpipe.nerf.train.images import ImageLoader
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.throughput import seconds_per_ray

APPEARANCE_PROTOCOL = ("each held-out photo's exposure and white balance (3 gains) fitted on its left half, PSNR and "
                       "SSIM on its right half, as NeRF-W does (psnr_mean_appearance: the whole view at the training "
                       "photos' mean exposure)")


def protocol(loader: ImageLoader, appearance: bool = False) -> str:
    """What held-out renders are compared with, in a sentence (metrics.json's ``protocol``); the renders are
    composited onto the scene's background colour (``nerfpipe.nerf.policy.build_background``). With
    ``appearance`` (a model that learned each photo's exposure), how a held-out photo's exposure is found."""
    color = loader.scene.background_color.value
    shown = ", ".join(f"{c:.2f}" for c in color) if color is not None else ""
    if loader.use_alpha and shown:
        said = f"renders composited onto ({shown}) against the photos composited onto it by their alpha"
    elif loader.backdrop is not None:
        said = (f"renders composited onto the backdrop colour ({shown}) against the photos composited onto it by "
                "their backdrop masks, as alpha captures are (psnr_photo: against the photos as taken)")
    else:
        said = "renders against the original photos"
    return f"{said}; {APPEARANCE_PROTOCOL}" if appearance else said


def fit_left_score_right(render: torch.Tensor, acc: torch.Tensor, background: torch.Tensor | None, gt: np.ndarray,
                         linear: bool) -> tuple[torch.Tensor, slice]:
    """A held-out view's render (H, W, 3), composited with opacity ``acc`` (H, W) onto ``background`` (3,)
    or None, under the exposure and white balance fitted on the left half of its photo ``gt``
    (``nerfpipe.nerf.appearance.fit_gains``; the background, a stand-in colour, is not exposed, as in
    training), and the columns to score it on: the right half."""
    over = torch.zeros(3) if background is None else background.cpu().float()
    behind = (1.0 - acc).clamp_min(0.0).unsqueeze(-1) * over  # (H, W, 3)
    light = render - behind
    half = render.shape[1] // 2
    target = torch.from_numpy(np.ascontiguousarray(gt[:, :half], dtype=np.float32)) - behind[:, :half]
    gains = fit_gains(light[:, :half].reshape(-1, 3), target.reshape(-1, 3), linear)
    exposed = apply_gains(light.reshape(-1, 3), gains, linear).reshape(render.shape) + behind
    return exposed.clamp(0.0, 1.0), slice(half, None)


def _metrics(render: torch.Tensor, target: np.ndarray) -> tuple[float, float]:
    """PSNR and SSIM (11x11 Gaussian window, smaller for views under 11 pixels a side) of render (H, W, 3)
    against target (H, W, 3), both in [0, 1]."""
    gt = torch.from_numpy(np.ascontiguousarray(target, dtype=np.float32))
    psnr = float(kornia.metrics.psnr(render, gt, 1.0))
    side = min(render.shape[0], render.shape[1])
    window = max(1, min(11, side if side % 2 else side - 1))
    ssim = float(kornia.metrics.ssim(render.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None], window).mean())
    return psnr, ssim


AUTO_EVAL_SCALE = 0.5  # held-out views are scored at half their side: where blur shows, the same for every run


def evaluation_scale(setting: str, model: RadianceModel, loader: ImageLoader, frames: list[Frame],
                     chunk: int) -> tuple[float, float]:
    """The scale held-out views are rendered and scored at, and the seconds that is predicted to take
    (``seconds_per_ray`` on the first view, times the views' pixels, times scale squared).

    ``setting``: a number in (0, 1], or "auto": ``AUTO_EVAL_SCALE``, whatever the time, so that every run of a
    capture is scored at the same size and their scores compare (a score at a size where blur does not show
    says nothing: scored at 56x100, phone photos read 25.2 dB where at 225x400 they read 23.4).
    """
    if not frames:
        return 1.0, 0.0
    pixels = sum(loader.world.camera_of(f).width * loader.world.camera_of(f).height for f in frames)
    first, camera = frames[0], loader.world.camera_of(frames[0])
    per_ray = seconds_per_ray(model, loader.intrinsics(first), first.c2w, camera.width, camera.height,
                              *loader.near_far[first.name], chunk)
    scale = evaluated_scale(setting)
    return scale, per_ray * pixels * scale**2


def evaluated_scale(setting: str) -> float:
    """The scale ``train.eval_scale`` scores the held-out views at: a number in (0, 1], or "auto" (``AUTO_EVAL_SCALE``)."""
    return AUTO_EVAL_SCALE if setting == "auto" else float(setting)


def scaled_size(width: int, height: int, scale: float) -> tuple[int, int]:
    return max(1, round(width * scale)), max(1, round(height * scale))


def _resized(pixels: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """An image (H, W, C) or mask (H, W) at ``size`` (width, height), by area averaging; masks stay boolean."""
    import cv2

    if pixels.shape[1] == size[0] and pixels.shape[0] == size[1]:
        return pixels
    if pixels.dtype == bool:
        return cv2.resize(pixels.astype(np.float32), size, interpolation=cv2.INTER_AREA) >= 0.5
    return cv2.resize(np.ascontiguousarray(pixels, dtype=np.float32), size, interpolation=cv2.INTER_AREA)


def evaluate(model: RadianceModel, loader: ImageLoader, frames: list[Frame], folder: Path | None, chunk: int,
             advance: Callable[..., None] | None = None, fit_appearance: bool | None = None,
             scale: float = 1.0) -> dict[str, Any]:
    """Render each view of ``frames``; PSNR and SSIM (kornia.metrics, 11x11 Gaussian window) against its image,
    averaged over views as the paper does. Against a constant backdrop the image is the photo composited onto
    the backdrop colour by its mask (``ImageLoader.foreground``), what the model is trained to render; each
    view's ``psnr_photo`` and the mean ``psnr_photo`` compare with the photo as taken. A model that learned each
    training photo's exposure (``model.appearance``) is scored as NeRF-W is (``fit_left_score_right``), with
    ``psnr_mean_appearance`` beside; ``fit_appearance`` scores any model so (True) or none (False).

    With a ``folder``, writes ``<view>.render.png`` beside ``<view>.gt.png`` (and ``<view>.photo.png``, the photo
    as taken, where a backdrop mask made the ground truth; sRGB-encoded when the model
    trained on linear RAW values). ``advance(1, info=...)`` is called after each view (a progress bar's).
    ``scale`` < 1 renders each view at that share of its width and height (the intrinsics scaled alike) and
    scores it against its image averaged down to that size.

    Returns ``psnr``, ``ssim`` (None without views), ``views`` (name, psnr, ssim, size each), ``seconds``,
    ``scale`` and ``protocol``, what the renders were compared with; with backdrop masks also ``psnr_photo``.
    """
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    linear = model.info.get("photometric") == "linear_raw"
    views = []
    fitted = model.appearance is not None if fit_appearance is None else fit_appearance
    for frame in frames:
        photo = loader.image(frame)
        mask = loader.foreground(frame, photo)
        gt = photo if mask is None else np.where(mask[..., None], photo, loader.background)
        camera = loader.world.camera_of(frame)
        size = scaled_size(camera.width, camera.height, scale)
        sx, sy = size[0] / camera.width, size[1] / camera.height
        fx, fy, cx, cy = loader.intrinsics(frame)
        photo, gt = _resized(photo, size), _resized(gt, size)
        near, far = loader.near_far[frame.name]
        out = model.render_image((fx * sx, fy * sy, cx * sx, cy * sy), frame.c2w, size[0], size[1], near, far, chunk)
        render = out["rgb"].clamp(0.0, 1.0)
        view = {"name": frame.name, "size": list(size)}
        scored = slice(None)
        if fitted:
            view["psnr_mean_appearance"] = round(_metrics(render, gt)[0], 4)
            render, scored = fit_left_score_right(render, out["acc"], model.background_tensor(), gt, linear)
        psnr, ssim = _metrics(render[:, scored], gt[:, scored])
        view.update(psnr=round(psnr, 4), ssim=round(ssim, 5))
        if mask is not None:
            view["psnr_photo"] = round(_metrics(render[:, scored], photo[:, scored])[0], 4)
        if folder is not None:
            stem = view_file_stem(frame.name)
            shown_too = () if mask is None else (("photo", photo),)  # the photo as taken, beside the masked one
            for suffix, pixels in (("render", render.numpy()), ("gt", gt), *shown_too):
                shown = srgb_encode(pixels) if linear else pixels
                write_png(folder / f"{stem}.{suffix}.png", np.round(np.clip(shown, 0, 1) * 255).astype(np.uint8))
        views.append(view)
        if advance is not None:
            advance(1, info=f"{frame.name}: {psnr:.2f} dB")
    if not views:
        return {"psnr": None, "ssim": None, "views": [], "seconds": 0.0, "scale": scale,
                "protocol": protocol(loader, fitted)}
    result = {
        "psnr": round(float(np.mean([v["psnr"] for v in views])), 4),
        "ssim": round(float(np.mean([v["ssim"] for v in views])), 5),
        "views": views,
        "seconds": round(time.perf_counter() - started, 2),
        "scale": scale,
        "protocol": protocol(loader, fitted),
    }
    for key in ("psnr_photo", "psnr_mean_appearance"):
        if key in views[0]:
            result[key] = round(float(np.mean([v[key] for v in views])), 4)
    return result
