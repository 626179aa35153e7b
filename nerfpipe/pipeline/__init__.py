"""The pipeline engine: stage contract, cache keys, artifact store, DAG, runner, typed errors.

It knows nothing about images or radiance fields; ``nerfpipe.stages`` does.
"""

from nerfpipe.pipeline.dag import Dag
from nerfpipe.pipeline.errors import (
    BadPhotoError,
    DiskFullError,
    InputError,
    NerfpipeError,
    ParamError,
    RunLockedError,
    StageError,
    UpstreamNotReadyError,
)
from nerfpipe.pipeline.params import ParamSpec, build_params, param_specs, parse_assignments
from nerfpipe.pipeline.runner import Pipeline, PlannedStage, StageOutcome, StageStatus
from nerfpipe.pipeline.stage import LaterStage, Stage, StageContext, StageInputs
from nerfpipe.pipeline.store import ArtifactStore, Committed, Damage

__all__ = [
    "ArtifactStore", "BadPhotoError", "Committed", "Damage", "Dag", "DiskFullError", "InputError", "NerfpipeError", "ParamError",
    "LaterStage", "ParamSpec", "Pipeline", "PlannedStage", "RunLockedError", "Stage", "StageContext", "StageError",
    "StageInputs", "StageOutcome", "StageStatus", "UpstreamNotReadyError", "build_params", "param_specs",
    "parse_assignments",
]
