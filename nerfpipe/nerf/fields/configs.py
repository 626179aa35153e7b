"""Each field kind's settings: the user's ``train.field`` group and the field's spec in ``model.json`` at once.

``--set train.field.kind=hash`` picks ``HashConfig`` (``nerfpipe.nerf.registry.FIELDS``); its fields are the
parameters ``train.field.*`` of that kind, validated here once, and the field is built from it
(``Field.from_config``). Torch-free, so that naming and checking a setting imports no torch. A new kind is a
config with a ``kind`` of its own and a ``target`` (its class), beside that class, and a line in the registry.
"""

from __future__ import annotations

import dataclasses

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

from nerfpipe.pipeline.params import param
from nerfpipe.pipeline.resources import check_memory

# Memory: what a size costs, checked against ``memory_limit`` before anything runs. Training holds each table
# four times (values, gradients, Adam's two moments).
TRAINING_COPIES = 4
FLOAT_BYTES = 4


def level_resolutions(levels: int, min_resolution: int, max_resolution: int) -> list[int]:
    """Each level's cells a side, geometric from ``min_resolution`` to ``max_resolution``: how the grid fields lay
    their levels, and what their tables' sizes are reckoned from before any torch runs."""
    if levels == 1:
        return [max_resolution]
    growth = (max_resolution / min_resolution) ** (1.0 / (levels - 1))
    return [int(round(min_resolution * growth**i)) for i in range(levels)]


def at_least(config: object, minimum: float, *names: str) -> None:
    """Raise ``ValueError`` naming the first of ``names`` below ``minimum``."""
    for name in names:
        value = getattr(config, name)
        if value < minimum:
            raise ValueError(f"{name} must be >= {minimum:g}, got {value}")


@dataclass(frozen=True)
class FieldConfig:
    """What every field kind's config answers. ``target``: "module:Class" of its field (or the class)."""

    kind: str = "?"

    target: ClassVar[Any]
    needs_box: ClassVar[bool] = True  # whether it spans a bounded box (an unbounded scene must then be contracted)
    sampler: ClassVar[str] = "marching"  # the sampler ``train.sampler.kind=auto`` gives it
    two_fields: ClassVar[bool] = False  # whether a hierarchical sampler's fine pass gets a field of its own

    def training_bytes(self) -> int:
        """Bytes its learned values take while training (``TRAINING_COPIES`` of each)."""
        return 0

    def sample_bytes(self) -> int:
        """About what one sample of a training batch holds for the backward pass."""
        return 0

    def describe(self) -> str | None:
        """A sentence for the train log, or None for the paper's own field."""
        return None

    def for_space(self, contracted: bool) -> "FieldConfig":
        """This config with what it leaves to the space decided: ``contracted`` where the space beyond the scene box
        is contracted into a shell (``nerfpipe.nerf.policy.contracts``)."""
        return self


@dataclass(frozen=True)
class GridConfig(FieldConfig):
    """Dense feature grids and a small MLP (Instant-NGP's field without its hash)."""

    kind: str = "grid"
    levels: int = param(3, "levels of the multiresolution grid", bounds=(1, 32))
    min_resolution: int = param(32, "cells a side of the coarsest level", bounds=(1, 4096))
    max_resolution: int = param(128, "cells a side of the finest level", bounds=(1, 8192))
    features: int = param(4, "features per vertex and level", bounds=(1, 64))
    hidden: int = param(0, "width of its MLPs; 0: by the space, 32 where the space beyond the box is contracted (its "
                           "fog costs a ray 34 samples: beer and the cup score the same as at 64 in equal time and "
                           "render 1.1-1.35x the rays a second), else 64 (a ray costs 5 in the temple's box, where 32 "
                           "scored 0.2-0.4 dB less)", bounds=(0, 1024))
    dir_freqs: int = param(0, "L for directions; 0: d itself, colour a smooth function of direction (the temple's 14 "
                              "photos: 28.6-28.8 dB, against 26.7-27.0 at 4, which fits each photo's own direction); "
                              "Section 5.1: 4", bounds=(0, 16))
    view_dependence: bool = param(True, "colour depends on the viewing direction; false is Table 2's 'No View Dependence'")

    target: ClassVar[Any] = "nerfpipe.nerf.fields.grid:GridField"
    # the MLPs' width by the space (``hidden`` 0): the cost of a sample's MLPs scales with the samples a ray takes
    widths: ClassVar[dict[bool, int]] = {True: 32, False: 64}
    geo_features: ClassVar[int] = 15  # the density MLP's outputs beside density, which the colour MLP reads
    init_scale: ClassVar[float] = 1e-4  # the tables start uniform in [-init_scale, init_scale]

    def __post_init__(self) -> None:
        at_least(self, 1, "levels", "min_resolution", "max_resolution", "features")
        at_least(self, 0, "dir_freqs", "hidden")
        if self.min_resolution > self.max_resolution:
            raise ValueError("min_resolution must not exceed max_resolution")
        check_memory("max_resolution, levels, features", "the feature tables, while training,", self.training_bytes())

    @property
    def width(self) -> int:
        """Its MLPs' width: ``hidden``, or where that was left to the space and ``for_space`` did not decide, a box's."""
        return self.hidden or self.widths[False]

    def for_space(self, contracted: bool) -> "GridConfig":
        return self if self.hidden else dataclasses.replace(self, hidden=self.widths[contracted])

    def resolutions(self) -> list[int]:
        return level_resolutions(self.levels, self.min_resolution, self.max_resolution)

    def level_sizes(self) -> list[int]:
        """Rows of each level's table: its dense vertex count."""
        return [(r + 1) ** 3 for r in self.resolutions()]

    def training_bytes(self) -> int:
        return TRAINING_COPIES * sum(self.level_sizes()) * self.features * FLOAT_BYTES

    def sample_bytes(self) -> int:
        """Its trilinear corners (an index and a weight each), their features, and the MLPs' activations."""
        corners = 8 * self.levels * (self.features + 3)
        return 2 * FLOAT_BYTES * (corners + 4 * self.width)

    def describe(self) -> str | None:
        return f"grid field: {self.levels} levels of {self.resolutions()} cells a side, {self.features} features " \
               f"each, and a {self.width}-wide MLP"


@dataclass(frozen=True)
class HashConfig(GridConfig):
    """The grid field with its fine levels hashed (Instant-NGP)."""

    kind: str = "hash"
    log2_table: int = param(19, "rows of each hashed level's table, as a power of 2 (Instant-NGP: 19)", bounds=(10, 24))

    target: ClassVar[Any] = "nerfpipe.nerf.fields.hash:HashGridField"

    def __post_init__(self) -> None:
        if not 10 <= self.log2_table <= 24:
            raise ValueError(f"log2_table must be in [10, 24], got {self.log2_table}")
        super().__post_init__()

    def level_sizes(self) -> list[int]:
        """Rows of each level: its dense vertex count, or the table size where that is smaller."""
        return [min((r + 1) ** 3, 2**self.log2_table) for r in self.resolutions()]

    def describe(self) -> str | None:
        hashed = sum(size < (r + 1) ** 3 for size, r in zip(self.level_sizes(), self.resolutions()))
        return (f"hash-grid field: {self.levels} levels of {self.resolutions()[0]} to {self.resolutions()[-1]} cells "
                f"a side, the finest {hashed} hashed into tables of 2^{self.log2_table} rows, {self.features} "
                f"features each, and a {self.width}-wide MLP")


@dataclass(frozen=True)
class PlanesConfig(GridConfig):
    """The grid field with three factorized planes a level (K-Planes)."""

    kind: str = "planes"

    target: ClassVar[Any] = "nerfpipe.nerf.fields.planes:PlaneField"
    init_low: ClassVar[float] = 0.1  # K-Planes' initialization, uniform in [0.1, 0.5]: the products start small, not 0
    init_high: ClassVar[float] = 0.5

    def level_sizes(self) -> list[int]:
        """Rows of each level: its three planes of (r + 1)^2 vertices."""
        return [3 * (r + 1) ** 2 for r in self.resolutions()]

    def describe(self) -> str | None:
        values = sum(self.level_sizes()) * self.features
        return (f"tri-plane field: {self.levels} levels of three planes of {self.resolutions()[0]} to "
                f"{self.resolutions()[-1]} cells a side ({values / 1e6:.1f} M values), {self.features} features "
                f"each, multiplied across the planes, and a {self.width}-wide MLP")


@dataclass(frozen=True)
class MlpConfig(FieldConfig):
    """The paper's MLP (Fig. 7), smaller by default: 4 layers of 128 where the paper has 8 of 256."""

    kind: str = "mlp"
    depth: int = param(4, "layers of the trunk (the paper: 8)", bounds=(1, 32))
    width: int = param(128, "channels per trunk layer (the paper: 256)", bounds=(1, 2048))
    view_width: int = param(64, "channels of the view-direction layer (the paper: 128)", bounds=(1, 2048))
    skip_after: int = param(0, "concatenate the encoded input to this layer's activation (the paper: 5; 0: none)", bounds=(0, 31))
    positional_encoding: bool = param(True, "encode x and d with Eq. 4; false is Table 2's 'No Pos. Encoding'")
    pos_freqs: int = param(10, "L for positions (Section 5.1: 10)", bounds=(0, 24))
    dir_freqs: int = param(0, "L for directions; 0: d itself; Section 5.1: 4", bounds=(0, 16))
    include_input: bool = param(True, "feed the raw coordinates beside their encoding (the authors' code does)")
    view_dependence: bool = param(True, "colour depends on the viewing direction; false is Table 2's 'No View Dependence'")
    density_activation: Literal["relu", "softplus"] = param("softplus", "relu (the paper) or softplus")
    fine_network: bool = param(False, "a separate fine network (the paper); false reuses the coarse one")

    target: ClassVar[Any] = "nerfpipe.nerf.fields.mlp:NerfField"
    needs_box: ClassVar[bool] = False  # it takes any point
    sampler: ClassVar[str] = "hierarchical"

    def __post_init__(self) -> None:
        at_least(self, 1, "depth", "width", "view_width")
        at_least(self, 0, "skip_after", "pos_freqs", "dir_freqs")
        if self.skip_after > self.depth - 1:
            raise ValueError(f"skip_after must be below depth ({self.depth}), got {self.skip_after}")

    @property
    def two_fields(self) -> bool:  # type: ignore[override]
        return self.fine_network

    def skips(self) -> tuple[int, ...]:
        """The trunk layers after which the encoded input joins again (0-based)."""
        return (self.skip_after - 1,) if self.skip_after else ()

    def sample_bytes(self) -> int:
        return 2 * FLOAT_BYTES * (self.depth * self.width + 6 * (3 + 6 * self.pos_freqs))
