"""What the report knows about a run, gathered once: each stage's status, the results that are fresh for
the run's current settings, and the SfM cameras (drawn by two sections)."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.pipeline import Committed, Stage, StageStatus


@dataclass(frozen=True)
class RunData:
    """A run as the report sees it.

    ``order``: every stage name in pipeline order; ``statuses``: name -> its status; ``results``: name ->
    its committed result, only for stages fresh for the current settings; ``folder``: the report's folder,
    whose ``img/`` the sections write their pictures into; ``previous``: the ``img/`` of the report this one
    replaces, whose pictures ``picture`` takes again where what they show has not changed.
    """

    run_dir: Path
    source: Path
    folder: Path
    stages: Mapping[str, Stage]
    order: tuple[str, ...]
    statuses: Mapping[str, StageStatus]
    results: Mapping[str, Committed]
    sfm_cameras: CameraSet | None = None
    previous: Path | None = None
    drawn: dict[str, str] = field(default_factory=dict)  # picture name -> its key, as ``picture`` made them

    @property
    def img(self) -> Path:
        return self.folder / "img"

    def picture(self, name: str, key: str, draw: Callable[[Path], object]) -> bool:
        """Put ``img/name`` in place: taken from the previous report where it was drawn under the same ``key``
        (what it shows: the commits of the results it is drawn from; the report's code is added here), else
        drawn by ``draw(path)``, which returns False where it could not draw it. False where there is none."""
        key = hashlib.sha256(f"{key}\n{CODE}".encode()).hexdigest()
        path = self.img / name
        old = None if self.previous is None else self.previous / name
        if old is not None and old.is_file() and self.previous_keys.get(name) == key:
            os.replace(old, path)
        elif draw(path) is False:
            return False
        self.drawn[name] = key
        return True

    @cached_property
    def previous_keys(self) -> dict[str, str]:
        """The keys the previous report's pictures were drawn under."""
        return {} if self.previous is None else picture_keys(self.previous)

    def commit(self, stage: str) -> str:
        """What identifies the fresh result of ``stage``: a result computed again gets a new one."""
        return self.results[stage].commit_id

    def artifact(self, stage: str, name: str) -> Path:
        """The path of artifact ``name`` in the fresh result of ``stage``."""
        return self.results[stage].path / self.stages[stage].provides[name]

    def describe(self, stage: str) -> list[str]:
        """The lines ``nerfpipe status`` prints about the fresh result of ``stage``."""
        result = self.results[stage]
        return self.stages[stage].describe(result.path, result.manifest)


KEYS = "pictures.json"  # in img/: each picture's key, written once all are drawn


def picture_keys(img: Path) -> dict[str, str]:
    """The keys of the pictures in a report's ``img/``; none where it was not finished."""
    try:
        keys = json.loads((img / KEYS).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return keys if isinstance(keys, dict) else {}


def _code() -> str:
    """A hash of the report's own sources: a picture drawn by other code is drawn again."""
    digest = hashlib.sha256()
    for source in sorted(Path(__file__).parent.glob("*.py")):
        digest.update(source.read_bytes())
    return digest.hexdigest()


CODE = _code()


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
