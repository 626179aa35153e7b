"""Empty-space skipping and early ray termination.

Not in the NeRF paper, whose sampler spends most of its N_c + N_f samples on empty space (Section 5.2
notes the inefficiency). Instant-NGP (Mueller et al. 2022, Section 4, "Accelerated ray marching") keeps a
grid of occupied cells, updated from the field's density while training, and marches each ray in small
constant steps, evaluating the field only inside occupied cells and stopping once the ray is opaque;
nerfacc (Li et al. 2023) does the same in PyTorch. This module is that scheme for any field with a
``query_density``:

- ``OccupancyGrid``: a running maximum of density per cell over the field's box (decay 0.95 per update,
  Instant-NGP's), and which cells are occupied: those whose density makes one marching step more than
  ``threshold`` optically thick.
- ``cells_seen``: the cells the training cameras see.
- ``cells_in_front``: the cells wholly in front of what each training camera's sparse points leave free
  (``nerfpipe.geometry.freespace``): empty space, carved for good.

How rays march it is ``nerfpipe.nerf.samplers.configs.MarchingConfig``.

The marching and the packed volume rendering over it are in ``nerfpipe.nerf.samplers.march``.
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor, nn

DensityFn = Callable[[Tensor], Tensor]


class OccupancyGrid(nn.Module):
    """Occupied cells of a ``resolution``^3 grid over the axis-aligned box [lo, hi] of field space.

    Buffers (saved with the model): ``density`` (R^3,) running maximum of sampled density per cell, -1
    for a cell never evaluated; ``occupied`` (R^3,) bool. Cells are indexed (i * R + j) * R + k along x, y, z.
    A new grid marks every cell occupied: nothing is skipped before the first update.
    """

    def __init__(self, lo: tuple[float, ...], hi: tuple[float, ...], resolution: int = 64, decay: float = 0.95) -> None:
        super().__init__()
        if resolution < 1:
            raise ValueError(f"occupancy resolution must be >= 1, got {resolution}")
        lo_t, hi_t = torch.tensor(lo, dtype=torch.float32), torch.tensor(hi, dtype=torch.float32)
        if lo_t.shape != (3,) or not bool((hi_t > lo_t).all()):
            raise ValueError(f"occupancy box must have hi > lo on every axis, got {lo} .. {hi}")
        self.resolution = resolution
        self.decay = decay
        self.register_buffer("lo", lo_t)
        self.register_buffer("hi", hi_t)
        self.register_buffer("density", torch.full((resolution**3,), -1.0))
        self.register_buffer("occupied", torch.ones(resolution**3, dtype=torch.bool))
        # cells some training camera sees (``restrict_to``); not saved: ``occupied`` already leaves the rest out
        self.register_buffer("seen", torch.ones(resolution**3, dtype=torch.bool), persistent=False)

    def reset(self) -> None:
        """As new: every cell some camera sees occupied, none evaluated."""
        self.density.fill_(-1.0)
        self.occupied.copy_(self.seen)

    def restrict_to(self, seen: Tensor) -> None:
        """Mark the cells no training camera sees (``seen`` (R^3,) False) empty for good, as Instant-NGP does:
        nothing there is ever trained, and a field's initial density would otherwise keep them occupied."""
        self.seen.copy_(seen)
        self.occupied &= seen

    @property
    def diagonal(self) -> float:
        return float(torch.linalg.vector_norm(self.hi - self.lo))

    def occupancy(self) -> float:
        """Fraction of cells occupied."""
        return float(self.occupied.float().mean())

    def cell_index(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """Flat cell index of field-space points (M, 3), and whether each lies inside the box (M,)."""
        r = self.resolution
        u = (points - self.lo) / (self.hi - self.lo)
        inside = ((u >= 0) & (u <= 1)).all(dim=-1)
        ijk = (u * r).floor().clamp(0, r - 1).long()
        return (ijk[:, 0] * r + ijk[:, 1]) * r + ijk[:, 2], inside

    def is_occupied(self, points: Tensor) -> Tensor:
        """(M, 3) field-space points -> (M,) bool: inside the box and in an occupied cell."""
        index, inside = self.cell_index(points)
        return inside & self.occupied[index]

    def cell_points(self, index: Tensor, jitter: bool, generator: torch.Generator | None = None) -> Tensor:
        """Points in cells ``index`` (M,): their centres, or uniformly random inside them."""
        r = self.resolution
        ijk = torch.stack([index // (r * r), (index // r) % r, index % r], dim=-1).to(self.lo.dtype)
        offset = (torch.rand(ijk.shape, generator=generator, device=ijk.device, dtype=ijk.dtype) if jitter
                  else torch.full_like(ijk, 0.5))
        return self.lo + (ijk + offset) / r * (self.hi - self.lo)

    @torch.no_grad()
    def update(self, density_fn: DensityFn, step_size: float, threshold: float, all_cells: bool,
               generator: torch.Generator | None = None, chunk: int = 65536) -> None:
        """One update: density at a random point of each chosen cell; the cell's value decays by
        ``decay`` and becomes the larger of that and the new density; a cell is occupied when
        sigma * step_size exceeds min(threshold, the mean of sigma * step_size over evaluated cells).

        Args:
            density_fn: (M, 3) field-space points -> (M,) densities.
            step_size: the marching step in field space, so the threshold is an optical depth per step.
            all_cells: evaluate every cell (warm-up), else a quarter at random and a quarter of the occupied.
        """
        n = self.resolution**3
        device = self.density.device
        if all_cells:
            cells = torch.arange(n, device=device)
        else:
            quarter = max(n // 4, 1)
            random_cells = torch.randint(n, (quarter,), generator=generator, device=device)
            occupied = self.occupied.nonzero().squeeze(-1)
            if len(occupied) > quarter:
                pick = torch.randint(len(occupied), (quarter,), generator=generator, device=device)
                occupied = occupied[pick]
            cells = torch.cat([random_cells, occupied])
        points = self.cell_points(cells, jitter=True, generator=generator)
        sampled = torch.cat([density_fn(points[i:i + chunk]).float().reshape(-1) for i in range(0, len(points), chunk)])
        sampled = torch.nan_to_num(sampled, nan=0.0, posinf=1e30).clamp_min(0.0)
        decayed = torch.where(self.density >= 0, self.density * self.decay, self.density)
        fresh = torch.full_like(self.density, -1.0).scatter_reduce_(0, cells, sampled, reduce="amax")
        self.density.copy_(torch.maximum(decayed, fresh))
        known = self.density >= 0
        mean = float((self.density[known] * step_size).mean()) if bool(known.any()) else 0.0
        # a hair below the limit: cells all at the mean (a field still near its initial constant, which bf16
        # rounds to one value) stay occupied rather than all turning empty at once
        limit = min(threshold, mean) * (1.0 - 1e-3)
        self.occupied.copy_((~known | (self.density * step_size > limit)) & self.seen)


@torch.no_grad()
def cells_seen(grid: OccupancyGrid, to_world: Callable[[Tensor], Tensor], intrinsics: Tensor, c2w: Tensor,
               chunk: int = 65536) -> Tensor:
    """Which cells' centres lie in front of and inside the view of at least one pinhole camera.

    Args:
        to_world: field coordinates (M, 3) -> world points (the ray space's ``from_field``).
        intrinsics: (I, 4) fx, fy, cx, cy, the image spanning [0, 2 cx] x [0, 2 cy]; c2w: (I, 4, 4) OpenCV.
    Returns:
        (R^3,) bool.
    """
    n = grid.resolution**3
    seen = torch.zeros(n, dtype=torch.bool, device=grid.occupied.device)
    rotation, center = c2w[:, :3, :3], c2w[:, :3, 3]
    for start in range(0, n, chunk):
        index = torch.arange(start, min(start + chunk, n), device=seen.device)
        world = to_world(grid.cell_points(index, jitter=False))
        seen[index] = _pixels(world, intrinsics, rotation, center)[3].any(dim=0)
    return seen


@torch.no_grad()
def cells_in_front(grid: OccupancyGrid, to_world: Callable[[Tensor], Tensor], intrinsics: Tensor, c2w: Tensor,
                   depth: Tensor, corners: int = 1 << 20) -> Tensor:
    """Which cells lie wholly in front of ``depth`` in at least one pinhole camera: space that camera sees empty.

    A cell is in front of a camera when its eight corners project inside the image, in front of the camera, at
    depths below the least of ``depth`` at their pixels (bilinear between its cells' centres), and its projection
    spans at most two of ``depth``'s cells each way, so that a dip in ``depth`` cannot hide between its corners.

    Args:
        to_world: field coordinates (M, 3) -> world points (the ray space's ``from_field``; inf past its end).
        intrinsics: (I, 4) fx, fy, cx, cy, the image spanning [0, 2 cx] x [0, 2 cy]; c2w: (I, 4, 4) OpenCV.
        depth: (I, rows, columns) per camera, over a grid of cells of its image, the depth along its optical axis
            up to which it sees empty space (0: none).
        corners: about how many grid corners to hold at once (slabs of cells along x).
    Returns:
        (R^3,) bool.
    """
    r = grid.resolution
    device = grid.occupied.device
    axis = torch.linspace(0.0, 1.0, r + 1, device=device)
    rows, cols = depth.shape[1:]
    maps = depth.to(device=device, dtype=torch.float32).unsqueeze(1)  # (I, 1, rows, columns)
    rotation, center = c2w[:, :3, :3].to(device), c2w[:, :3, 3].to(device)
    k = intrinsics.to(device)
    free = torch.zeros((r, r, r), dtype=torch.bool, device=device)
    slab = max(1, corners // (r + 1) ** 2 - 1)
    for start in range(0, r, slab):
        stop = min(start + slab, r)
        ijk = torch.stack(torch.meshgrid(axis[start:stop + 1], axis, axis, indexing="ij"), dim=-1)
        world = to_world(grid.lo + ijk.reshape(-1, 3) * (grid.hi - grid.lo))
        finite = torch.isfinite(world).all(dim=-1)
        world = torch.where(finite.unsqueeze(-1), world, 0.0)
        for i in range(len(k)):
            cx, cy = k[i, 2], k[i, 3]
            z, u, v, inside = (x[0] for x in _pixels(world, k[i:i + 1], rotation[i:i + 1], center[i:i + 1]))
            ok = finite & inside
            u, v = torch.where(ok, u, 0.0), torch.where(ok, v, 0.0)
            where = torch.stack([u / cx - 1.0, v / cy - 1.0], dim=-1).reshape(1, 1, -1, 2)
            limit = torch.nn.functional.grid_sample(maps[i:i + 1], where, mode="bilinear", padding_mode="border",
                                                    align_corners=False).reshape(-1)
            shape = (stop - start + 1, r + 1, r + 1)
            whole = _over_corners(ok.reshape(shape), torch.amin) > 0
            nearer = _over_corners(torch.where(ok, z, torch.inf).reshape(shape), torch.amax) < _over_corners(
                limit.reshape(shape), torch.amin)
            narrow = ((_spread(u.reshape(shape)) <= 4 * cx / cols) & (_spread(v.reshape(shape)) <= 4 * cy / rows))
            free[start:stop] |= whole & nearer & narrow
    return free.reshape(-1)


def _pixels(world: Tensor, intrinsics: Tensor, rotation: Tensor, center: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """World points (M, 3) in pinhole cameras (intrinsics (I, 4), rotations (I, 3, 3), centres (I, 3), OpenCV):
    depths z, pixels u, v, and whether each lies in front of the camera inside its image [0, 2 cx] x [0, 2 cy];
    each (I, M)."""
    local = (world.unsqueeze(0) - center.unsqueeze(1)) @ rotation  # (I, M, 3) in each camera's frame
    z = local[..., 2]
    u = intrinsics[:, 0:1] * local[..., 0] / z.clamp_min(1e-9) + intrinsics[:, 2:3]
    v = intrinsics[:, 1:2] * local[..., 1] / z.clamp_min(1e-9) + intrinsics[:, 3:4]
    inside = (z > 0) & (u >= 0) & (u <= 2 * intrinsics[:, 2:3]) & (v >= 0) & (v <= 2 * intrinsics[:, 3:4])
    return z, u, v, inside


def _over_corners(lattice: Tensor, reduce: Callable[..., Tensor]) -> Tensor:
    """(A + 1, B + 1, C + 1) values at a grid's corners -> (A, B, C): ``reduce`` over each cell's eight."""
    a, b, c = (n - 1 for n in lattice.shape)
    eight = [lattice[x:x + a, y:y + b, z:z + c] for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    return reduce(torch.stack(eight).to(torch.float32) if lattice.dtype == torch.bool else torch.stack(eight), dim=0)


def _spread(lattice: Tensor) -> Tensor:
    """(A + 1, B + 1, C + 1) -> (A, B, C): the largest less the least of each cell's eight corner values."""
    return _over_corners(lattice, torch.amax) - _over_corners(lattice, torch.amin)
