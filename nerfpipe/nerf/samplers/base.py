"""Samplers: where along each ray a model evaluates its field (nerfacc's split of sampling from rendering).

A sampler's one job is ``sample(rays, ...) -> RaySamples``: packed samples, each with its ray and the stretch
of ray it stands for; ``nerfpipe.nerf.render.volume.volume_render`` composites them and ``RadianceModel.render``
is the one place that does. ``update(step, density, generator)`` keeps what a sampler learns from the field
(an occupancy grid) up to date while training. Two are registered (``nerfpipe.nerf.registry.SAMPLERS``):

- ``HierarchicalSampler``: Section 5.2, N_c stratified samples rendered through the coarse field, N_f more
  drawn from its weights (Eq. 5) for the fine one; the coarse rendering is also fitted (Eq. 6).
- ``MarchingSampler``: Instant-NGP's empty-space skipping, marching an occupancy grid that training keeps
  up to date (``nerfpipe.nerf.samplers.occupancy``, ``nerfpipe.nerf.samplers.march``); the coarse field only.

A new sampler is a class with these methods and a line in the registry.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, ClassVar, Protocol

import torch
from torch import Tensor

from nerfpipe.nerf.samplers.march import DensityFn, march, visible, within_budget
from nerfpipe.nerf.samplers.occupancy import MarchingConfig, OccupancyGrid, cells_seen
from nerfpipe.nerf.spaces.rays import RayBatch
from nerfpipe.nerf.render.volume import RaySamples, RenderOutput
from nerfpipe.nerf.samplers.sampling import sample_intervals, sample_pdf, stratified_samples

Box = tuple[tuple[float, ...], tuple[float, ...]]


class Probe(Protocol):
    """What a sampler may ask of the model while it samples (``RadianceModel.render`` hands one over)."""

    def density_features(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """Densities (M,) of the first field at field coordinates (M, 3) and its features there
        (``Field.density_features``), without gradients."""

    def render(self, samples: RaySamples, level: int) -> RenderOutput:
        """``samples`` rendered through field ``level`` (0: coarse, 1: fine), with gradients while training."""


@dataclass(frozen=True)
class SamplingConfig:
    """N_c stratified samples, N_f more from the coarse weights (0: no hierarchical sampling)."""

    n_coarse: int = 64
    n_fine: int = 128
    lindisp: bool = False


class Sampler(Protocol):
    """Where a model samples its rays."""

    kind: ClassVar[str]
    fields: ClassVar[int]  # fields it evaluates: 1 (coarse), or 2 (coarse, then fine)
    adaptive: ClassVar[bool]  # whether its samples per ray vary, so the trainer adapts its rays per batch

    def sample(self, rays: RayBatch, space: Any, probe: Probe, *, train: bool, generator: torch.Generator | None,
               max_samples: int = 0) -> tuple[RaySamples, int, tuple[RenderOutput, ...]]:
        """Samples of ``rays`` (in ``space``'s ray coordinates), randomized when ``train``; with
        ``max_samples`` > 0 those of the leading rays only, within about that many. Returns the samples,
        the field level to evaluate them with, and the renderings made on the way (``Probe.render``)."""

    def update(self, step: int, density: DensityFn, generator: torch.Generator) -> None:
        """What the sampler keeps up to date with the field, before training step ``step``."""

    def start(self, space: Any, intrinsics: Tensor, c2w: Tensor) -> None:
        """Before training: the training cameras (intrinsics (I, 4), c2w (I, 4, 4)) and the ray space."""

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

    @staticmethod
    def spec_of(params: Any, box: Box | None, lindisp: bool) -> dict[str, Any]:
        """The spec ``nerfpipe.nerf.config.SamplerParams`` asks for."""

    @classmethod
    def from_spec(cls, spec: dict[str, Any]) -> "Sampler":
        """Built from a spec (model.json), training state fresh."""

    def spec(self) -> dict[str, Any]:
        """What ``from_spec`` rebuilds it from (stored in model.json)."""

    @staticmethod
    def describe(spec: dict[str, Any]) -> str | None:
        """A sentence for the train log about the sampler ``spec`` describes, or None for the paper's own."""


class StatelessSampler:
    """What a sampler that keeps nothing beside the fields does between renders: nothing. A sampler with no
    training state of its own (``HierarchicalSampler``) takes these rather than writing them out again."""

    def update(self, step: int, density: DensityFn, generator: torch.Generator) -> None:
        pass

    def start(self, space: Any, intrinsics: Tensor, c2w: Tensor) -> None:
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
    def from_spec(cls, spec: dict[str, Any]) -> "HierarchicalSampler":
        return cls(SamplingConfig(**spec["sampling"]))

    def spec(self) -> dict[str, Any]:
        return {"sampling": asdict(self.config)}

    @staticmethod
    def describe(spec: dict[str, Any]) -> None:
        """The paper's sampling needs no sentence in the train log."""
        return None

    def candidates_per_ray(self) -> int:
        c = self.config
        return c.n_coarse + (c.n_coarse + c.n_fine if c.n_fine > 0 else 0)

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
        t = stratified_samples(rays.near, rays.far, c.n_coarse, train, c.lindisp, generator)
        edges = sample_intervals(t, rays.near, rays.far)
        samples = RaySamples.dense(t, edges[:, :-1], edges[:, 1:])
        if c.n_fine <= 0:
            return samples, 0, ()
        coarse = probe.render(samples, 0)
        weights = coarse.weights.detach().reshape(len(rays), c.n_coarse)
        extra = sample_pdf(edges.detach(), weights, c.n_fine, not train, generator).detach()
        t_all = torch.sort(torch.cat([t, extra], dim=-1), dim=-1).values
        edges = sample_intervals(t_all, rays.near, rays.far)
        return RaySamples.dense(t_all, edges[:, :-1], edges[:, 1:]), 1, (coarse,)


class MarchingSampler:
    """Empty-space skipping (Instant-NGP): rays march the occupied cells of ``grid`` with ``config``'s steps,
    stopping at transmittance ``config.early_stop``; training refreshes the grid from the field's density."""

    kind = "marching"
    fields = 1
    adaptive = True

    def __init__(self, grid: OccupancyGrid, config: MarchingConfig) -> None:
        self.grid, self.config = grid, config

    @staticmethod
    def spec_of(params: Any, box: Box | None, lindisp: bool) -> dict[str, Any]:
        """The spec ``nerfpipe.nerf.config.SamplerParams`` asks for: a grid over ``box`` (needs one)."""
        config = MarchingConfig(steps=params.steps, threshold=params.occupancy_threshold, early_stop=params.early_stop)
        return {"occupancy": {"resolution": params.occupancy_resolution, "box": [list(box[0]), list(box[1])],
                              "marching": asdict(config)}}

    @classmethod
    def from_spec(cls, spec: dict[str, Any]) -> "MarchingSampler":
        occ = spec["occupancy"]
        grid = OccupancyGrid(tuple(occ["box"][0]), tuple(occ["box"][1]), occ["resolution"])
        return cls(grid, MarchingConfig(**occ["marching"]))

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

    def sample(self, rays: RayBatch, space: Any, probe: Probe, *, train: bool, generator: torch.Generator | None,
               max_samples: int = 0) -> tuple[RaySamples, int, tuple[RenderOutput, ...]]:
        """The occupied steps of each ray (``march``) that it reaches before its transmittance falls below
        ``early_stop`` (``visible``). ``max_samples`` (0: no limit) bounds the work of one call, whatever
        the grid became since the caller chose how many rays to draw: the visibility pass looks at the
        leading rays with at most ``4 max_samples`` marched samples, and the samples kept are those of the
        leading rays with at most ``max_samples`` visible ones."""
        samples = march(rays, space, self.grid, self.config.steps, train, generator)
        if max_samples > 0:
            samples = samples.leading(within_budget(samples, 4 * max_samples))
        # a window of places along the rays at a time, so that a ray that stopped evaluates nothing more (training
        # too: the temple trains 1.34x the rays a second of a pass over every marched sample, docs/benchmarks.md)
        samples = visible(rays, space, samples, probe.density_features, self.config.early_stop, 16)
        if max_samples > 0:
            samples = samples.leading(within_budget(samples, max_samples))
        return samples, 0, ()

    def update(self, step: int, density: DensityFn, generator: torch.Generator) -> None:
        """Refresh the grid from the field's density every ``update_every`` steps."""
        if step % self.config.update_every:
            return
        self.grid.update(density, self.grid.diagonal / self.config.steps, self.config.threshold,
                         step < self.config.warmup, generator)

    def start(self, space: Any, intrinsics: Tensor, c2w: Tensor) -> None:
        """Only cells a training camera sees can ever be occupied (where the space can tell)."""
        to_world = space.seen_map()
        if to_world is not None:
            self.grid.restrict_to(cells_seen(self.grid, to_world, intrinsics, c2w))

    def reset(self) -> None:
        self.grid.reset()

    def stats(self) -> dict[str, float]:
        return {"occupancy": round(self.grid.occupancy(), 4)}

    def candidates_per_ray(self) -> int:
        return 4 * self.config.steps + 1  # what ``march`` lays out along a ray before the grid culls them

    def state_dict(self) -> dict[str, Any]:
        return self.grid.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> Any:
        return self.grid.load_state_dict(state)

    def to(self, device: torch.device | str) -> "MarchingSampler":
        self.grid = self.grid.to(device)
        return self
