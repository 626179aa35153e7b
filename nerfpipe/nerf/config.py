"""The train stage's parameter groups, as ``--set train.GROUP.NAME=VALUE`` names them.

Each group is the user-facing configuration of one part of the model, validated here once:
``field`` (``nerfpipe.nerf.fields.base``), ``sampler`` (``nerfpipe.nerf.samplers.base``), ``space`` (the ray space
and scene box, ``nerfpipe.nerf.policy``), ``optim`` (``nerfpipe.nerf.train.trainer``) and ``per_image``
(``nerfpipe.nerf.appearance``, ``nerfpipe.nerf.refinement``). This module imports no torch, so listing
the parameters (``nerfpipe stages``) stays quick and training can set torch's CPU state before torch runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Mapping, Protocol

from nerfpipe.nerf.fields.configs import FieldConfig, GridConfig, at_least
from nerfpipe.nerf.registry import FIELDS, SAMPLERS, configs
from nerfpipe.nerf.samplers.configs import SamplerConfig
from nerfpipe.pipeline.params import Auto, param


def step_bytes(field: FieldConfig, sampler: SamplerConfig, optim: "OptimParams") -> int:
    """About what one training step holds: its samples (``FieldConfig.sample_bytes`` each), or the candidates a
    sampler lays out for them, whichever is more."""
    return sampler.step_bytes(field.sample_bytes(), optim.batch_rays, optim.batch_samples)


def field_configs() -> dict[str, type]:
    """The field kinds ``train.field.kind`` chooses from (``nerfpipe.nerf.registry.FIELDS``)."""
    return configs(FIELDS)


def sampler_configs() -> dict[str, type]:
    """The sampler kinds ``train.sampler.kind`` chooses from (``nerfpipe.nerf.registry.SAMPLERS``)."""
    return configs(SAMPLERS)


def auto_sampler(built: Mapping[str, Any]) -> str:
    """``train.sampler.kind=auto``: the sampler the field asks for (``FieldConfig.sampler``): marching an
    occupancy grid with a field that spans a box, Section 5.2's sampling with the MLP."""
    field = built.get("field", GridConfig())
    return field.sampler


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
    adam_beta2: float = param(0.99, "Adam beta2 (the paper: 0.999; Instant-NGP: 0.99)", bounds=(0.001, 0.999999))
    density_noise: str = param("auto", "std of noise on raw density: auto (1.0 for forward-facing real captures, "
                                       "else 0) or a number")
    distortion: float = param(0.0, "weight of mip-NeRF 360's distortion loss (Eq. 15) against floaters, 0: off "
                                    "(on beer it thins the fog to 11-16 samples a ray, 1.8-2.3x the rays a second, but costs 0.3-0.9 dB "
                                    "held out: docs/benchmarks.md)", bounds=(0.0, 100.0))
    pixels: Literal["uniform", "error"] = param("uniform", "which training pixels a step draws: uniform, or error (half of "
                                                           "them in proportion to each 16-pixel tile's recent error, "
                                                           "the loss weighted to stay unbiased; Instant-NGP's error map)")

    def __post_init__(self) -> None:
        at_least(self, 1, "batch_rays")
        at_least(self, 0, "batch_samples")
        if not (0 < self.lr_final and 0 < self.lr) or self.adam_eps <= 0 or not (0 < self.adam_beta2 < 1):
            raise ValueError("need lr > 0, lr_final > 0, adam_eps > 0 and 0 < adam_beta2 < 1")
        at_least(self, 0, "distortion")
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
        at_least(self, 0, "appearance_lr", "pose_lr", "pose_penalty")


class TrainSettings(Protocol):
    """The train parameters the policy and the trainer read (``nerfpipe.stages.train.TrainParams``): its groups
    and the schedule around them. The trainer takes them as they are: there is no copy of them."""

    field: FieldConfig
    sampler: SamplerConfig
    space: SpaceParams
    optim: OptimParams
    per_image: PerImageParams
    steps: int
    seconds: float
    seed: int
    checkpoint_every: int
    keep_checkpoints: int
    autocast: str
    tf32: bool
    compile: str
