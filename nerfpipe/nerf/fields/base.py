"""Fields: (x, d) -> (rgb, sigma), the part of a model that is learned.

Every field answers the same few questions, so that the model, the samplers and the exports never ask
which kind it is. The registered ones (``nerfpipe.nerf.registry.FIELDS``): the grid field
(``nerfpipe.nerf.fields.grid``) with its hashed (``hash_field``) and factorized-plane (``plane_field``) kinds,
and the paper's MLP (``nerfpipe.nerf.fields.mlp``). A new field is a class
with these members and a line in the registry.
"""

from __future__ import annotations

from typing import Any, ClassVar, Protocol

from torch import Tensor

from nerfpipe.nerf.registry import FIELDS, resolve

Box = tuple[tuple[float, ...], tuple[float, ...]]


class Field(Protocol):
    """A radiance field as the model uses it (an ``nn.Module``)."""

    kind: ClassVar[str]  # its name in the registry
    needs_box: ClassVar[bool]  # whether it spans a bounded box (an unbounded scene must then be contracted)
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

    @staticmethod
    def spec_of(params: Any, box: Box | None) -> dict[str, Any]:
        """The spec ``nerfpipe.nerf.config.FieldParams`` asks for over ``box`` (field coordinates; None: unbounded)."""

    @classmethod
    def from_spec(cls, spec: dict[str, Any]) -> "Field":
        """Rebuilt from ``spec()`` (model.json), before its weights are loaded."""

    def spec(self) -> dict[str, Any]:
        """What ``from_spec`` rebuilds it from; ``spec_of`` gives the same for parameters."""

    @staticmethod
    def describe(spec: dict[str, Any]) -> str | None:
        """A sentence for the train log about the field ``spec`` describes, or None for the paper's own."""

    def parameters(self) -> Any: ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: dict[str, Any]) -> Any: ...

    def train(self, mode: bool = True) -> Any: ...

    def eval(self) -> Any: ...

    def to(self, device: Any) -> Any: ...


def field_class(kind: str) -> type:
    return resolve(FIELDS, kind)


def field_spec(field: Field) -> dict[str, Any]:
    return {"kind": field.kind, **field.spec()}
