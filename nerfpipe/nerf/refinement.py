"""Camera refinement: per training image, a correction of its pose learned with the field (SO(3) x R^3).

Image i's camera-to-world pose [R | c] becomes [exp(w_i) R | c + t_i]: the camera turns by the rotation
vector w_i (world axes, about its own centre; ``kornia.geometry.liegroup.So3.exp``) and its centre moves by
t_i. Rotation and translation are kept apart, so a turn of the camera does not also swing its centre
around the world origin, as a correction on the left of the whole pose would.

Gauge: the field and all cameras together can move rigidly without changing a single pixel, so the
corrections are centred -- their mean over the images is removed -- and only the cameras' motion relative
to each other is learned; held-out views, whose poses are not refined, stay in the frame they were in.
"""

from __future__ import annotations

import math

import torch
from kornia.geometry.liegroup import So3
from torch import Tensor, nn


class PoseRefinement(nn.Module):
    """Per training image, a rotation vector and a translation (I, 6: w, t); zero (no change) at initialisation."""

    def __init__(self, images: int) -> None:
        super().__init__()
        self.tangent = nn.Parameter(torch.zeros(images, 6))

    def centred(self) -> Tensor:
        """(I, 6) the corrections less their mean over the images (the gauge above)."""
        return self.tangent - self.tangent.mean(dim=0, keepdim=True)

    def forward(self, c2w: Tensor) -> Tensor:
        """The refined poses (I, 4, 4) of the images' poses ``c2w`` (I, 4, 4)."""
        v = self.centred().to(c2w.dtype)
        rotation = So3.exp(v[:, :3]).matrix()
        out = c2w.clone()
        out[:, :3, :3] = rotation @ c2w[:, :3, :3]
        out[:, :3, 3] = c2w[:, :3, 3] + v[:, 3:]
        return out

    def penalty(self) -> Tensor:
        """Mean squared size of the corrections: the regulariser that keeps a camera put when the photos do
        not say where to move it."""
        return (self.centred() ** 2).sum(dim=-1).mean()

    def moved(self) -> tuple[Tensor, Tensor]:
        """How far each camera moved: rotation in degrees (I,) and centre displacement in world units (I,)."""
        v = self.centred().detach()
        return v[:, :3].norm(dim=-1) * (180.0 / math.pi), v[:, 3:].norm(dim=-1)


def rotation_error_deg(a: Tensor, b: Tensor) -> Tensor:
    """The angle in degrees (N,) of the rotation between the rotations of poses a and b (N, 4, 4) or (N, 3, 3)."""
    relative = a[..., :3, :3].transpose(-1, -2) @ b[..., :3, :3]
    return torch.rad2deg(So3.from_matrix(relative).log().norm(dim=-1))
