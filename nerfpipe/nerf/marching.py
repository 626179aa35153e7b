"""Marching an occupancy grid, and volume rendering of the packed samples it gives (Instant-NGP, nerfacc).

- ``march``: constant steps along each ray inside [near, far], kept where the cell of the occupancy grid
  (``nerfpipe.nerf.occupancy``) is occupied, packed to the left of an (R, K) layout with the stretch of ray
  each sample stands for.
- ``render_marched``: the samples composited with Eq. 3 (``rendering.composite`` with explicit
  intervals). A density-only pass without gradients drops the samples behind the point where
  transmittance falls below ``early_stop`` before the field is evaluated with gradients; rendering
  without gradients marches in segments and stops each ray there. A sample budget keeps the leading rays
  whose samples fit it, so one training step costs about the same however the grid changed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor

from nerfpipe.nerf.contraction import Contraction
from nerfpipe.nerf.occupancy import DensityFn, MarchingConfig, OccupancyGrid
from nerfpipe.nerf.rendering import Composite, composite, optical_depth

# (points (M, 3), unit view directions (M, 3)) -> (rgb (M, 3), sigma (M,))
FieldFn = Callable[[Tensor, Tensor], tuple[Tensor, Tensor]]


@dataclass
class PackedSamples:
    """Samples of R rays packed to the left: row r holds ``count[r]`` samples in order of depth, then
    padding. t, starts, ends: (R, K); valid: (R, K) bool. A padding entry has t = starts = ends = the
    ray's far bound, an interval of length 0 that nothing stops in."""

    t: Tensor
    starts: Tensor
    ends: Tensor
    valid: Tensor
    step: Tensor | None = None  # (R, K): the index of each sample's step along its ray (padding: the last + 1)

    @property
    def count(self) -> Tensor:
        return self.valid.sum(dim=-1)

    def columns(self, start: int, stop: int) -> "PackedSamples":
        return PackedSamples(self.t[:, start:stop], self.starts[:, start:stop], self.ends[:, start:stop],
                             self.valid[:, start:stop], None if self.step is None else self.step[:, start:stop])

    def rows(self, index: Tensor | slice) -> "PackedSamples":
        return PackedSamples(self.t[index], self.starts[index], self.ends[index], self.valid[index],
                             None if self.step is None else self.step[index])


def pack_left(valid: Tensor, *values: Tensor, fill: Tensor) -> tuple[Tensor, list[Tensor]]:
    """Move the entries of each row where ``valid`` holds to its front, keeping their order; the rest
    become ``fill`` (R, 1). Returns the packed mask (R, K) and values, K the largest count (at least 1)."""
    counts = valid.sum(dim=-1)
    width = max(int(counts.max()) if counts.numel() else 0, 1)
    order = torch.argsort((~valid).to(torch.int8), dim=-1, stable=True)[:, :width]
    packed_valid = torch.gather(valid, -1, order)
    packed = [torch.where(packed_valid, torch.gather(v, -1, order), fill) for v in values]
    return packed_valid, packed


def march(origins: Tensor, directions: Tensor, near: Tensor, far: Tensor, grid: OccupancyGrid, steps: int,
          randomized: bool, generator: torch.Generator | None = None,
          contraction: Contraction | None = None) -> PackedSamples:
    """Constant steps of ``grid.diagonal / steps`` in field space along each ray inside [near, far], kept
    where the grid is occupied. With a ``contraction``, rays are world rays, the grid lies in contracted
    space, and the steps are of that length in contracted space (``contracted_steps``).

    Step k of a ray stands for the interval [near + k dt, near + (k + 1) dt] cut at far, with
    dt = diagonal / (steps |d|), so the steps tile [near, far]; its sample lies a fraction u into it, one u
    per ray, uniform in [0, 1) when ``randomized`` (training), 0.5 otherwise. A ray gets
    ``ceil((far - near) / dt)`` steps; rays clipped to the field box at most ``steps + 1``.

    Args:
        origins, directions: (R, 3) in field space; near, far: (R,).
    Returns:
        PackedSamples of the occupied steps.
    """
    n_rays = origins.shape[0]
    if n_rays == 0:
        empty = origins.new_zeros((0, 1))
        return PackedSamples(empty, empty, empty, empty.bool())
    if contraction is None:
        starts, ends = constant_steps(directions, near, far, grid.diagonal / steps, 4 * steps + 1)
    else:
        starts, ends = contracted_steps(origins, directions, near, far, contraction, grid.diagonal / steps, 4 * steps + 1)
    if randomized:
        u = torch.rand((n_rays, 1), generator=generator, device=origins.device, dtype=origins.dtype)
    else:
        u = torch.full((n_rays, 1), 0.5, device=origins.device, dtype=origins.dtype)
    inside = starts < far.unsqueeze(-1)
    t = starts + u * (ends - starts).clamp_min(0.0)
    points = origins.unsqueeze(-2) + t.unsqueeze(-1) * directions.unsqueeze(-2)
    if contraction is not None:
        points = contraction.to_field(points)
    keep = torch.zeros_like(inside)
    if bool(inside.any()):
        keep[inside] = grid.is_occupied(points[inside])
    fill = far.unsqueeze(-1)
    index = torch.arange(t.shape[1], device=t.device, dtype=t.dtype).expand_as(t)
    valid, (t, starts, ends, step) = pack_left(keep, t, starts, ends, index, fill=fill)
    step = torch.where(valid, step, torch.full_like(step, float(index.shape[1])))
    return PackedSamples(t, starts, ends, valid, step)


def constant_steps(directions: Tensor, near: Tensor, far: Tensor, step: float, most: int) -> tuple[Tensor, Tensor]:
    """Steps of length ``step`` in the rays' own space tiling [near, far]: starts and ends (R, S), the
    last step of a ray cut at far, S the most any ray needs (at most ``most``: rays longer than that many
    steps, unclipped ones, stop there)."""
    norm = torch.linalg.vector_norm(directions, dim=-1).clamp_min(1e-12)
    dt = step / norm
    length = (far - near).clamp_min(0.0)
    needed = torch.nan_to_num(length / dt, nan=0.0, posinf=0.0)
    n_steps = int(torch.ceil(needed.max()).item()) if len(near) else 0
    n_steps = max(min(n_steps, most), 1)
    k = torch.arange(n_steps, device=directions.device, dtype=directions.dtype)
    starts = near.unsqueeze(-1) + k * dt.unsqueeze(-1)
    return starts, torch.minimum(starts + dt.unsqueeze(-1), far.unsqueeze(-1))


def contracted_steps(origins: Tensor, directions: Tensor, near: Tensor, far: Tensor, contraction: Contraction,
                     step: float, most: int) -> tuple[Tensor, Tensor]:
    """Steps of about ``step`` in contracted space along world rays, tiling [near, far]: inside the scene
    box a constant world step, beyond it one that grows with the squared distance from the box
    (``Contraction.step_scale_at``), so far content gets as many samples as its size in the grid. Each step's
    length is set at its start, from the point's norm before contraction (5 tensor operations a step rather
    than 25 through the contracted point: beer trains 10-15 % faster). Returns starts and ends (R, S); S is at
    most ``most``."""
    x0, dx = contraction.box_rays(origins, directions)
    base = step / torch.linalg.vector_norm(dx, dim=-1).clamp_min(1e-12)  # |dx| is field_length, from box_rays' dx
    t = near.clone()
    edges = [t]
    for _ in range(most):
        norm = torch.addcmul(x0, t.unsqueeze(-1), dx).abs().amax(dim=-1)
        t = torch.minimum(torch.addcmul(t, base, Contraction.step_scale_at(norm)), far)
        edges.append(t)
        if not bool((t < far).any()):
            break
    stacked = torch.stack(edges, dim=-1)
    return stacked[:, :-1], stacked[:, 1:]




def transmittance_before(sigmas: Tensor, samples: PackedSamples) -> Tensor:
    """T_i of each packed sample (Eq. 3), over the intervals' lengths. (R, K)."""
    tau = optical_depth(sigmas, (samples.ends - samples.starts).clamp_min(0.0))
    return torch.exp(-torch.cat([torch.zeros_like(tau[:, :1]), torch.cumsum(tau, dim=-1)[:, :-1]], dim=-1))


def visible(density_fn: DensityFn, origins: Tensor, directions: Tensor, samples: PackedSamples,
            early_stop: float) -> PackedSamples:
    """The samples a ray reaches before its transmittance falls below ``early_stop``, from one pass of
    density alone without gradients (nerfacc's visibility pass). Still packed: the kept samples of each
    ray are a prefix, since transmittance never grows along a ray."""
    if early_stop <= 0 or not bool(samples.valid.any()):
        return samples
    with torch.no_grad():
        sigmas = torch.zeros_like(samples.t)
        points = origins.unsqueeze(-2) + samples.t.unsqueeze(-1) * directions.unsqueeze(-2)
        sigmas[samples.valid] = density_fn(points[samples.valid]).float().to(sigmas.dtype)
        keep = samples.valid & (transmittance_before(sigmas, samples) > early_stop)
    width = max(int(keep.sum(dim=-1).max()), 1)
    kept = samples.columns(0, width)
    return PackedSamples(kept.t, kept.starts, kept.ends, keep[:, :width], kept.step)


def evaluate_packed(field: FieldFn, origins: Tensor, directions: Tensor, viewdirs: Tensor,
                    samples: PackedSamples) -> tuple[Tensor, Tensor]:
    """The field at the valid samples; zero density and colour at padding. Returns rgb (R, K, 3), sigma (R, K)."""
    n_rays, width = samples.t.shape
    valid = samples.valid
    points = origins.unsqueeze(-2) + samples.t.unsqueeze(-1) * directions.unsqueeze(-2)
    dirs = viewdirs.unsqueeze(-2).expand(n_rays, width, 3)
    rgb_v, sigma_v = field(points[valid], dirs[valid])
    rgb = torch.zeros((n_rays, width, 3), dtype=rgb_v.dtype, device=rgb_v.device)
    sigma = torch.zeros((n_rays, width), dtype=sigma_v.dtype, device=sigma_v.device)
    return rgb.index_put((valid,), rgb_v), sigma.index_put((valid,), sigma_v)


def composite_packed(rgb: Tensor, sigma: Tensor, samples: PackedSamples, far: Tensor,
                     background: Tensor | None) -> Composite:
    return composite(sigma, rgb, samples.t, far, background, intervals=(samples.starts, samples.ends))


def rays_within(samples: PackedSamples, budget: int) -> int:
    """How many leading rays have at most ``budget`` samples together; at least one."""
    total = torch.cumsum(samples.count, dim=0)
    return max(int((total <= budget).sum()), 1)


def leading_rays(budget: int, samples: PackedSamples, *per_ray: Tensor) -> tuple[PackedSamples, ...]:
    """``samples`` and the per-ray tensors (R, ...) cut to the ``rays_within(samples, budget)`` leading rays."""
    n = rays_within(samples, budget)
    return (samples.rows(slice(0, n)), *(x[:n] for x in per_ray))


def render_marched(field: FieldFn, density_fn: DensityFn, origins: Tensor, directions: Tensor, viewdirs: Tensor,
                   near: Tensor, far: Tensor, grid: OccupancyGrid, config: MarchingConfig,
                   background: Tensor | None = None, randomized: bool = True,
                   generator: torch.Generator | None = None, max_samples: int = 0,
                   contraction: Contraction | None = None) -> tuple[Composite, int]:
    """Render rays by marching the occupancy grid, with gradients (training).

    ``max_samples`` (0: no limit) bounds the work of one call, whatever the grid became since the caller
    chose how many rays to draw: the visibility pass evaluates the leading rays with at most
    ``4 * max_samples`` marched samples, and the field, with gradients, those of them with at most
    ``max_samples`` visible ones. The composite is of those leading rays only (its length says how many).

    Returns the composite (Eq. 3 over the marched intervals) and how many samples the field evaluated.
    """
    samples = march(origins, directions, near, far, grid, config.steps, randomized, generator, contraction)
    per_ray = (origins, directions, viewdirs, far)
    if max_samples > 0:
        samples, *per_ray = leading_rays(4 * max_samples, samples, *per_ray)
    samples = visible(density_fn, per_ray[0], per_ray[1], samples, config.early_stop)
    if max_samples > 0:
        samples, *per_ray = leading_rays(max_samples, samples, *per_ray)
    origins, directions, viewdirs, far = per_ray
    rgb, sigma = evaluate_packed(field, origins, directions, viewdirs, samples)
    result = composite_packed(rgb, sigma, samples, far, background)
    if samples.step is not None:  # in units of the whole march: each step 1 / steps long, equal in field space
        result.intervals = (samples.step / config.steps, (samples.step + 1.0) / config.steps)
    return result, int(samples.valid.sum())


@torch.no_grad()
def render_marched_segments(field: FieldFn, origins: Tensor, directions: Tensor, viewdirs: Tensor, near: Tensor,
                            far: Tensor, grid: OccupancyGrid, config: MarchingConfig,
                            background: Tensor | None = None, segment: int = 16,
                            contraction: Contraction | None = None) -> tuple[dict[str, Tensor], int]:
    """Render rays without gradients, ``segment`` samples of each ray at a time, dropping each ray once its
    transmittance is below ``config.early_stop``: the same sums as ``composite`` over every sample, less
    the rays' remaining weight (at most ``early_stop`` each).

    Returns rgb (R, 3), depth, disparity, acc (R,) as ``render_chunked`` does, and the samples evaluated.
    """
    samples = march(origins, directions, near, far, grid, config.steps, randomized=False, contraction=contraction)
    n_rays, width = samples.t.shape
    dtype = torch.float64 if origins.dtype == torch.float64 else torch.float32
    T = torch.ones(n_rays, dtype=dtype, device=origins.device)
    rgb = torch.zeros((n_rays, 3), dtype=dtype, device=origins.device)
    acc = torch.zeros(n_rays, dtype=dtype, device=origins.device)
    depth_sum = torch.zeros(n_rays, dtype=dtype, device=origins.device)
    evaluated = 0
    for start in range(0, width, segment):
        part = samples.columns(start, start + segment)
        active = part.valid.any(dim=-1)
        if config.early_stop > 0:
            active &= T > config.early_stop
        if not bool(active.any()):
            if not bool(part.valid.any()):
                break
            continue
        rows = active.nonzero().squeeze(-1)
        sub = part.rows(rows)
        c_rgb, c_sigma = evaluate_packed(field, origins[rows], directions[rows], viewdirs[rows], sub)
        evaluated += int(sub.valid.sum())
        piece = composite(c_sigma, c_rgb, sub.t, far[rows], None, intervals=(sub.starts, sub.ends))
        t_rows = T[rows]
        rgb[rows] += t_rows.unsqueeze(-1) * piece.rgb
        acc[rows] += t_rows * piece.acc
        depth_sum[rows] += t_rows * piece.acc * piece.depth
        tau = optical_depth(c_sigma, (sub.ends - sub.starts).clamp_min(0.0)).sum(dim=-1)
        T[rows] = t_rows * torch.exp(-tau)
    if background is not None:
        rgb = rgb + (1.0 - acc).clamp_min(0.0).unsqueeze(-1) * background.to(rgb)
    hit = acc > 1e-10
    far_ = far.to(dtype)
    depth = torch.where(hit, depth_sum / torch.where(hit, acc, torch.ones_like(acc)), far_)
    depth = torch.minimum(torch.maximum(depth, near.to(dtype)), far_)
    positive = depth > 0
    disparity = torch.where(positive, 1.0 / torch.where(positive, depth, torch.ones_like(depth)), torch.zeros_like(depth))
    return {"rgb": rgb, "depth": depth, "disparity": disparity, "acc": acc}, evaluated

