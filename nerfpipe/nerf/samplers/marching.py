"""Instant-NGP's empty-space skipping as a sampler: rays march the occupied cells of an occupancy grid
(``nerfpipe.nerf.samplers.occupancy``, ``nerfpipe.nerf.samplers.march``) that training keeps up to date."""

from __future__ import annotations

import dataclasses
from typing import Any

import torch
from torch import Tensor

from nerfpipe.nerf.render.volume import RaySamples, RenderOutput
from nerfpipe.nerf.samplers.base import Box, Probe
from nerfpipe.nerf.samplers.configs import MarchingConfig
from nerfpipe.nerf.samplers.march import DensityFn, march, visible, within_budget
from nerfpipe.nerf.samplers.occupancy import OccupancyGrid, cells_in_front, cells_seen
from nerfpipe.nerf.spaces.rays import RayBatch


class MarchingSampler:
    """Empty-space skipping (Instant-NGP): rays march the occupied cells of ``grid`` with ``config``'s steps,
    stopping at transmittance ``config.early_stop``; training refreshes the grid from the field's density."""

    adaptive = True
    # Training skips the visibility pass while it keeps more than this share of the marched samples. The pass
    # evaluates the density of every marched sample (a gather and the density MLP, no gradient) to drop the ones
    # behind opaque surfaces, each of which would cost a density and colour evaluation with its backward pass, about
    # five times as much on a CPU (measured: the temple, 77 % kept, trains 7 % fewer rays a second without the
    # pass): it pays below about four fifths kept. In fog (beer's contracted shell: 94-98 % kept) it is a fifth of a
    # step spent for nothing, and skipping it trains 1.29x the rays a second (docs/benchmarks.md). Only in contracted
    # space, where that fog is: an object in its box keeps the pass (lego's draft field, 90 % kept early on, trained
    # 500 fixed steps without it to 1 dB below its pose-refinement test's mark, on fewer rays a step). Rendering
    # always runs it: its densities are reused there.
    SKIP_VISIBILITY_ABOVE = 0.85

    def __init__(self, grid: OccupancyGrid, config: MarchingConfig) -> None:
        """``config.occupancy_resolution`` is taken as the grid's, whatever it said."""
        if config.occupancy_resolution != grid.resolution:
            config = dataclasses.replace(config, occupancy_resolution=grid.resolution)
        self.grid, self.config = grid, config
        self.visible_share = -1.0  # of the marched samples, what the last visibility pass in training kept (-1: none yet)
        self.measure = True  # whether the next training call runs the visibility pass whatever the share
        self.carved = 0.0  # of the cells the training cameras see, the share ``start`` found empty in front of them

    @classmethod
    def from_config(cls, config: MarchingConfig, box: Box | None) -> "MarchingSampler":
        """An occupancy grid of ``config.occupancy_resolution`` cells a side over ``box`` (it needs one)."""
        if box is None:
            raise ValueError("marching an occupancy grid needs a bounded field box, and was given none")
        return cls(OccupancyGrid(tuple(box[0]), tuple(box[1]), config.occupancy_resolution), config)

    def sample(self, rays: RayBatch, space: Any, probe: Probe, *, train: bool, generator: torch.Generator | None,
               max_samples: int = 0) -> tuple[RaySamples, int, tuple[RenderOutput, ...]]:
        """The occupied steps of each ray (``march``) that it reaches before its transmittance falls below
        ``early_stop`` (``visible``). ``max_samples`` (0: no limit) bounds the work of one call, whatever
        the grid became since the caller chose how many rays to draw: the visibility pass looks at the
        leading rays with at most ``4 max_samples`` marched samples, and the samples kept are those of the
        leading rays with at most ``max_samples`` visible ones."""
        training = train and torch.is_grad_enabled() and getattr(space, "kind", "") == "contracted"
        skip = training and not self.measure and self.visible_share > self.SKIP_VISIBILITY_ABOVE
        # the training pass evaluates every marched sample where it skips the visibility pass: the budget bounds those
        budget = max_samples if skip else 4 * max_samples
        samples = march(rays, space, self.grid, self.config.steps, train, generator, budget)
        if skip:
            return samples, 0, ()
        marched = len(samples)
        # a window of places along the rays at a time, so that a ray that stopped evaluates nothing more (training
        # too: the temple trains 1.34x the rays a second of a pass over every marched sample, docs/benchmarks.md)
        # in one native loop a ray where the model can (not rendering: its densities and features are reused there)
        reached = probe.reached(samples, self.config.early_stop) if torch.is_grad_enabled() else None
        if reached is not None:
            samples = samples.select(reached)
        else:
            samples = visible(rays, space, samples, probe.density_features, self.config.early_stop, 16)
        if training:
            self.visible_share, self.measure = len(samples) / max(marched, 1), False
        if max_samples > 0:
            samples = samples.leading(within_budget(samples, max_samples))
        return samples, 0, ()

    def update(self, step: int, density: DensityFn, generator: torch.Generator) -> None:
        """Refresh the grid from the field's density every ``update_every`` steps; the training step that follows
        a refresh measures what share of its samples the visibility pass keeps (``SKIP_VISIBILITY_ABOVE``)."""
        self.measure = self.measure or step % self.config.update_every == 0
        if step % self.config.update_every:
            return
        self.grid.update(density, self.grid.diagonal / self.config.steps, self.config.occupancy_threshold,
                         step < self.config.warmup, generator)

    def start(self, space: Any, intrinsics: Tensor, c2w: Tensor, least_depth: Tensor | None = None) -> None:
        """Only cells a training camera sees can ever be occupied, and none that one of them sees empty: in front of
        ``carve`` x the least depth of its sparse points near a pixel. Where the space can tell (not NDC)."""
        to_world = space.seen_map()
        if to_world is None:
            return
        seen = cells_seen(self.grid, to_world, intrinsics, c2w)
        self.carved = 0.0
        if least_depth is not None and self.config.carve > 0:
            free = torch.where(torch.isfinite(least_depth), self.config.carve * least_depth, 0.0)
            empty = cells_in_front(self.grid, to_world, intrinsics, c2w, free) & seen
            self.carved = float(empty.sum()) / max(int(seen.sum()), 1)
            seen &= ~empty
        self.grid.restrict_to(seen)

    def reset(self) -> None:
        self.grid.reset()
        self.visible_share, self.measure = -1.0, True

    def stats(self) -> dict[str, float]:
        return {"occupancy": round(self.grid.occupancy(), 4)}

    def candidates_per_ray(self) -> int:
        return 4 * self.config.steps + 1  # what ``march`` lays out along a ray before the grid culls them

    def state_dict(self) -> dict[str, Any]:
        """The grid's buffers, and the visible share last measured (so a resumed training skips as it would have)."""
        return {**self.grid.state_dict(), "visible_share": torch.tensor(self.visible_share)}

    def load_state_dict(self, state: dict[str, Any]) -> Any:
        state = dict(state)
        share = state.pop("visible_share", None)  # a model saved before it was kept: measured again
        self.visible_share, self.measure = (-1.0, True) if share is None else (float(share), False)
        return self.grid.load_state_dict(state)

    def to(self, device: torch.device | str) -> "MarchingSampler":
        self.grid = self.grid.to(device)
        return self


def describe_carving(sampler: Any) -> str | None:
    """A sentence for the train log on what ``MarchingSampler.start`` carved, or None where it carved nothing."""
    carved = getattr(sampler, "carved", 0.0)
    if carved <= 0:
        return None
    return (f"{carved:.0%} of the occupancy cells the training photos see lie in front of {sampler.config.carve:g}x "
            "the depth of the sparse points each photo sees there: empty for good "
            "(train.sampler.carve)")
