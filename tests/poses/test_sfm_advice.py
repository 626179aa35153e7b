"""When SfM registers too few photos, its advice names only what was not tried already."""

from __future__ import annotations

import logging
import shutil

import pycolmap
import pytest

from nerfpipe.artifacts import ImageIndex
from nerfpipe.pipeline import Pipeline
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.stage import StageContext
from nerfpipe.poses.colmap import mapping
from nerfpipe.stages import IngestStage, SfmParams
from tests.helpers import TEMPLE


@pytest.mark.parametrize(("matcher", "suggested"), [("exhaustive", False), ("sequential", True)])
def test_the_advice_after_too_few_registered_photos_skips_the_matcher_just_used(tmp_path, monkeypatch, matcher,
                                                                                  suggested) -> None:
    capture = tmp_path / "capture"
    capture.mkdir()
    for i in (1, 2, 3):
        shutil.copy(TEMPLE / f"templeSR000{i}.png", capture)
    ingest = Pipeline([IngestStage()], capture, tmp_path / "run", None, {}).run()[0]
    records = ImageIndex.load(ingest.path / "images.json").records
    monkeypatch.setattr(mapping, "map_images", lambda *args, **kwargs: pycolmap.Reconstruction())  # none registers
    params = SfmParams(matcher=matcher, max_features=1024, relaxed_retry=False)
    (tmp_path / "out").mkdir()
    with pytest.raises(StageError, match="SfM registered only 0 of 3 photos") as err:
        mapping.run_sfm(ingest.path / "images", records, tmp_path / "out", params, StageContext(logging.getLogger("t")))
    assert ("--set sfm.matcher=exhaustive" in str(err.value)) == suggested
    assert "--set sfm.max_features=2048" in str(err.value)  # twice what was used
