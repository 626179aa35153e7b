"""The train stage's parameters for a test, named short: ``train_settings(lr=1e-3, steps=10)``."""

from __future__ import annotations

import dataclasses
from typing import Any

from nerfpipe.nerf.config import OptimParams, PerImageParams
from nerfpipe.pipeline.params import override
from nerfpipe.stages.train import TrainParams

_GROUPS = {**{f.name: "optim." for f in dataclasses.fields(OptimParams)},
           **{f.name: "per_image." for f in dataclasses.fields(PerImageParams)}}


def train_settings(**values: Any) -> TrainParams:
    """``TrainParams`` with ``values`` set, a setting of the ``optim`` or ``per_image`` group by its own name."""
    return override(TrainParams(), {_GROUPS.get(name, "") + name: value for name, value in values.items()})
