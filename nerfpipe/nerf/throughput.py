"""What rendering a trained model costs, timed before the work starts (held-out evaluation, depth export, the
render stage), for sizing that work to a job's budget (``nerfpipe.pipeline.budget.fit_to_allotment``)."""

from __future__ import annotations

import time

import numpy as np
import torch

from nerfpipe.nerf.device import synchronize
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.spaces.rays import RayBatch, pixel_centers

PROBE_RAYS = 4096  # rays timed to predict what rendering whole views costs
WARM_UP_RAYS = 256
VIEW_RAYS = 1 << 18  # a larger view is timed at a smaller size with the same field of view (a 4K frame: 8.3 M rays)


def _probe(model: RadianceModel, intrinsics: tuple[float, float, float, float], c2w: np.ndarray, width: int,
           height: int, near: float, far: float, rays: int) -> RayBatch:
    """The rays of ``rays`` pixels of the pinhole view, spread evenly over it."""
    device = model.device
    uv = pixel_centers(width, height, device)
    n = min(rays, len(uv))  # evenly spaced, in integers: float32 steps past 2^24 pixels round beyond the last
    uv = uv[torch.arange(n, device=device) * (len(uv) - 1) // max(n - 1, 1)]
    n = len(uv)
    k = torch.tensor(intrinsics, dtype=torch.float32, device=device).expand(n, 4)
    pose = torch.as_tensor(np.asarray(c2w), dtype=torch.float32, device=device)
    return model.ray_space.rays(uv, k, pose, torch.full((n,), near, device=device), torch.full((n,), far, device=device))


def seconds_per_ray(model: RadianceModel, intrinsics: tuple[float, float, float, float], c2w: np.ndarray,
                    width: int, height: int, near: float, far: float, chunk: int, rays: int = PROBE_RAYS) -> float:
    """Seconds ``model`` takes to render one ray of the pinhole view (``intrinsics`` fx, fy, cx, cy at
    ``width`` x ``height``, pose ``c2w``), timed on ``rays`` of its pixels spread evenly over the image, so
    empty space and surfaces weigh as they do in the whole view, and on at least one ``chunk`` of them: a
    chunk's fixed cost (on a GPU, launching its kernels: 4096 rays cost about what 32768 do) is paid per
    chunk by the whole view, and a probe smaller than a chunk would charge it to fewer rays (on an H200,
    a predicted 79 s for 9 beer views at 720x1280 that took 8 s). A few of them are rendered first,
    untimed: the first call of a process pays for warming up what every later one reuses."""
    batch = _probe(model, intrinsics, c2w, width, height, near, far, max(rays, chunk))
    model.render_rays(batch.slice(0, WARM_UP_RAYS), chunk)
    synchronize(model.device)
    started = time.perf_counter()
    model.render_rays(batch, chunk)
    synchronize(model.device)
    return (time.perf_counter() - started) / max(len(batch), 1)


def seconds_per_view(model: RadianceModel, intrinsics: tuple[float, float, float, float], c2w: np.ndarray,
                     width: int, height: int, near: float, far: float, chunk: int) -> float:
    """Seconds ``model`` takes to render the whole pinhole view (as ``seconds_per_ray`` takes its arguments),
    timed on that view after a short warm-up (a view of more than ``VIEW_RAYS`` pixels on the same view at
    that many, its time scaled by the pixels). Dearer than ``seconds_per_ray`` by the view's size, and closer:
    a chunk of neighbouring pixels marches alike, where a probe of pixels spread over the view pays for the
    ray with the most samples in each chunk."""
    return timed_view(model, intrinsics, c2w, width, height, near, far, chunk)[0]


def timed_view(model: RadianceModel, intrinsics: tuple[float, float, float, float], c2w: np.ndarray, width: int,
               height: int, near: float, far: float, chunk: int) -> tuple[float, dict[str, torch.Tensor] | None]:
    """``seconds_per_view``'s seconds, and the view it rendered (``RadianceModel.render_image``'s maps) where it
    rendered the whole view at its size, else None: a stage that renders that view anyway keeps it rather than
    render it twice."""
    model.render_rays(_probe(model, intrinsics, c2w, width, height, near, far, WARM_UP_RAYS), chunk)
    synchronize(model.device)
    shrink = min(1.0, (VIEW_RAYS / max(width * height, 1)) ** 0.5)  # timing a huge view would cost what it predicts
    small = (max(1, round(width * shrink)), max(1, round(height * shrink)))
    sx, sy = small[0] / width, small[1] / height
    started = time.perf_counter()
    rendered = model.render_image((intrinsics[0] * sx, intrinsics[1] * sy, intrinsics[2] * sx, intrinsics[3] * sy),
                                  c2w, *small, near, far, chunk)
    seconds = (time.perf_counter() - started) * (width * height) / (small[0] * small[1])
    return seconds, rendered if small == (width, height) else None
