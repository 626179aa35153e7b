"""Marching an occupancy grid (Instant-NGP, nerfacc): where a ``MarchingSampler`` puts its samples.

- ``march``: steps of constant length in field coordinates along each ray inside [near, far] (the ray
  space's ``steps``), kept where the cell of the occupancy grid (``nerfpipe.nerf.samplers.occupancy``) is occupied,
  packed ray after ray (``RaySamples``) with the stretch of ray each stands for.
- ``visible``: the samples each ray reaches before its transmittance falls below ``early_stop``, from the
  field's density alone, without gradients, a window of samples at a time so that a ray that has stopped
  costs nothing more (nerfacc's visibility pass).
- ``within_budget``: the leading rays whose samples fit a budget, so one training step costs about the
  same however the grid changed.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import torch
from torch import Tensor

from nerfpipe.nerf import native
from nerfpipe.nerf.kernels import run
from nerfpipe.nerf.samplers.occupancy import OccupancyGrid
from nerfpipe.nerf.spaces.rays import RayBatch
from nerfpipe.nerf.render.volume import RaySamples, optical_depth

# field coordinates (M, 3) -> densities (M,)
DensityFn = Callable[[Tensor], Tensor]
# samples (M,) of a batch of rays, by ray index and t -> densities (M,) and the features the field's colour reads
# (M, F) at their points (``Probe.density_features``)
FeaturesFn = Callable[[Tensor, Tensor], tuple[Tensor, Tensor]]


def at_samples(rays: RayBatch, space, fn: Callable[[Tensor], tuple[Tensor, Tensor]]) -> FeaturesFn:
    """``fn`` of field coordinates (``Field.density_features``) as a ``FeaturesFn`` of samples of ``rays``."""
    return lambda ray, t: fn(space.field_points(rays.points(ray, t)))


def march(rays: RayBatch, space, grid: OccupancyGrid, steps: int, randomized: bool,
          generator: torch.Generator | None = None, budget: int = 0) -> RaySamples:
    """Steps of ``grid.diagonal / steps`` in field coordinates along each ray inside [near, far], kept where
    the grid is occupied (``space``: the ``RaySpace`` the rays are in).

    Step k of a ray stands for its k-th stretch of the space's ``steps``, tiling [near, far]; its sample lies
    a fraction u into it, one u per ray, uniform in [0, 1) when ``randomized`` (training), 0.5 otherwise.
    A ray takes at most ``4 steps + 1`` steps (rays clipped to the field box need at most ``steps + 1``).
    ``spans`` measure each sample's stretch in whole-march units (step k: [k, k + 1] / steps).
    With a ``budget`` > 0, only the leading rays whose samples number at most that together (at least one ray:
    ``within_budget``) are kept; their samples are the same.

    On the CPU, in a contracted or box space, with a budget, the march runs in one native loop a ray
    (``nerfpipe.nerf.native.march_marched``, rendering's march in render.c): torch's lays out every candidate step
    of every ray (about 130 a ray on the temple, 4.3 of them kept) and tests each, a seventh of a training step there.

    Returns:
        RaySamples of the occupied steps.
    """
    n_rays = len(rays)
    dtype, device = rays.origins.dtype, rays.origins.device
    if randomized:
        u = torch.rand((n_rays, 1), generator=generator, device=device, dtype=dtype)
    else:
        u = torch.full((n_rays, 1), 0.5, device=device, dtype=dtype)
    marched = _native_march(rays, space, grid, steps, u, budget)
    if marched is not None:
        return marched
    starts, ends = space.steps(rays.origins, rays.directions, rays.near, rays.far, grid.diagonal / steps,
                               4 * steps + 1)
    # every candidate tested where it lies, then one compaction: a boolean index per array would scan the mask again
    # for each of them (the march took a fifth of a render on beer, most of it in those scans)
    # one ray, or one step a ray, runs eagerly: the compiled graph would be specialized to that size of 1
    keep, t = run(occupied_candidates, starts.numel() if min(starts.shape) > 1 else 0, starts.device, space, grid,
                  rays.origins, rays.directions, rays.far, starts, ends, u)
    flat = keep.nonzero().squeeze(-1)  # row-major: ray after ray, k increasing
    columns = starts.shape[1]
    ray, step = flat // columns, (flat % columns).to(t.dtype)
    t, s, e = (x.reshape(-1)[flat] for x in (t, starts, ends))
    samples = RaySamples(ray, t, s, e, n_rays, (step / steps, (step + 1.0) / steps))
    return samples.leading(within_budget(samples, budget)) if budget > 0 else samples


def march_frame(space) -> tuple[bool, tuple[float, ...], tuple[float, ...]] | None:
    """How the native loops (render.c) find a ray's field points in ``space``: (contracted, centre, half extent) of
    the box a contracted space keeps (its scene box), or (False, 0, 1) for a box space's world coordinates; None for
    a space they do not know (NDC)."""
    kind = getattr(space, "kind", "")
    if kind == "contracted":
        lo, hi = space.box
        return True, tuple((a + b) / 2.0 for a, b in zip(lo, hi)), tuple((b - a) / 2.0 for a, b in zip(lo, hi))
    return (False, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)) if kind == "box" else None


def _native_march(rays: RayBatch, space, grid: OccupancyGrid, steps: int, u: Tensor, budget: int) -> RaySamples | None:
    """``march`` in the native loop (``native.march_marched``), or None where it does not run: no budget, a space
    other than contracted or box (NDC), or what the kernel refuses."""
    frame = march_frame(space)
    if budget <= 0 or frame is None or len(rays) == 0:
        return None
    contracted, center, half = frame
    made = native.march_marched(contracted, center, half, grid.diagonal / steps, 4 * steps + 1,
                                grid.occupied, (tuple(grid.lo.tolist()), tuple(grid.hi.tolist())), rays.origins,
                                rays.directions, rays.near, rays.far, u.reshape(-1), budget)
    if made is None:
        return None
    (ray, t, starts, ends, step), kept = made
    step = step.to(t.dtype)
    return RaySamples(ray, t, starts, ends, kept, (step / steps, (step + 1.0) / steps))


def occupied_candidates(space, grid: OccupancyGrid, origins: Tensor, directions: Tensor, far: Tensor, starts: Tensor,
                        ends: Tensor, u: Tensor) -> tuple[Tensor, Tensor]:
    """``march``'s candidates: the sample a fraction ``u`` (R, 1) into each step [starts, ends] (R, S) of rays
    (R, 3) in ``space``, and whether it lies before ``far`` (R,) in an occupied cell of ``grid``. Returns
    (R S,) bool, row-major, and t (R, S). A pure function of its inputs, which rendering compiles
    (``nerfpipe.nerf.kernels``): one loop over the candidates, where eagerly each step's array is written out."""
    t = torch.addcmul(starts, u, (ends - starts).clamp_min(0.0))  # (R, S)
    points = torch.addcmul(origins.unsqueeze(1), t.unsqueeze(-1), directions.unsqueeze(1))  # (R, S, 3)
    return (starts < far.unsqueeze(-1)).reshape(-1) & grid.is_occupied(space.field_points(points.reshape(-1, 3))), t


def visible(rays: RayBatch, space, samples: RaySamples, evaluate: FeaturesFn, early_stop: float,
            window: int = 0) -> RaySamples:
    """The samples a ray reaches with transmittance above ``early_stop``, from the field's density, evaluated
    without gradients (``evaluate``: densities and features of samples given by ray index and t, ``FeaturesFn``).

    Samples are taken ``window`` places along each ray at first (0: all at once), on the rays still above
    ``early_stop`` only: a ray that has stopped drops the rest of its samples unevaluated. Each round after
    looks twice as far along the rays still going, as long as that is no more than the first round's
    ``window`` places of every ray: the rays that go on (through thin density) do so in few rounds, and no
    round is larger than the first. The kept samples of
    each ray are a prefix of its own, since transmittance never grows. Called where gradients are off
    (rendering, not training), the kept samples carry what was evaluated (``RaySamples.known``), so the
    field's density is not evaluated twice.
    """
    remember = not torch.is_grad_enabled()
    with torch.no_grad():
        return _visible(rays, space, samples, evaluate, early_stop, window, remember)


def _visible(rays: RayBatch, space, samples: RaySamples, evaluate: FeaturesFn, early_stop: float, window: int,
             remember: bool) -> RaySamples:
    if early_stop <= 0 or not len(samples):
        return samples
    counts = samples.counts()
    first = torch.cumsum(counts, dim=0) - counts
    depth = torch.zeros(samples.n_rays, dtype=torch.float64, device=counts.device)  # optical depth so far, per ray
    keep = torch.zeros(len(samples), dtype=torch.bool, device=counts.device)
    sigmas = torch.zeros(len(samples), device=counts.device) if remember else None
    features = None
    limit = -math.log(early_stop)  # T > early_stop <=> optical depth < limit
    longest = int(counts.max())
    start, width = 0, window if window > 0 else longest
    active = torch.arange(samples.n_rays, device=counts.device)
    while start < longest:
        active = active[(counts[active] > start) & (depth[active] < limit)]
        if not len(active):
            break
        offset = torch.arange(start, start + width, device=counts.device)
        within = offset < counts[active].unsqueeze(-1)  # (A, W): the window's places each ray has
        index = (first[active].unsqueeze(-1) + offset)[within]  # ray after ray, in order along each
        part = RaySamples(samples.ray[index], samples.t[index], samples.starts[index], samples.ends[index],
                          samples.n_rays)  # what the round reads: not the spans
        sigma, feature = evaluate(part.ray, part.t)
        sigma = sigma.float().reshape(-1)
        if remember:
            if features is None:
                features = feature.new_zeros((len(samples), feature.shape[-1]))
            sigmas[index], features[index] = sigma, feature
        tau = optical_depth(sigma, (part.ends - part.starts).clamp_min(0.0)).double()
        keep[index] = depth[part.ray] + part.exclusive_sums(tau) < limit
        depth.index_add_(0, part.ray, tau)
        start = start + width
        width = max(window, min(2 * width, window * samples.n_rays // max(len(active), 1))) if window > 0 else longest
    if remember and features is not None:
        samples = dataclasses.replace(samples, known=(sigmas, features))
    return samples.select(keep)


def within_budget(samples: RaySamples, budget: int) -> int:
    """How many leading rays have at most ``budget`` samples together; at least one (0: all rays)."""
    if budget <= 0:
        return samples.n_rays
    total = torch.cumsum(samples.counts(), dim=0)
    return min(max(int((total <= budget).sum()), 1), samples.n_rays)
