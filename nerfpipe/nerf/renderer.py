"""Rendering a batch of rays with a coarse and a fine field: the hierarchical procedure of Section 5.2."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor

from nerfpipe.nerf.rendering import Composite, composite
from nerfpipe.nerf.sampling import sample_intervals, sample_pdf, stratified_samples

# (points (M, 3), unit view directions (M, 3)) -> (rgb (M, 3), sigma (M,))
FieldFn = Callable[[Tensor, Tensor], tuple[Tensor, Tensor]]


@dataclass(frozen=True)
class SamplingConfig:
    """N_c stratified samples, N_f more from the coarse weights (0: no hierarchical sampling)."""

    n_coarse: int = 64
    n_fine: int = 128
    lindisp: bool = False


@dataclass
class RayBatch:
    """Rays to render. origins, directions: (R, 3) in the space the field is queried in (world, or NDC for
    forward-facing scenes); viewdirs: (R, 3) unit world directions fed to the field; near, far: (R,)."""

    origins: Tensor
    directions: Tensor
    viewdirs: Tensor
    near: Tensor
    far: Tensor

    def __len__(self) -> int:
        return self.origins.shape[0]

    def slice(self, start: int, stop: int) -> "RayBatch":
        return RayBatch(*(getattr(self, k)[start:stop] for k in ("origins", "directions", "viewdirs", "near", "far")))

    def to(self, device: torch.device | str) -> "RayBatch":
        return RayBatch(*(getattr(self, k).to(device) for k in ("origins", "directions", "viewdirs", "near", "far")))


def evaluate(field: FieldFn, rays: RayBatch, t: Tensor) -> tuple[Tensor, Tensor]:
    """The field at r(t) = o + t d for every sample.

    Args:
        t: (R, N).
    Returns:
        rgb: (R, N, 3); sigma: (R, N).
    """
    n_rays, n_samples = t.shape
    points = rays.origins.unsqueeze(-2) + t.unsqueeze(-1) * rays.directions.unsqueeze(-2)
    viewdirs = rays.viewdirs.unsqueeze(-2).expand(n_rays, n_samples, 3)
    rgb, sigma = field(points.reshape(-1, 3), viewdirs.reshape(-1, 3))
    return rgb.reshape(n_rays, n_samples, 3), sigma.reshape(n_rays, n_samples)


def render_rays(
    coarse: FieldFn,
    fine: FieldFn | None,
    rays: RayBatch,
    sampling: SamplingConfig,
    background: Tensor | None = None,
    randomized: bool = True,
    generator: torch.Generator | None = None,
) -> dict[str, Composite]:
    """Render rays: N_c stratified samples through ``coarse`` (Eq. 2, 3); then, when N_f > 0, N_f samples
    drawn from the coarse weights (Eq. 5), and ``fine`` (or ``coarse`` again when ``fine`` is None)
    evaluated at the union of both sets, N_c + N_f samples, composited with Eq. 3.

    ``randomized`` draws stratified and inverse-transform samples at random (training); otherwise both
    are deterministic (evaluation).

    Returns:
        {"coarse": Composite} and, with hierarchical sampling, {"fine": Composite}; per-ray tensors (R, ...).
    """
    t_coarse = stratified_samples(rays.near, rays.far, sampling.n_coarse, randomized, sampling.lindisp, generator)
    rgb, sigma = evaluate(coarse, rays, t_coarse)
    out = {"coarse": composite(sigma, rgb, t_coarse, rays.far, background)}
    if sampling.n_fine > 0:
        edges = sample_intervals(t_coarse, rays.near, rays.far)
        weights = out["coarse"].weights.detach()
        t_new = sample_pdf(edges.detach(), weights, sampling.n_fine, not randomized, generator).detach()
        t_all = torch.sort(torch.cat([t_coarse, t_new], dim=-1), dim=-1).values
        rgb, sigma = evaluate(fine if fine is not None else coarse, rays, t_all)
        out["fine"] = composite(sigma, rgb, t_all, rays.far, background)
    return out


def render_chunked(
    coarse: FieldFn,
    fine: FieldFn | None,
    rays: RayBatch,
    sampling: SamplingConfig,
    background: Tensor | None = None,
    chunk: int = 4096,
) -> dict[str, Tensor]:
    """Deterministic rendering of many rays, ``chunk`` at a time, without gradients.

    Returns:
        rgb (R, 3), depth (R,), disparity (R,), acc (R,) of the final (fine, else coarse) composite.
    """
    parts: dict[str, list[Tensor]] = {"rgb": [], "depth": [], "disparity": [], "acc": []}
    with torch.no_grad():
        for start in range(0, len(rays), chunk):
            result = render_rays(coarse, fine, rays.slice(start, start + chunk), sampling, background, randomized=False)
            final = result.get("fine", result["coarse"])
            for key in parts:
                parts[key].append(getattr(final, key))
    return {key: torch.cat(values) if values else torch.zeros(0) for key, values in parts.items()}
