"""Fields with a known answer, for testing renderers and exports against closed-form geometry."""

from __future__ import annotations

import torch
from torch import Tensor


class SphereField(torch.nn.Module):
    """A solid sphere: density ``density`` inside ``radius`` of ``center``, 0 outside; colour given by
    the position, c = (x - center) / (2 radius) + 0.5, so colours are in [0, 1] on and inside it.

    Usable wherever the renderer takes a field, ``field(points (M, 3), viewdirs (M, 3)) -> (rgb, sigma)``,
    including as the field of a ``RadianceModel``, so exports can be checked against closed-form geometry.
    """

    def __init__(self, center: tuple[float, float, float] = (0.0, 0.0, 0.0), radius: float = 0.5,
                 density: float = 1e3) -> None:
        super().__init__()
        self.register_buffer("center", torch.tensor(center, dtype=torch.float32))
        self.radius = radius
        self.density = density

    def forward(self, points: Tensor, viewdirs: Tensor | None = None, density_noise: float = 0.0) -> tuple[Tensor, Tensor]:
        offset = points - self.center.to(points)
        inside = offset.norm(dim=-1) <= self.radius
        sigma = torch.where(inside, torch.full_like(offset[..., 0], self.density), torch.zeros_like(offset[..., 0]))
        rgb = (offset / (2 * self.radius) + 0.5).clamp(0.0, 1.0)
        return rgb, sigma

    def query_density(self, points: Tensor) -> Tensor:
        return self(points)[1]

    def density_features(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """The density, and the points themselves: the colour is a function of position."""
        return self(points)[1], points

    def colour(self, points: Tensor, viewdirs: Tensor | None) -> Tensor:
        return self(points)[0]

    def intersect(self, origins: Tensor, directions: Tensor) -> Tensor:
        """First ray parameter t >= 0 where o + t d enters the sphere, inf where the ray misses it.

        Args:
            origins, directions: (R, 3); directions need not be unit length.
        Returns:
            t: (R,).
        """
        oc = origins - self.center.to(origins)
        a = (directions * directions).sum(-1)
        b = 2.0 * (oc * directions).sum(-1)
        c = (oc * oc).sum(-1) - self.radius**2
        disc = b * b - 4 * a * c
        root = torch.sqrt(disc.clamp_min(0.0))
        t0 = (-b - root) / (2 * a)
        t1 = (-b + root) / (2 * a)
        t = torch.where(t0 >= 0, t0, t1)
        return torch.where((disc >= 0) & (t >= 0), t, torch.full_like(t, float("inf")))
