"""The grid field with factorized planes: K-Planes' multiscale tri-plane (Fridovich-Keil et al. 2023, Section 3).

Each level holds three 2D feature planes, over (x, y), (x, z) and (y, z), of ``r + 1`` vertices a side.
A point's feature at that level is the element-wise product of its three bilinear samples (K-Planes'
Hadamard product: unlike a sum it can single out one 3D cell, an AND of three 2D ones), and the levels'
features are concatenated for the grid field's MLPs. So a finest level of 1024 cells a side costs
3 x 1025^2 rows, where the dense grid would need 1025^3 and the hash grid shares 2^19 rows by collision.

Everything else -- the one stacked (rows, features) table, its row gather and scatter, the MLPs -- is the grid field's (``nerfpipe.nerf.fields.grid``).
"""

from __future__ import annotations

import torch
from torch import Tensor

from nerfpipe.nerf.fields.configs import PlanesConfig
from nerfpipe.nerf.fields.grid import GridField, grid_cells

PLANES = ((0, 1), (0, 2), (1, 2))  # the axes each plane spans


def bilinear_corners(u: Tensor, resolutions: Tensor, offsets: Tensor) -> tuple[Tensor, Tensor]:
    """Vertices and weights of bilinear interpolation on the three planes of each level.

    Args:
        u: (M, 3) in [0, 1] (clamped); resolutions: (L,) cells a side; offsets: (L,) the row of each level's
            first plane, whose plane p (``PLANES``) holds vertex (i, j) at offset_l + (p (r+1) + i) (r+1) + j.
    Returns:
        index: (3 L, 4, M) rows, plane-major (level l's plane p at p L + l); weights: (3 L, 4, M), summing
        to 1 over the 4 corners (corner c = 2 da + db).
    """
    i0, f, n = grid_cells(u, resolutions)
    index, weights = [], []
    for plane, (a, b) in enumerate(PLANES):
        base = offsets.view(-1, 1) + (plane * n + i0[:, a]) * n + i0[:, b]  # (L, M)
        wa, wb = (1.0 - f[:, a], f[:, a]), (1.0 - f[:, b], f[:, b])
        index.append(torch.stack([base + da * n + db for da in (0, 1) for db in (0, 1)], dim=1))  # (L, 4, M)
        weights.append(torch.stack([wa[da] * wb[db] for da in (0, 1) for db in (0, 1)], dim=1))
    return torch.cat(index), torch.cat(weights)


class PlaneField(GridField):
    """The grid field whose levels are three factorized planes each (K-Planes), fine enough for the photos."""

    def __init__(self, lo: tuple[float, ...], hi: tuple[float, ...], config: PlanesConfig = PlanesConfig()) -> None:
        super().__init__(lo, hi, config)
        with torch.no_grad():
            self.table.uniform_(config.init_low, config.init_high)

    def corners(self, u: Tensor) -> tuple[Tensor, Tensor]:
        return bilinear_corners(u, self.resolutions, self.offsets)

    def combine(self, features: Tensor) -> Tensor:
        """(M, 3 L, F) plane samples, plane-major -> (M, L F): the product of each level's three planes."""
        m, planes, width = features.shape
        return features.view(m, 3, planes // 3, width).prod(dim=1).flatten(1)  # no -1: M may be 0
