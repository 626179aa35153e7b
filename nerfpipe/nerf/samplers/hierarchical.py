"""Section 5.2's sampling: N_c stratified samples rendered through the coarse field, N_f more drawn from its
weights (Eq. 5) for the fine one; the coarse rendering is also fitted (Eq. 6)."""

from __future__ import annotations

from typing import Any

import torch

from nerfpipe.nerf.render.volume import RaySamples, RenderOutput
from nerfpipe.nerf.samplers.base import Box, Probe, StatelessSampler
from nerfpipe.nerf.samplers.configs import HierarchicalConfig
from nerfpipe.nerf.samplers.sampling import sample_intervals, sample_pdf, stratified_samples
from nerfpipe.nerf.spaces.rays import RayBatch


class HierarchicalSampler(StatelessSampler):
    """Section 5.2: N_c stratified samples, then N_f from the coarse weights (``config.fine`` > 0)."""

    adaptive = False

    def __init__(self, config: HierarchicalConfig) -> None:
        self.config = config

    @classmethod
    def from_config(cls, config: HierarchicalConfig, box: Box | None = None) -> "HierarchicalSampler":
        """Section 5.2's sampling needs no box."""
        return cls(config)

    def candidates_per_ray(self) -> int:
        c = self.config
        return c.n_coarse + (c.n_coarse + c.fine if c.fine > 0 else 0)

    def sample(self, rays: RayBatch, space: Any, probe: Probe, *, train: bool, generator: torch.Generator | None,
               max_samples: int = 0) -> tuple[RaySamples, int, tuple[RenderOutput, ...]]:
        """N_c stratified samples (Eq. 2); with N_f > 0 they are rendered through the coarse field and N_f
        more drawn from its weights (Eq. 5), the fine field evaluated at the union, N_c + N_f samples.
        Randomized when ``train``, deterministic otherwise. The cost a ray is fixed: ``max_samples`` is not read.

        Each sample stands for the stretch of ray closer to it than to its neighbours (``sample_intervals``:
        from near, through the midpoints, to far), the bins Eq. 5's PDF is drawn from. Eq. 3's
        delta_i = t_{i+1} - t_i tiles the same stretch shifted by half a sample; centring the stretches on
        the samples makes the weights of the bins the PDF draws from those of the same bins, and puts a
        ray's stopping depth within half a spacing of a surface rather than up to a whole one behind it."""
        c = self.config
        t = stratified_samples(rays.near, rays.far, c.n_coarse, train, c.lindisp == "on", generator)
        edges = sample_intervals(t, rays.near, rays.far)
        samples = RaySamples.dense(t, edges[:, :-1], edges[:, 1:])
        if c.fine <= 0:
            return samples, 0, ()
        coarse = probe.render(samples, 0)
        weights = coarse.weights.detach().reshape(len(rays), c.n_coarse)
        extra = sample_pdf(edges.detach(), weights, c.fine, not train, generator).detach()
        t_all = torch.sort(torch.cat([t, extra], dim=-1), dim=-1).values
        edges = sample_intervals(t_all, rays.near, rays.far)
        return RaySamples.dense(t_all, edges[:, :-1], edges[:, 1:]), 1, (coarse,)
