"""Each sampler kind's settings: the user's ``train.sampler`` group and the sampler's spec in ``model.json``.

``--set train.sampler.kind=hierarchical`` picks ``HierarchicalConfig`` (``nerfpipe.nerf.registry.SAMPLERS``);
``auto`` gives the one the field asks for (``FieldConfig.sampler``). Torch-free, as the field configs are.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from nerfpipe.nerf.fields.configs import at_least
from nerfpipe.pipeline.params import Auto, param
from nerfpipe.pipeline.resources import check_memory

OCCUPANCY_CELL_BYTES = 24  # a cell's density, flags and the indices and maxima of an update
# what a march lays out before the occupancy grid culls it: 4 steps + 1 candidates a ray (``march``), about
# CANDIDATE_BYTES each (start, end, t, a point, its index and flags)
CANDIDATE_BYTES = 48


@dataclass(frozen=True)
class SamplerConfig:
    """What every sampler kind's config answers. ``target``: "module:Class" of its sampler (or the class)."""

    kind: str = "?"

    target: ClassVar[Any]
    needs_box: ClassVar[bool] = False  # whether it grids the field box (an unbounded scene has none)

    def fields(self) -> int:
        """Fields its samples are evaluated with: 1, or 2 (coarse, then fine)."""
        return 1

    def step_samples(self, batch_rays: int, batch_samples: int) -> int:
        """Samples a training step evaluates at most."""
        return batch_rays

    def step_candidates(self, batch_rays: int, batch_samples: int) -> int:
        """Candidates a step lays out before culling them to its samples (0: none)."""
        return 0

    def step_bytes(self, sample_bytes: int, batch_rays: int, batch_samples: int) -> int:
        """About what one training step holds: its samples, or the candidates laid out for them."""
        return max(self.step_samples(batch_rays, batch_samples) * sample_bytes,
                   self.step_candidates(batch_rays, batch_samples) * CANDIDATE_BYTES)

    def describe(self) -> str | None:
        """A sentence for the train log, or None for the paper's own sampling."""
        return None


@dataclass(frozen=True)
class MarchingConfig(SamplerConfig):
    """Empty-space skipping: rays march the occupied cells of an occupancy grid (Instant-NGP).

    Instant-NGP marches 1024 steps at 800 px, a step about the size of a grid cell; a cell is occupied when one
    step through its density is more than ``occupancy_threshold`` optically thick (nerfacc's 0.01), or above
    the grid's mean when that is lower (early in training)."""

    kind: str = "marching"
    occupancy_resolution: int = param(64, "cells a side of the occupancy grid", bounds=(1, 1024))
    steps: int = param(128, "marching steps along the field box's diagonal (about one per image pixel at 100 px lego)", bounds=(1, 100_000))
    early_stop: float = param(1e-4, "stop a marched ray once its transmittance is below this (0: never)", bounds=(0.0, 0.99))
    occupancy_threshold: float = param(0.01, "a cell is occupied when one step through it is this optically thick", bounds=(0.0, 1000.0))
    carve: float = param(0.5, "cells a training photo sees in front of this share of the depth of its nearest sparse points (over a sixteenth of its side) are empty for good (0: none)", bounds=(0.0, 0.99))

    target: ClassVar[Any] = "nerfpipe.nerf.samplers.marching:MarchingSampler"
    needs_box: ClassVar[bool] = True
    update_every: ClassVar[int] = 16  # training steps between grid updates (Instant-NGP: 16)
    warmup: ClassVar[int] = 256  # updates before this step evaluate every cell; later ones a quarter at random
    #                               plus a quarter of the occupied ones (Instant-NGP)

    def __post_init__(self) -> None:
        at_least(self, 1, "occupancy_resolution", "steps")
        at_least(self, 0, "occupancy_threshold")
        if not (0 <= self.early_stop < 1):
            raise ValueError(f"early_stop must be in [0, 1), got {self.early_stop}")
        if not (0 <= self.carve < 1):
            raise ValueError(f"carve must be in [0, 1), got {self.carve}")
        check_memory("occupancy_resolution", "the occupancy grid's cells", OCCUPANCY_CELL_BYTES * self.occupancy_resolution**3)

    def step_samples(self, batch_rays: int, batch_samples: int) -> int:
        """Rays adapt to ``batch_samples`` and evaluate at most twice as many; without it, ``steps`` a ray."""
        return 2 * batch_samples if batch_samples else batch_rays * self.steps

    def step_candidates(self, batch_rays: int, batch_samples: int) -> int:
        """4 steps + 1 a ray, for up to 16 x batch_rays rays a step while the rays adapt to batch_samples."""
        return (16 if batch_samples else 1) * batch_rays * (4 * self.steps + 1)

    def describe(self) -> str | None:
        return (f"empty-space skipping: a {self.occupancy_resolution}^3 occupancy grid over the field box, "
                f"{self.steps} marching steps along its diagonal, rays stop at transmittance "
                f"{self.early_stop:g} (instead of N_c + N_f samples per ray)")


@dataclass(frozen=True)
class HierarchicalConfig(SamplerConfig):
    """Section 5.2: N_c stratified samples, N_f more from the coarse weights."""

    kind: str = "hierarchical"
    n_coarse: int = param(32, "N_c stratified samples per ray (the paper: 64)", bounds=(1, 4096))
    n_fine: int = param(64, "N_f samples from the coarse weights (the paper: 128; 0: no hierarchical sampling)", bounds=(0, 4096))
    hierarchical: bool = param(True, "hierarchical sampling; false is Table 2's 'No Hierarchical' (N_c samples only)")
    lindisp: Auto = param("auto", "sample linearly in disparity; auto: for unbounded scenes")

    target: ClassVar[Any] = "nerfpipe.nerf.samplers.hierarchical:HierarchicalSampler"

    def __post_init__(self) -> None:
        at_least(self, 1, "n_coarse")
        at_least(self, 0, "n_fine")

    @property
    def fine(self) -> int:
        """N_f as drawn: 0 without hierarchical sampling."""
        return self.n_fine if self.hierarchical else 0

    def fields(self) -> int:
        return 2 if self.fine > 0 else 1

    def step_samples(self, batch_rays: int, batch_samples: int) -> int:
        return batch_rays * (self.n_coarse + self.fine)
