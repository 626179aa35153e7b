"""Samplers: where along each ray a model evaluates its field (nerfacc's split of sampling from rendering).

A sampler's one job is ``sample(rays, ...) -> RaySamples``: packed samples, each with its ray and the stretch
of ray it stands for; ``nerfpipe.nerf.render.volume.volume_render`` composites them and ``RadianceModel.render``
is the one place that does. ``update(step, density, generator)`` keeps what a sampler learns from the field
(an occupancy grid) up to date while training. Two are registered (``nerfpipe.nerf.registry.SAMPLERS``):

- ``HierarchicalSampler`` (``nerfpipe.nerf.samplers.hierarchical``): Section 5.2, N_c stratified samples rendered through the coarse field, N_f more
  drawn from its weights (Eq. 5) for the fine one; the coarse rendering is also fitted (Eq. 6).
- ``MarchingSampler`` (``nerfpipe.nerf.samplers.marching``): Instant-NGP's empty-space skipping, marching an occupancy grid that training keeps
  up to date (``nerfpipe.nerf.samplers.occupancy``, ``nerfpipe.nerf.samplers.march``); the coarse field only.

A new sampler is a class with these methods, its config (``nerfpipe.nerf.samplers.configs.SamplerConfig``,
whose ``target`` is the class) and a line in the registry.
"""

from __future__ import annotations

from typing import Any, ClassVar, Protocol

import torch
from torch import Tensor

from nerfpipe.nerf.render.volume import RaySamples, RenderOutput
from nerfpipe.nerf.samplers.march import DensityFn
from nerfpipe.nerf.spaces.rays import RayBatch

Box = tuple[tuple[float, ...], tuple[float, ...]]


class Probe(Protocol):
    """What a sampler may ask of the model while it samples (``RadianceModel.render`` hands one over)."""

    def density_features(self, ray: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
        """Densities (M,) of the first field at samples (M,) of the rays being sampled, given by ray index and t, and
        its features there (``Field.density_features``), without gradients."""

    def render(self, samples: RaySamples, level: int) -> RenderOutput:
        """``samples`` rendered through field ``level`` (0: coarse, 1: fine), with gradients while training."""

    def reached(self, samples: RaySamples, early_stop: float) -> Tensor | None:
        """Which of ``samples`` each ray reaches before its transmittance falls below ``early_stop``, a mask (N,), where
        the model can say so natively (``nerfpipe.nerf.fused``); None: the sampler finds out from ``density_features``."""


class Sampler(Protocol):
    """Where a model samples its rays."""

    adaptive: ClassVar[bool]  # whether its samples per ray vary, so the trainer adapts its rays per batch

    def sample(self, rays: RayBatch, space: Any, probe: Probe, *, train: bool, generator: torch.Generator | None,
               max_samples: int = 0) -> tuple[RaySamples, int, tuple[RenderOutput, ...]]:
        """Samples of ``rays`` (in ``space``'s ray coordinates), randomized when ``train``; with
        ``max_samples`` > 0 those of the leading rays only, within about that many. Returns the samples,
        the field level to evaluate them with, and the renderings made on the way (``Probe.render``)."""

    def update(self, step: int, density: DensityFn, generator: torch.Generator) -> None:
        """What the sampler keeps up to date with the field, before training step ``step``."""

    def start(self, space: Any, intrinsics: Tensor, c2w: Tensor, least_depth: Tensor | None = None) -> None:
        """Before training: the ray space, the training cameras (intrinsics (I, 4), c2w (I, 4, 4)), and the least
        depths of the sparse points each sees over a grid of cells of its image ((I, rows, columns), inf where none:
        ``nerfpipe.geometry.freespace.frame_least_depths``; None: no points)."""

    def reset(self) -> None:
        """Back to the state training starts from."""

    def stats(self) -> dict[str, float]:
        """Figures for the training log (an occupancy grid's occupied share)."""

    def candidates_per_ray(self) -> int:
        """The most samples it lays out along one ray at once (before any are culled): what a call's memory
        grows with, so that callers bound the rays they hand it (``RadianceModel.render``)."""

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: dict[str, Any]) -> Any: ...

    def to(self, device: torch.device | str) -> Any: ...

    config: Any  # its ``nerfpipe.nerf.samplers.configs.SamplerConfig``: the user's settings, and its spec

    @classmethod
    def from_config(cls, config: Any, box: Box | None) -> "Sampler":
        """Built from its config over the field ``box`` (None: unbounded), training state fresh."""


class StatelessSampler:
    """What a sampler that keeps nothing beside the fields does between renders: nothing. A sampler with no
    training state of its own (``HierarchicalSampler``) takes these rather than writing them out again."""

    def update(self, step: int, density: DensityFn, generator: torch.Generator) -> None:
        pass

    def start(self, space: Any, intrinsics: Tensor, c2w: Tensor, least_depth: Tensor | None = None) -> None:
        pass

    def reset(self) -> None:
        pass

    def stats(self) -> dict[str, float]:
        return {}

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        pass

    def to(self, device: torch.device | str) -> "StatelessSampler":
        return self


