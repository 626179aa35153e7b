"""The stage contract.

A stage is a class with a name, a version, a frozen-dataclass ``Params`` with named ``presets``, the
artifacts it ``requires`` from upstream stages and the artifacts it ``provides`` (name -> path inside its
own output folder). ``run`` reads only the artifacts it declared and the capture files it listed in
``input_files``, and writes only inside ``out``. Bump ``version`` whenever the stage's output for the
same inputs and parameters changes: the version is part of the cache key.
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, ClassVar, Generic, Iterator, Mapping, TypeVar

from nerfpipe.pipeline.budget import Allotment, FloorWork
from nerfpipe.pipeline.fingerprint import Fingerprint
from nerfpipe.pipeline.summary import Summary


def capture_root(source: Path) -> Path:
    """The folder capture files are named relative to: the capture folder, or the folder of a capture that
    is one file (a video)."""
    return source if source.is_dir() else source.parent


T = TypeVar("T")


@dataclass(frozen=True)
class ArtifactRef(Generic[T]):
    """A typed reference to an artifact: the name a stage requires it by and the loader that reads it
    (``nerfpipe.artifacts.BOUNDS``), so that a hand-off is a type, not a string and a file format."""

    name: str
    loader: Callable[[Path], T]

    def load(self, path: Path) -> T:
        return self.loader(path)


@dataclass(frozen=True)
class StageInputs:
    """What a stage may read: upstream artifacts by name, and the fingerprinted capture files of ``source``
    (a capture folder, or one file such as a video)."""

    artifacts: Mapping[str, Path]
    source: Path
    files: tuple[Fingerprint, ...] = ()

    def __getitem__(self, artifact: str) -> Path:
        return self.artifacts[artifact]

    def load(self, artifact: ArtifactRef[T]) -> T:
        """The artifact ``artifact`` names, read by its loader: ``inputs.load(BOUNDS)`` is a ``Bounds``."""
        return artifact.load(self[artifact.name])

    def path(self, fp: Fingerprint) -> Path:
        return capture_root(self.source) / fp.relpath


# progress(total, description) -> advance(n=1, info=None); ``info`` is a short status text shown beside the bar
ProgressFactory = Callable[[int, str], contextlib.AbstractContextManager[Callable[..., None]]]


@contextlib.contextmanager
def _no_progress(total: int, description: str) -> Iterator[Callable[..., None]]:
    yield lambda n=1, info=None: None


@dataclass(frozen=True)
class LaterStage:
    """A budgeted stage still to run after the running one: its ``params`` and the ``seconds`` of its share."""

    stage: "Stage"
    params: Any
    seconds: float

    @property
    def name(self) -> str:
        return self.stage.name

    def floor_work(self, *capture: Any) -> FloorWork | None:
        return self.stage.floor_work(self.params, *capture)


@dataclass
class StageContext:
    """Services the runner gives a running stage: a logger, progress bars, and ``extra``: what the caller of
    the pipeline hands the stages outside their parameters (it never enters a cache key)."""

    log: logging.Logger
    progress: ProgressFactory = _no_progress
    debug: bool = False
    extra: dict[str, Any] = field(default_factory=dict)
    allotment: Allotment | None = None  # its part of the job's time budget (``nerfpipe.pipeline.budget``), if any
    later: tuple[LaterStage, ...] = ()  # under a budget, the stages with a share still to run after it


class Stage:
    """Base class of every stage. Subclasses set the class attributes and implement ``run``."""

    name: ClassVar[str]
    version: ClassVar[int]
    Params: ClassVar[type]
    Summary: ClassVar[type[Summary]] = Summary  # what ``run`` returns: the stage's figures and its ``describe()``
    presets: ClassVar[Mapping[str, Mapping[str, Any]]] = {}
    requires: ClassVar[tuple[str, ...]] = ()
    provides: ClassVar[Mapping[str, str]] = {}
    libraries: ClassVar[tuple[str, ...]] = ()
    inputs_label: ClassVar[str] = "input files"
    # A resumable stage keeps its work folder across interrupted attempts at the same cache key (and
    # must cope with finding a partial one there); others always start from an empty folder.
    resumable: ClassVar[bool] = False
    # Resources a batch executor reserves for one run of the stage: CPU cores, and a GPU when the
    # stage can use one and the cluster has one (``accelerated``).
    cpus: ClassVar[float] = 1
    accelerated: ClassVar[bool] = False
    # Its part in a job's time budget (``nerfpipe.pipeline.budget``): a share of it that the stage sizes its
    # work to fit, or ``elastic``: the parameters that, set by a user or a preset, stop it taking the rest.
    budget_share: ClassVar[float] = 0.0
    elastic: ClassVar[tuple[str, ...]] = ()
    # An optional stage (an export) that cannot make what it looks for (a ``StageError``) does not stop the
    # run: the runner warns, and skips only the stages that need its result.
    optional: ClassVar[bool] = False

    @classmethod
    def summary(cls) -> str:
        return (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""

    def machine_preset(self, overrides: Mapping[str, Any]) -> tuple[str, str] | None:
        """The preset this stage takes where the job names none, sized for the machine it runs on, and why (a
        line for the log); None: its defaults. ``overrides``: the job's settings of this stage."""
        return None

    def input_files(self, source: Path, params: Any) -> list[Path]:
        """Files of the capture folder this stage reads; their fingerprints enter the cache key."""
        return []

    def expected_bytes(self, inputs: StageInputs, params: Any) -> int:
        """About how many bytes ``run`` will write, where the stage can tell beforehand; 0 when it cannot.

        The runner refuses to start the stage, with a clear message, when the disk has less free space.
        """
        return 0

    def least_seconds(self, params: Any) -> tuple[float, str] | None:
        """The fewest seconds ``params`` can cost on any machine, and the setting that asks for them, where the
        parameters alone tell (``train.steps``): a job whose budget is smaller is refused before it starts."""
        return None

    def floor_work(self, params: Any, *capture: Any) -> FloorWork | None:
        """What this stage's outputs cost at their floors, where it can tell before its inputs exist, from what the
        elastic stage knows of the ``capture`` (the application says what that is); None: no floor to keep."""
        return None

    def describe(self, result: Path, manifest: Mapping[str, Any]) -> list[str]:
        """Lines ``nerfpipe status`` prints about a committed result (its folder and manifest): its summary's."""
        return self.Summary.from_json(manifest.get("summary") or {}).describe()

    def run(self, inputs: StageInputs, out: Path, params: Any, ctx: StageContext) -> Summary | None:
        """Produce every artifact in ``provides`` inside ``out``; return its ``Summary`` for the manifest."""
        raise NotImplementedError
