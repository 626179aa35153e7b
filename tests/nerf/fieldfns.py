"""Fields made from plain functions, rendered through the same ``RadianceModel.render`` a trained field is."""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor

from nerfpipe.nerf.fields.configs import MlpConfig
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.spaces.ray_space import BoxSpace
from nerfpipe.nerf.spaces.rays import RayBatch
from nerfpipe.nerf.render.volume import RenderOutput

FieldFn = Callable[[Tensor, Tensor], tuple[Tensor, Tensor]]

# Fig. 7's MLP as Section 5.1 gives it: 8 layers of 256, gamma(x) again after the fifth, a 128-unit view branch,
# L = 10 and 4, no raw coordinates beside their encoding, ReLU density
PAPER_MLP = dict(depth=8, width=256, skip_after=5, view_width=128, pos_freqs=10, dir_freqs=4, include_input=False,
                 density_activation="relu")


def paper_mlp(**changes) -> MlpConfig:
    """The paper's MLP config with ``changes``; a trunk too shallow for the fifth layer's skip has none."""
    values = {**PAPER_MLP, **changes}
    if "skip_after" not in changes and values["depth"] <= values["skip_after"]:
        values["skip_after"] = 0
    return MlpConfig(**values)


class FnField(torch.nn.Module):
    """A field of the function ``fn(points (M, 3), viewdirs (M, 3)) -> (rgb (M, 3), sigma (M,))``."""

    kind = "fn"

    def __init__(self, fn: FieldFn) -> None:
        super().__init__()
        self.fn = fn
        self.register_buffer("anchor", torch.zeros(1))  # where the model finds its device

    def forward(self, x: Tensor, d: Tensor | None = None, density_noise: float = 0.0) -> tuple[Tensor, Tensor]:
        return self.fn(x, torch.zeros_like(x) if d is None else d)

    def query_density(self, x: Tensor) -> Tensor:
        return self.fn(x, torch.zeros_like(x))[1]

    def density_features(self, x: Tensor) -> tuple[Tensor, Tensor]:
        return self.query_density(x), x

    def colour(self, x: Tensor, d: Tensor | None) -> Tensor:
        return self.fn(x, torch.zeros_like(x) if d is None else d)[0]


def model_of(coarse: FieldFn, fine: FieldFn | None, sampler, space=None) -> RadianceModel:
    return RadianceModel(FnField(coarse), None if fine is None else FnField(fine), sampler, space or BoxSpace(), None)


def render_fields(coarse: FieldFn, fine: FieldFn | None, rays: RayBatch, sampler, background: Tensor | None = None,
                  train: bool = False, generator: torch.Generator | None = None, space=None) -> RenderOutput:
    """``rays`` rendered by a model of these fields and ``sampler``, as ``RadianceModel.render`` does."""
    return model_of(coarse, fine, sampler, space).render(rays, train=train, generator=generator, background=background)
