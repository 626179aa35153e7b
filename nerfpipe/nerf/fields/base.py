"""Fields: (x, d) -> (rgb, sigma), the part of a model that is learned.

Every field answers the same few questions, so that the model, the samplers and the exports never ask
which kind it is. The registered ones (``nerfpipe.nerf.registry.FIELDS``): the grid field
(``nerfpipe.nerf.fields.grid``) with its hashed (``hash``) and factorized-plane (``planes``) kinds,
and the paper's MLP (``nerfpipe.nerf.fields.mlp``). A new field is a class
with these members and a line in the registry.
"""

from __future__ import annotations

from typing import Any, Protocol

from torch import Tensor


Box = tuple[tuple[float, ...], tuple[float, ...]]


class Field(Protocol):
    """A radiance field as the model uses it (an ``nn.Module``)."""

    training: bool

    def __call__(self, x: Tensor, d: Tensor | None = None, density_noise: float = 0.0) -> tuple[Tensor, Tensor]:
        """x: (M, 3) field coordinates, d: (M, 3) unit view directions -> rgb (M, 3) in [0, 1], sigma (M,) >= 0."""

    def query_density(self, x: Tensor) -> Tensor:
        """sigma (M,) at x (M, 3), without colour."""

    def density_features(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """sigma (M,) at x (M, 3) and the features (M, F) ``colour`` reads: a field evaluated in two halves,
        so that rendering without gradients reuses the density its sampler looked at
        (``nerfpipe.nerf.samplers.march.visible``)."""

    def colour(self, features: Tensor, d: Tensor | None) -> Tensor:
        """rgb (M, 3) in [0, 1] from ``density_features``' features and unit view directions d (M, 3):
        ``field(x, d)`` is ``(colour(density_features(x)[1], d), density_features(x)[0])``."""

    config: Any  # its ``nerfpipe.nerf.fields.configs.FieldConfig``: the user's settings, and its spec

    @classmethod
    def from_config(cls, config: Any, box: Box | None) -> "Field":
        """Built from its config over ``box`` (field coordinates; None: unbounded), before any weights load."""

    def box(self) -> Box | None:
        """The box it spans, as ``from_config`` took it."""

    def parameters(self) -> Any: ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: dict[str, Any]) -> Any: ...

    def train(self, mode: bool = True) -> Any: ...

    def eval(self) -> Any: ...

    def to(self, device: Any) -> Any: ...


