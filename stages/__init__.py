"""The stages of nerfpipe, one module each, and the default pipeline that chains them."""

from __future__ import annotations

from nerfpipe.pipeline.stage import Stage
from nerfpipe.stages.ingest import IngestParams, IngestStage
from nerfpipe.stages.sfm import SfmParams, SfmStage


def default_stages() -> list[Stage]:
    """The stages `nerfpipe run` chains, in declaration order."""
    return [IngestStage(), SfmStage()]


__all__ = ["IngestParams", "IngestStage", "SfmParams", "SfmStage", "default_stages"]
