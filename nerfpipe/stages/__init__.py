"""The stages of nerfpipe, one module each, and the default pipeline that chains them."""

from __future__ import annotations

import logging

from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.pipeline.budget import format_duration
from nerfpipe.pipeline.runner import Pipeline
from nerfpipe.pipeline.stage import Stage
from nerfpipe.stages.bounds import BoundsParams, BoundsStage
from nerfpipe.stages.export_depth import ExportDepthParams, ExportDepthStage
from nerfpipe.stages.export_mesh import ExportMeshParams, ExportMeshStage
from nerfpipe.stages.export_points import ExportPointsParams, ExportPointsStage
from nerfpipe.stages.ingest import IngestParams, IngestStage
from nerfpipe.stages.render import RenderParams, RenderStage
from nerfpipe.stages.scene import SceneParams, SceneStage
from nerfpipe.stages.sfm import SfmParams, SfmStage
from nerfpipe.stages.train import TrainParams, TrainStage
from nerfpipe.stages.undistort import UndistortParams, UndistortStage

log = logging.getLogger("nerfpipe")


# ``nerfpipe run``'s default budget for the whole job: a base, and more for each megapixel of photos to fit
# (after ingest's resizing), within these bounds. The demo (16 photos of 640 x 480) gets 3 min 45 s (its held-out
# views: 27.55 dB in 3 min 32 s), a phone capture of 71 frames of 720 x 1280 about 7.8 minutes.
BUDGET_BASE_SECONDS = 205.0
BUDGET_SECONDS_PER_MEGAPIXEL = 4.0
BUDGET_RANGE_SECONDS = (205.0, 600.0)


def auto_budget(pipe: Pipeline) -> float:
    """The job budget ``--budget auto`` gives the capture of ``pipe``, from the pixels of its cameras in the
    bounds stage's world (which has run by the time a stage asks for its allotment)."""
    world = CameraSet.load(pipe.artifact("world", "normalized cameras"))
    megapixels = sum(world.camera_of(f).width * world.camera_of(f).height for f in world.frames) / 1e6
    lo, hi = BUDGET_RANGE_SECONDS
    seconds = float(min(max(BUDGET_BASE_SECONDS + BUDGET_SECONDS_PER_MEGAPIXEL * megapixels, lo), hi))
    log.info("budget: %s for the whole job, for %d photos of %.1f megapixels together (auto: %s and %g s a "
             "megapixel, within %s to %s; --budget sets it)", format_duration(seconds), len(world.frames), megapixels,
             format_duration(BUDGET_BASE_SECONDS), BUDGET_SECONDS_PER_MEGAPIXEL, format_duration(lo), format_duration(hi))
    return seconds


auto_budget.ceiling = BUDGET_RANGE_SECONDS[1]  # type: ignore[attr-defined]  # the most auto gives, for refusals


def default_stages() -> list[Stage]:
    """The stages `nerfpipe run` chains, in declaration order."""
    return [
        IngestStage(), SfmStage(), UndistortStage(), BoundsStage(), SceneStage(), TrainStage(),
        ExportDepthStage(), ExportPointsStage(), ExportMeshStage(), RenderStage(),
    ]


__all__ = [
    "BoundsParams", "BoundsStage", "ExportDepthParams", "ExportDepthStage", "ExportMeshParams", "ExportMeshStage",
    "ExportPointsParams", "ExportPointsStage", "RenderParams", "RenderStage", "IngestParams", "IngestStage", "SceneParams", "SceneStage", "SfmParams",
    "SfmStage", "TrainParams", "TrainStage", "UndistortParams", "UndistortStage", "auto_budget", "default_stages",
]
