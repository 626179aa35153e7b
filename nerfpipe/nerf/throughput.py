"""What rendering a trained model costs, timed before the work starts, and the size of that work that fits a
time allotment (held-out evaluation, depth export, the render stage, under a job's budget)."""

from __future__ import annotations

import time

import numpy as np
import torch

from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.rays import pixel_centers

PROBE_RAYS = 4096  # rays timed to predict what rendering whole views costs
WARM_UP_RAYS = 256


def seconds_per_ray(model: RadianceModel, intrinsics: tuple[float, float, float, float], c2w: np.ndarray,
                    width: int, height: int, near: float, far: float, chunk: int, rays: int = PROBE_RAYS) -> float:
    """Seconds ``model`` takes to render one ray of the pinhole view (``intrinsics`` fx, fy, cx, cy at
    ``width`` x ``height``, pose ``c2w``), timed on ``rays`` of its pixels spread evenly over the image, so
    empty space and surfaces weigh as they do in the whole view. A few of them are rendered first, untimed:
    the first call of a process pays for warming up what every later one reuses."""
    device = model.device
    uv = pixel_centers(width, height, device)
    uv = uv[torch.linspace(0, len(uv) - 1, min(rays, len(uv)), device=device).long()]
    n = len(uv)
    k = torch.tensor(intrinsics, dtype=torch.float32, device=device).expand(n, 4)
    pose = torch.as_tensor(np.asarray(c2w), dtype=torch.float32, device=device)
    batch = model.ray_space.rays(uv, k, pose, torch.full((n,), near, device=device), torch.full((n,), far, device=device))
    model.render_batch(batch.slice(0, WARM_UP_RAYS), chunk)
    started = time.perf_counter()
    model.render_batch(batch, chunk)
    return (time.perf_counter() - started) / max(n, 1)


def seconds_per_view(model: RadianceModel, intrinsics: tuple[float, float, float, float], c2w: np.ndarray,
                     width: int, height: int, near: float, far: float, chunk: int) -> float:
    """Seconds ``model`` takes to render the whole pinhole view (as ``seconds_per_ray`` takes its arguments),
    timed on that view after a short warm-up. Dearer than ``seconds_per_ray`` by the view's size, and closer:
    a chunk of neighbouring pixels marches alike, where a probe of pixels spread over the view pays for the
    ray with the most samples in each chunk."""
    seconds_per_ray(model, intrinsics, c2w, width, height, near, far, chunk, rays=WARM_UP_RAYS)
    started = time.perf_counter()
    model.render_image(intrinsics, c2w, width, height, near, far, chunk)
    return time.perf_counter() - started


def fitting_scale(per_ray: float, pixels: float, seconds: float, floor: float, ceiling: float = 1.0) -> float:
    """The largest scale s in [floor, ceiling] of every side of ``pixels`` worth of views whose cost,
    ``per_ray * pixels * s**2``, is at most ``seconds``; rounded down to hundredths where that stays above
    ``floor``."""
    scale = min(ceiling, float(np.sqrt(max(seconds, 0.0) / max(per_ray * pixels, 1e-12))))
    rounded = np.floor(scale * 100.0) / 100.0
    return float(max(floor, rounded if rounded > 0 else scale))
