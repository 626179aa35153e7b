"""Samplers: where along each ray a model evaluates its field, and how those samples are composited.

A sampler answers one question for the model and the trainer, whatever it is: render these rays. The
model (``nerfpipe.nerf.model.RadianceModel``) and the trainer never ask which kind it is. Two are
registered (``nerfpipe.nerf.registry.SAMPLERS``):

- ``HierarchicalSampler``: Section 5.2, N_c stratified samples through the coarse field, N_f more drawn
  from its weights (Eq. 5) through the fine one (``nerfpipe.nerf.renderer``).
- ``MarchingSampler``: Instant-NGP's empty-space skipping, marching an occupancy grid that training keeps
  up to date (``nerfpipe.nerf.occupancy``, ``nerfpipe.nerf.marching``); the coarse field only.

A new sampler is a class with these methods and a line in the registry.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any, Callable, ClassVar, Protocol

import torch
from torch import Tensor

from nerfpipe.nerf.contraction import Contraction
from nerfpipe.nerf.marching import render_marched, render_marched_segments
from nerfpipe.nerf.occupancy import MarchingConfig, OccupancyGrid, cells_seen
from nerfpipe.nerf.renderer import FieldFn, RayBatch, SamplingConfig, render_rays
from nerfpipe.nerf.rendering import Composite

DensityFn = Callable[[Tensor], Tensor]
Box = tuple[tuple[float, ...], tuple[float, ...]]


class Sampler(Protocol):
    """Where a model samples its rays. ``coarse`` / ``fine`` are world-space fields (``FieldFn``)."""

    kind: ClassVar[str]
    fields: ClassVar[int]  # fields it evaluates: 1 (coarse), or 2 (coarse, then fine)
    adaptive: ClassVar[bool]  # whether its samples per ray vary, so the trainer adapts its rays per batch

    def render_train(self, coarse: FieldFn, fine: FieldFn | None, density: DensityFn, rays: RayBatch,
                     generator: torch.Generator, max_samples: int) -> tuple[dict[str, Composite], int]:
        """Randomized, with gradients: {name: Composite} for each rendering in the loss (Eq. 6), and the
        field evaluations spent. Each Composite may cover only the leading rays, within ``max_samples``."""

    def render(self, coarse: FieldFn, fine: FieldFn | None, rays: RayBatch, background: Tensor | None,
               ) -> tuple[dict[str, Tensor], int]:
        """Deterministic, without gradients: rgb (R, 3), depth, disparity, acc (R,), and the evaluations."""

    def before_step(self, step: int, density: DensityFn, generator: torch.Generator) -> None:
        """What the sampler keeps up to date with the field, before each training step."""

    def start(self, to_world: Callable[[Tensor], Tensor] | None, intrinsics: Tensor, c2w: Tensor) -> None:
        """Before training: the training cameras (``to_world``: field to world points; None: keep all)."""

    def reset(self) -> None:
        """Back to the state training starts from."""

    def occupied_share(self) -> float | None:
        """The share of its grid that is occupied, for a sampler that skips empty space; else None."""

    def candidates_per_ray(self) -> int:
        """The most samples it lays out along one ray at once (before any are culled): what a call's memory
        grows with, so that callers bound the rays they hand it (``RadianceModel.render_batch``)."""

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: dict[str, Any]) -> Any: ...

    def to(self, device: torch.device | str) -> Any: ...

    @staticmethod
    def spec_of(params: Any, box: Box | None, lindisp: bool) -> dict[str, Any]:
        """The spec ``nerfpipe.nerf.config.SamplerParams`` asks for."""

    @classmethod
    def from_spec(cls, spec: dict[str, Any], contraction: Contraction | None = None) -> "Sampler":
        """Built from a spec (model.json), training state fresh."""

    def spec(self) -> dict[str, Any]:
        """What ``from_spec`` rebuilds it from (stored in model.json)."""

    @staticmethod
    def describe(spec: dict[str, Any]) -> str | None:
        """A sentence for the train log about the sampler ``spec`` describes, or None for the paper's own."""


class StatelessSampler:
    """What a sampler that keeps nothing beside the fields does between renders: nothing. A sampler with no
    training state of its own (``HierarchicalSampler``) takes these rather than writing them out again."""

    def before_step(self, step: int, density: DensityFn, generator: torch.Generator) -> None:
        pass

    def start(self, to_world: Callable[[Tensor], Tensor] | None, intrinsics: Tensor, c2w: Tensor) -> None:
        pass

    def reset(self) -> None:
        pass

    def occupied_share(self) -> float | None:
        return None

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        pass

    def to(self, device: torch.device | str) -> "StatelessSampler":
        return self


class HierarchicalSampler(StatelessSampler):
    """Section 5.2: N_c stratified samples, then N_f from the coarse weights (``config.n_fine`` > 0)."""

    kind = "hierarchical"
    fields = 2
    adaptive = False

    def __init__(self, config: SamplingConfig) -> None:
        self.config = config

    @staticmethod
    def spec_of(params: Any, box: Box | None, lindisp: bool) -> dict[str, Any]:
        """The spec ``nerfpipe.nerf.config.SamplerParams`` asks for."""
        return {"sampling": asdict(SamplingConfig(params.n_coarse, params.n_fine if params.hierarchical else 0, lindisp))}

    @classmethod
    def from_spec(cls, spec: dict[str, Any], contraction: Contraction | None = None) -> "HierarchicalSampler":
        return cls(SamplingConfig(**spec["sampling"]))

    def spec(self) -> dict[str, Any]:
        return {"sampling": asdict(self.config)}

    @staticmethod
    def describe(spec: dict[str, Any]) -> None:
        """The paper's sampling needs no sentence in the train log."""
        return None

    def samples_per_ray(self) -> int:
        c = self.config
        return c.n_coarse + (c.n_coarse + c.n_fine if c.n_fine > 0 else 0)

    def candidates_per_ray(self) -> int:
        return self.samples_per_ray()

    def render_train(self, coarse: FieldFn, fine: FieldFn | None, density: DensityFn, rays: RayBatch,
                     generator: torch.Generator, max_samples: int) -> tuple[dict[str, Composite], int]:
        out = render_rays(coarse, fine, rays, self.config, None, randomized=True, generator=generator)
        return out, len(rays) * self.samples_per_ray()

    @torch.no_grad()
    def render(self, coarse: FieldFn, fine: FieldFn | None, rays: RayBatch, background: Tensor | None,
               ) -> tuple[dict[str, Tensor], int]:
        result = render_rays(coarse, fine, rays, self.config, background, randomized=False)
        final = result.get("fine", result["coarse"])
        return {key: getattr(final, key) for key in ("rgb", "depth", "disparity", "acc")}, \
            len(rays) * self.samples_per_ray()


class MarchingSampler:
    """Empty-space skipping (Instant-NGP): rays march the occupied cells of ``grid`` with ``config``'s steps,
    stopping at transmittance ``config.early_stop``; training refreshes the grid from the field's density."""

    kind = "marching"
    fields = 1
    adaptive = True

    def __init__(self, grid: OccupancyGrid, config: MarchingConfig, contraction: Contraction | None = None) -> None:
        self.grid, self.config, self.contraction = grid, config, contraction

    @staticmethod
    def spec_of(params: Any, box: Box | None, lindisp: bool) -> dict[str, Any]:
        """The spec ``nerfpipe.nerf.config.SamplerParams`` asks for: a grid over ``box`` (needs one)."""
        config = MarchingConfig(steps=params.steps, threshold=params.occupancy_threshold, early_stop=params.early_stop)
        return {"occupancy": {"resolution": params.occupancy_resolution, "box": [list(box[0]), list(box[1])],
                              "marching": asdict(config)}}

    @classmethod
    def from_spec(cls, spec: dict[str, Any], contraction: Contraction | None = None) -> "MarchingSampler":
        occ = spec["occupancy"]
        grid = OccupancyGrid(tuple(occ["box"][0]), tuple(occ["box"][1]), occ["resolution"])
        return cls(grid, MarchingConfig(**occ["marching"]), contraction)

    def spec(self) -> dict[str, Any]:
        grid = self.grid
        return {"occupancy": {"resolution": grid.resolution, "box": [grid.lo.tolist(), grid.hi.tolist()],
                              "marching": asdict(self.config)}}

    @staticmethod
    def describe(spec: dict[str, Any]) -> str:
        occ = spec["occupancy"]
        return (f"empty-space skipping: a {occ['resolution']}^3 occupancy grid over the field box, "
                f"{occ['marching']['steps']} marching steps along its diagonal, rays stop at transmittance "
                f"{occ['marching']['early_stop']:g} (instead of N_c + N_f samples per ray)")

    def render_train(self, coarse: FieldFn, fine: FieldFn | None, density: DensityFn, rays: RayBatch,
                     generator: torch.Generator, max_samples: int) -> tuple[dict[str, Composite], int]:
        final, samples = render_marched(coarse, density, rays.origins, rays.directions, rays.viewdirs, rays.near,
                                        rays.far, self.grid, self.config, None, True, generator,
                                        max_samples=max_samples, contraction=self.contraction)
        return {"coarse": final}, samples

    def render(self, coarse: FieldFn, fine: FieldFn | None, rays: RayBatch, background: Tensor | None,
               ) -> tuple[dict[str, Tensor], int]:
        return render_marched_segments(coarse, rays.origins, rays.directions, rays.viewdirs, rays.near, rays.far,
                                       self.grid, self.config, background, contraction=self.contraction)

    def before_step(self, step: int, density: DensityFn, generator: torch.Generator) -> None:
        """Refresh the grid from the field's density every ``update_every`` steps."""
        if step % self.config.update_every:
            return
        self.grid.update(density, self.grid.diagonal / self.config.steps, self.config.threshold,
                         step < self.config.warmup, generator)

    def start(self, to_world: Callable[[Tensor], Tensor] | None, intrinsics: Tensor, c2w: Tensor) -> None:
        """Only cells a training camera sees can ever be occupied."""
        if to_world is not None:
            self.grid.restrict_to(cells_seen(self.grid, to_world, intrinsics, c2w))

    def reset(self) -> None:
        self.grid.reset()

    def occupied_share(self) -> float | None:
        return self.grid.occupancy()

    def candidates_per_ray(self) -> int:
        return 4 * self.config.steps + 1  # what ``march`` lays out along a ray before the grid culls them

    def state_dict(self) -> dict[str, Any]:
        return self.grid.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> Any:
        return self.grid.load_state_dict(state)

    def to(self, device: torch.device | str) -> "MarchingSampler":
        self.grid = self.grid.to(device)
        return self
