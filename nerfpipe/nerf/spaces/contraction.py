"""Scene contraction for unbounded space (mip-NeRF 360, Barron et al. 2022, Eq. 10).

The scene box is mapped to [-1, 1]^3 and kept as it is; everything beyond it is squeezed into the shell
between the cube of half-size 1 and the cube of half-size 2:

    contract(x) = x                              if ||x|| <= 1
                  (2 - 1 / ||x||) x / ||x||       otherwise

with the L-infinity norm, as nerfstudio's nerfacto does, so the contracted space is the cube [-2, 2]^3 that
dense grids and an occupancy grid tile without waste. Distances shrink as 1 / ||x||^2 along a ray pointing
away from the centre, so steps of constant length in contracted space are steps that grow with the square
of the distance in the world: marching them (``Contraction.step_scale``) samples far content sparsely,
as sampling linearly in disparity does.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

BOUND = 2.0  # contracted points lie in [-BOUND, BOUND]^3


def contract(x: Tensor) -> Tensor:
    """Eq. 10 with the L-infinity norm. (..., 3) -> (..., 3) in [-2, 2]^3; the identity inside [-1, 1]^3,
    continuous across its surface, and finite for any finite input (|result| < 2)."""
    norm = x.abs().amax(dim=-1, keepdim=True)
    outside = norm > 1.0
    safe = torch.where(outside, norm, torch.ones_like(norm))
    return torch.where(outside, (2.0 - 1.0 / safe) * (x / safe), x)


def uncontract(y: Tensor) -> Tensor:
    """The inverse of ``contract`` on (-2, 2)^3: a contracted norm m > 1 came from the norm 1 / (2 - m).
    Points at |y| = 2 map to infinity; callers keep inside."""
    m = y.abs().amax(dim=-1, keepdim=True)
    outside = m > 1.0
    safe = torch.where(outside, m, torch.ones_like(m))
    return torch.where(outside, y / safe / (2.0 - safe), y)


@dataclass(frozen=True)
class Contraction:
    """World points -> contracted field coordinates: the box [lo, hi] (the scene box) becomes [-1, 1]^3 and
    the world beyond it the shell up to [-2, 2]^3."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    def _center_half(self, like: Tensor) -> tuple[Tensor, Tensor]:
        lo = torch.as_tensor(self.lo, dtype=like.dtype, device=like.device)
        hi = torch.as_tensor(self.hi, dtype=like.dtype, device=like.device)
        return (lo + hi) / 2.0, (hi - lo) / 2.0

    def to_field(self, points: Tensor) -> Tensor:
        """World points (..., 3) -> contracted coordinates (..., 3)."""
        center, half = self._center_half(points)
        return contract((points - center) / half)

    def from_field(self, points: Tensor) -> Tensor:
        """Contracted coordinates (..., 3) in (-2, 2)^3 -> world points."""
        center, half = self._center_half(points)
        return uncontract(points) * half + center

    def field_length(self, directions: Tensor) -> Tensor:
        """How far one unit of ray parameter t moves inside the box, in its normalized units. (R, 3) -> (R,)."""
        _, half = self._center_half(directions)
        return torch.linalg.vector_norm(directions / half, dim=-1)

    def box_rays(self, origins: Tensor, directions: Tensor) -> tuple[Tensor, Tensor]:
        """Rays (R, 3) in the units where the box is [-1, 1]^3 (before contraction): origins and directions."""
        center, half = self._center_half(origins)
        return (origins - center) / half, directions / half

    @staticmethod
    def step_scale_at(norm: Tensor) -> Tensor:
        """``step_scale`` from the L-infinity norm n of a point in the box's units before contraction: 1 inside
        the box, n^2 beyond (1 / (2 - m)^2 with m = 2 - 1 / n), without contracting the point first."""
        return norm.clamp(1.0, 1e6).square()  # 1e6: step_scale's cap, m <= 2 - 1e-6

    @staticmethod
    def step_scale(field_points: Tensor) -> Tensor:
        """By how much a world step must grow at contracted points (..., 3) to stay the same length in
        contracted space, along a ray leaving the centre: 1 inside the box, the squared world norm
        1 / (2 - m)^2 beyond it (contraction shrinks radial distances by its derivative 1 / ||x||^2)."""
        m = field_points.abs().amax(dim=-1).clamp(max=BOUND - 1e-6)
        return Contraction.step_scale_at(1.0 / (2.0 - m))  # the norm before contraction: m = 2 - 1 / n
