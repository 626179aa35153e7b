"""What the report knows about a run, gathered once: each stage's status, the results that are fresh for
the run's current settings, and the SfM cameras (drawn by two sections)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.pipeline import Committed, Stage, StageStatus


@dataclass(frozen=True)
class RunData:
    """A run as the report sees it.

    ``order``: every stage name in pipeline order; ``statuses``: name -> its status; ``results``: name ->
    its committed result, only for stages fresh for the current settings; ``folder``: the report's folder,
    whose ``img/`` the sections write their pictures into.
    """

    run_dir: Path
    source: Path
    folder: Path
    stages: Mapping[str, Stage]
    order: tuple[str, ...]
    statuses: Mapping[str, StageStatus]
    results: Mapping[str, Committed]
    sfm_cameras: CameraSet | None = None

    @property
    def img(self) -> Path:
        return self.folder / "img"

    def artifact(self, stage: str, name: str) -> Path:
        """The path of artifact ``name`` in the fresh result of ``stage``."""
        return self.results[stage].path / self.stages[stage].provides[name]

    def describe(self, stage: str) -> list[str]:
        """The lines ``nerfpipe status`` prints about the fresh result of ``stage``."""
        result = self.results[stage]
        return self.stages[stage].describe(result.path, result.manifest)


def gather(run_dir: Path, stages: Sequence[Any] | None, folder: Path) -> RunData:
    """Plan the run in ``run_dir`` as its last ``run`` configured it and read what the report needs."""
    from nerfpipe.pipeline import Pipeline
    from nerfpipe.stages import default_stages

    pipe = Pipeline.from_run_dir(list(stages) if stages is not None else default_stages(), run_dir)
    statuses = {s.name: s for s in pipe.status()}
    results = {name: s.result for name, s in statuses.items() if s.state == "fresh" and s.result is not None}
    run = RunData(run_dir, pipe.source, folder, pipe.dag.stages, tuple(pipe.dag.order), statuses, results)
    if "sfm" in results:
        return replace(run, sfm_cameras=CameraSet.load(run.artifact("sfm", "sfm_model")))
    return run
