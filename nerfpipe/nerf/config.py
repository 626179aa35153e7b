"""The train stage's parameter groups, as ``--set train.GROUP.NAME=VALUE`` names them.

Each group is the user-facing configuration of one part of the model, validated here once:
``field`` (``nerfpipe.nerf.fields.base``), ``sampler`` (``nerfpipe.nerf.samplers.base``), ``space`` (the ray space
and scene box, ``nerfpipe.nerf.policy``), ``optim`` (``nerfpipe.nerf.train.trainer``) and ``per_image``
(``nerfpipe.nerf.appearance``, ``nerfpipe.nerf.refinement``). This module imports no torch, so listing
the parameters (``nerfpipe stages``) stays quick and training can set torch's CPU state before torch runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from nerfpipe.nerf.registry import FIELDS, SAMPLERS, check
from nerfpipe.pipeline.params import Auto, param
from nerfpipe.pipeline.resources import check_memory


# Memory: what a size costs, checked against ``memory_limit`` before anything runs. Training holds each table
# four times (values, gradients, Adam's two moments).
TRAINING_COPIES = 4
FLOAT_BYTES = 4
OCCUPANCY_CELL_BYTES = 24  # a cell's density, flags and the indices and maxima of an update


def level_resolutions(levels: int, min_resolution: int, max_resolution: int) -> list[int]:
    """Each level's cells a side, geometric from ``min_resolution`` to ``max_resolution``: how the grid fields lay
    their levels, and what their tables' sizes are reckoned from before any torch runs."""
    if levels == 1:
        return [max_resolution]
    growth = (max_resolution / min_resolution) ** (1.0 / (levels - 1))
    return [int(round(min_resolution * growth**i)) for i in range(levels)]


def _resolutions(params: "FieldParams") -> list[int]:
    return level_resolutions(params.levels, params.min_resolution, params.max_resolution)


def _dense_rows(params: "FieldParams") -> int:
    return sum((r + 1) ** 3 for r in _resolutions(params))


# rows of a field's feature tables, by kind: a kind not listed (a new part) is sized as dense grids, the most
_TABLE_ROWS = {
    "grid": _dense_rows,
    "hash": lambda p: sum(min((r + 1) ** 3, 1 << p.log2_table) for r in _resolutions(p)),
    "planes": lambda p: sum(3 * (r + 1) ** 2 for r in _resolutions(p)),
    "mlp": lambda p: 0,
}


def field_training_bytes(params: "FieldParams") -> int:
    """Bytes the field's feature tables take while training (``TRAINING_COPIES`` of each)."""
    rows = _TABLE_ROWS.get(params.kind, _dense_rows)(params)
    return TRAINING_COPIES * rows * params.features * FLOAT_BYTES


def sample_bytes(field: "FieldParams") -> int:
    """About what one sample of a training batch holds for the backward pass: its trilinear corners (an index
    and a weight each), their features, the encoding and the MLPs' activations."""
    corners = 8 * field.levels * (field.features + 3)
    activations = max(4 * field.hidden, field.depth * field.width) + 6 * (3 + 6 * field.pos_freqs)
    return 2 * FLOAT_BYTES * (corners + activations)


# samples a training step evaluates, by sampler: marching adapts its rays to batch_samples (and evaluates at most
# twice as many); hierarchical sampling takes N_c + N_f a ray
_STEP_SAMPLES = {
    "marching": lambda s, o: 2 * o.batch_samples if o.batch_samples else o.batch_rays * s.steps,
    "hierarchical": lambda s, o: o.batch_rays * (s.n_coarse + (s.n_fine if s.hierarchical else 0)),
}


# what a march lays out before the occupancy grid culls it: 4 steps + 1 candidates a ray (``march``), about
# CANDIDATE_BYTES each (start, end, t, a point, its index and flags), for up to 16 x batch_rays rays a step while
# the rays adapt to batch_samples
CANDIDATE_BYTES = 48
_STEP_CANDIDATES = {
    "marching": lambda s, o: (16 if o.batch_samples else 1) * o.batch_rays * (4 * s.steps + 1),
    "hierarchical": lambda s, o: 0,
}


def step_bytes(field: "FieldParams", sampler: "SamplerParams", optim: "OptimParams") -> int:
    """About what one training step holds: its samples (``sample_bytes`` each), or the candidates a march lays
    out for them, whichever is more. ``auto`` marches a grid field and samples hierarchically along the MLP's
    rays, as ``assembly`` chooses."""
    kind = sampler.kind if sampler.kind != "auto" else "hierarchical" if field.kind == "mlp" else "marching"
    samples = _STEP_SAMPLES.get(kind, _STEP_SAMPLES["hierarchical"])(sampler, optim)
    candidates = _STEP_CANDIDATES.get(kind, _STEP_CANDIDATES["hierarchical"])(sampler, optim)
    return max(samples * sample_bytes(field), candidates * CANDIDATE_BYTES)


def _at_least(params: object, minimum: float, *names: str) -> None:
    for name in names:
        value = getattr(params, name)
        if value < minimum:
            raise ValueError(f"{name} must be >= {minimum:g}, got {value}")


@dataclass(frozen=True)
class FieldParams:
    """The radiance field: dense grids and a small MLP (fast), or the paper's MLP (Fig. 7)."""

    kind: str = param("grid", "grid: dense feature grids + a small MLP (fast); hash: its finer levels hashed "
                              "(Instant-NGP); planes: three factorized planes a level (K-Planes); mlp: the paper's "
                              "MLP (Fig. 7); any field in nerfpipe.nerf.registry.FIELDS")
    levels: int = param(3, "grid: levels of the multiresolution grid", bounds=(1, 32))
    min_resolution: int = param(32, "grid: cells a side of the coarsest level", bounds=(1, 4096))
    max_resolution: int = param(128, "grid: cells a side of the finest level", bounds=(1, 8192))
    features: int = param(4, "grid: features per vertex and level", bounds=(1, 64))
    log2_table: int = param(19, "hash: rows of each hashed level's table, as a power of 2 (Instant-NGP: 19)", bounds=(10, 24))
    hidden: int = param(64, "grid: width of its MLPs", bounds=(1, 1024))
    depth: int = param(4, "mlp: layers of the trunk (the paper: 8)", bounds=(1, 32))
    width: int = param(128, "mlp: channels per trunk layer (the paper: 256)", bounds=(1, 2048))
    view_width: int = param(64, "mlp: channels of the view-direction layer (the paper: 128)", bounds=(1, 2048))
    skip_after: int = param(0, "mlp: concatenate the encoded input to this layer's activation (the paper: 5; 0: none)", bounds=(0, 31))
    positional_encoding: bool = param(True, "encode x and d with Eq. 4; false is Table 2's 'No Pos. Encoding'")
    pos_freqs: int = param(10, "L for positions (Section 5.1: 10)", bounds=(0, 24))
    dir_freqs: int = param(0, "L for directions; 0: d itself, colour a smooth function of direction (the temple's 14 "
                              "photos: 28.6-28.8 dB, against 26.7-27.0 at 4, which fits each photo's own direction); "
                              "Section 5.1: 4, as the paper and balanced presets have", bounds=(0, 16))
    include_input: bool = param(True, "mlp: feed the raw coordinates beside their encoding (the authors' code does)")
    view_dependence: bool = param(True, "colour depends on the viewing direction; false is Table 2's 'No View Dependence'")
    density_activation: Literal["relu", "softplus"] = param("softplus", "mlp: relu (the paper) or softplus")
    fine_network: bool = param(False, "a separate fine network (the paper); false reuses the coarse one")

    def __post_init__(self) -> None:
        check(FIELDS, self.kind, "kind")
        _at_least(self, 1, "levels", "min_resolution", "max_resolution", "features", "hidden", "depth", "width",
                  "view_width")
        _at_least(self, 0, "skip_after", "pos_freqs", "dir_freqs")
        if not 10 <= self.log2_table <= 24:
            raise ValueError(f"log2_table must be in [10, 24], got {self.log2_table}")
        if self.skip_after > self.depth - 1:
            raise ValueError(f"skip_after must be below depth ({self.depth}), got {self.skip_after}")
        if self.min_resolution > self.max_resolution:
            raise ValueError("min_resolution must not exceed max_resolution")
        check_memory("max_resolution, levels, features", "the feature tables, while training,",
                     field_training_bytes(self))


@dataclass(frozen=True)
class SamplerParams:
    """Where along each ray the field is evaluated: marching an occupancy grid, or Section 5.2's sampling."""

    kind: str = param("auto", "marching: empty-space skipping through an occupancy grid (Instant-NGP); hierarchical: "
                              "Section 5.2's N_c + N_f samples; auto: marching with the grid field; any sampler in "
                              "nerfpipe.nerf.registry.SAMPLERS")
    occupancy_resolution: int = param(64, "cells a side of the occupancy grid", bounds=(1, 1024))
    steps: int = param(128, "marching steps along the field box's diagonal (about one per image pixel at 100 px lego)", bounds=(1, 100_000))
    early_stop: float = param(1e-4, "stop a marched ray once its transmittance is below this (0: never)", bounds=(0.0, 0.99))
    occupancy_threshold: float = param(0.01, "a cell is occupied when one step through it is this optically thick", bounds=(0.0, 1000.0))
    n_coarse: int = param(32, "N_c stratified samples per ray (the paper: 64); without the occupancy grid", bounds=(1, 4096))
    n_fine: int = param(64, "N_f samples from the coarse weights (the paper: 128; 0: no hierarchical sampling)", bounds=(0, 4096))
    hierarchical: bool = param(True, "hierarchical sampling; false is Table 2's 'No Hierarchical' (N_c samples only)")
    lindisp: Auto = param("auto", "sample linearly in disparity; auto: for unbounded scenes")

    def __post_init__(self) -> None:
        check(SAMPLERS, self.kind, "kind", ("auto",))
        _at_least(self, 1, "occupancy_resolution", "steps", "n_coarse")
        _at_least(self, 0, "n_fine", "occupancy_threshold")
        if not (0 <= self.early_stop < 1):
            raise ValueError(f"early_stop must be in [0, 1), got {self.early_stop}")
        check_memory("occupancy_resolution", "the occupancy grid's cells", OCCUPANCY_CELL_BYTES * self.occupancy_resolution**3)


@dataclass(frozen=True)
class SpaceParams:
    """The ray space and the scene box the fields live in."""

    contract: Auto = param("auto", "contract the space beyond the scene box (mip-NeRF 360); auto: unbounded scenes "
                                   "and inward 360 ones without a backdrop")
    clip_to_box: bool = param(True, "inward 360 with a backdrop: clip each ray to the scene box")
    contract_around: Literal["scene", "cameras"] = param(
        "scene", "contracted space keeps at full resolution the scene box, or the box of the scene and the cameras "
                 "(as mip-NeRF 360 keeps its cameras inside the uncontracted ball; on beer 0.3-0.9 dB worse in 4 "
                 "minutes: docs/benchmarks.md)")
    hull: Auto = param("auto", "shrink the scene box to the box of the photos' visual hull, where the grids then "
                               "spend their cells; auto and on: for inward 360 photos with silhouettes (alpha or a "
                               "backdrop), on also says why when it cannot")
    hull_tolerance: float = param(0.05, "carve a cell only when more than this share of the photos seeing it call "
                                        "it backdrop (mask errors)", bounds=(0.0, 0.99))

    def __post_init__(self) -> None:
        if not 0 <= self.hull_tolerance < 1:
            raise ValueError(f"hull_tolerance must be in [0, 1) (1 carves nothing), got {self.hull_tolerance}")


@dataclass(frozen=True)
class OptimParams:
    """Batches, the optimizer and its schedule (Section 5.3)."""

    batch_rays: int = param(4096, "rays per batch (the paper: 4096); with batch_samples, the starting and largest / 16 batch", bounds=(1, 1_048_576))
    batch_samples: int = param(16384, "while marching, adapt the rays per batch to about this many samples "
                                      "(Instant-NGP), and evaluate at most twice as many a step; 0: fixed batch_rays", bounds=(0, 4_194_304))
    lr: float = param(3e-2, "initial Adam learning rate of the fields: a grid field's feature tables, an MLP field's "
                            "weights (the paper: 5e-4)", bounds=(1e-08, 10.0))
    lr_final: float = param(9e-3, "learning rate at the last step (at most lr), reached by exponential decay (the "
                                  "paper: 5e-5); minutes of training leave a field far from converged, so it decays "
                                  "little, as Instant-NGP's (lego 100 px at 2 minutes: 30.92 dB at a 20-fold decay)", bounds=(1e-10, 10.0))
    mlp_lr_share: float = param(0.33, "a grid field's MLPs learn at this share of lr and lr_final, its feature tables at "
                                      "lr itself (lego 100 px at 2 minutes: 32.24 dB, 31.93 with 1)", bounds=(1e-06, 1.0))
    adam_eps: float = param(1e-15, "Adam epsilon (the paper: 1e-7)", bounds=(1e-20, 1.0))
    adam_beta2: float = param(0.99, "Adam beta2 (the paper: 0.999; Instant-NGP: 0.99)", bounds=(0.0, 0.999999))
    density_noise: str = param("auto", "std of noise on raw density: auto (1.0 for forward-facing real captures, "
                                       "else 0) or a number")
    distortion: float = param(0.0, "weight of mip-NeRF 360's distortion loss (Eq. 15) against floaters, 0: off "
                                    "(on beer 0.01 cost 2.2 dB in 4 minutes: docs/benchmarks.md)", bounds=(0.0, 100.0))

    def __post_init__(self) -> None:
        _at_least(self, 1, "batch_rays")
        _at_least(self, 0, "batch_samples")
        if not (0 < self.lr_final and 0 < self.lr) or self.adam_eps <= 0 or not (0 < self.adam_beta2 < 1):
            raise ValueError("need lr > 0, lr_final > 0, adam_eps > 0 and 0 < adam_beta2 < 1")
        _at_least(self, 0, "distortion")
        if not 0 < self.mlp_lr_share <= 1:
            raise ValueError(f"mlp_lr_share must be in (0, 1], got {self.mlp_lr_share}")
        if self.density_noise != "auto":
            try:
                noise = float(self.density_noise)
            except ValueError:
                raise ValueError(f"density_noise must be auto or a number >= 0, got {self.density_noise!r}") from None
            if not noise >= 0:
                raise ValueError(f"density_noise must be >= 0, got {noise}")


@dataclass(frozen=True)
class PerImageParams:
    """What is learned for each training photo beside the field."""

    appearance: Auto = param("auto", "learn each photo's exposure and white balance (3 gains on linear light); "
                                     "auto: when the scene finds exposure varying")
    appearance_lr: float = param(1e-2, "learning rate of the per-image exposure gains (decays as lr does)", bounds=(0.0, 10.0))
    refine_poses: Auto = param("auto", "refine each training camera's pose with the field; auto: for photos whose "
                                       "poses the sparse points cannot vouch for, not for rendered captures")
    pose_lr: float = param(3e-3, "learning rate of the camera corrections (decays as lr does)", bounds=(0.0, 10.0))
    pose_penalty: float = param(1e-3, "weight of the camera corrections' mean squared size in the loss", bounds=(0.0, 1000000.0))

    def __post_init__(self) -> None:
        _at_least(self, 0, "appearance_lr", "pose_lr", "pose_penalty")
