"""The grid field with Instant-NGP's multiresolution hash encoding (Mueller et al. 2022, Section 3).

Levels whose dense grid has at most ``2**log2_table`` vertices stay dense (a one-to-one table, as
Instant-NGP keeps its coarse levels); each finer level maps its vertex (i, j, k) into a table of that many
rows by the spatial hash of Eq. 4 there, (i * 1 xor j * 2654435761 xor k * 805459861) mod T, and lets its
collisions be averaged out by the gradients, the MLP telling the colliding points apart by the other levels.
So a finest level of 1024 or 2048 cells a side costs the memory of ``2**log2_table`` rows, not 1025^3.

Everything else -- the one stacked (rows, features) table, the trilinear gather and scatter of
``nerfpipe.nerf.fields.grid``, the MLPs -- is the grid field's.
"""

from __future__ import annotations

import torch
from torch import Tensor

from nerfpipe.nerf.fields.grid import CORNERS, GridField, corner_weights, grid_cells

PRIMES = (1, 2654435761, 805459861)  # Instant-NGP's hash, one prime per axis (the first is 1 for coherence)


def hashed_corners(u: Tensor, resolutions: Tensor, offsets: Tensor, sizes: Tensor) -> tuple[Tensor, Tensor]:
    """``nerfpipe.nerf.fields.grid.trilinear_corners`` for levels of which some are hashed.

    Args:
        u: (M, 3) in [0, 1] (clamped); resolutions, offsets: (L,) as there; sizes: (L,) rows of each level:
            a level with fewer rows than (r + 1)^3 vertices is hashed into them (a power of two).
    Returns:
        index: (L, 8, M) rows of the stacked table; weights: (L, 8, M), summing to 1 over the corners.
    """
    i0, f, n = grid_cells(u, resolutions)
    d = CORNERS.to(u.device).t().unsqueeze(-1)  # (3, 8, 1)
    x, y, z = (i0[:, a].unsqueeze(1) + d[a] for a in range(3))  # (L, 8, M) each: the corners' vertices
    n = n.unsqueeze(-1)  # (L, 1, 1)
    dense = (x * n + y) * n + z
    hashed = torch.bitwise_and(torch.bitwise_xor(torch.bitwise_xor(x * PRIMES[0], y * PRIMES[1]), z * PRIMES[2]),
                               (sizes - 1).view(-1, 1, 1))
    is_hashed = (sizes < n.view(-1) ** 3).view(-1, 1, 1)  # (L, 1, 1)
    return torch.where(is_hashed, hashed, dense) + offsets.view(-1, 1, 1), corner_weights(f)


class HashGridField(GridField):
    """The grid field whose fine levels are hashed (Instant-NGP), so they can be as fine as the photos."""

    def corners(self, u: Tensor) -> tuple[Tensor, Tensor]:
        return hashed_corners(u, self.resolutions, self.offsets, self.sizes)

    native_corners = corners  # the native kernels hash these levels as Eq. 4 does (``grid.natively_cornered``)
