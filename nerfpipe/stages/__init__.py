"""The stages of nerfpipe, one module each, and the default pipeline that chains them."""

from __future__ import annotations

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


def default_stages() -> list[Stage]:
    """The stages `nerfpipe run` chains, in declaration order."""
    return [
        IngestStage(), SfmStage(), UndistortStage(), BoundsStage(), SceneStage(), TrainStage(),
        ExportDepthStage(), ExportPointsStage(), ExportMeshStage(), RenderStage(),
    ]


__all__ = [
    "BoundsParams", "BoundsStage", "ExportDepthParams", "ExportDepthStage", "ExportMeshParams", "ExportMeshStage",
    "ExportPointsParams", "ExportPointsStage", "RenderParams", "RenderStage", "IngestParams", "IngestStage", "SceneParams", "SceneStage", "SfmParams",
    "SfmStage", "TrainParams", "TrainStage", "UndistortParams", "UndistortStage", "default_stages",
]
