"""Many captures at once: one run directory per capture, each stage of each capture a task of an executor.

The driver (this module, in the ``nerfpipe batch`` process) plans every capture with the same cache keys
as ``nerfpipe run``, restores what is fresh in place and submits one task per stage that is not, after
the tasks of its upstream stages. A task (``run_stage_task``) runs in whichever process or node the
executor picks: it rebuilds the capture's ``Pipeline`` from a picklable ``StageJob`` and runs one stage,
under that stage's lock, committing with an atomic rename inside the capture's run directory; so the run
directories must sit on a filesystem that every node sees at the same path.

Failures stay with their capture: a stage that fails ends its capture (its downstream stages report the
upstream failure and do not run) and the other captures go on. The driver holds each capture's run
lock while the capture is in progress, so ``nerfpipe run`` on the same folder waits its turn.
"""

from __future__ import annotations

import importlib
import logging
import os
import socket
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from nerfpipe.pipeline.dag import Dag
from nerfpipe.pipeline.errors import InputError, NerfpipeError
from nerfpipe.pipeline.executors import Executor, Handle, TaskFailure
from nerfpipe.pipeline.lock import RunLock
from nerfpipe.pipeline.params import build_params
from nerfpipe.pipeline.runner import Pipeline
from nerfpipe.pipeline.stage import Stage
from nerfpipe.pipeline.plan import check_run_dir
from nerfpipe.pipeline.store import ArtifactStore, write_json_atomic

log = logging.getLogger("nerfpipe")

SUMMARY = "batch.json"


def load_stages(ref: str) -> list[Stage]:
    """The stage list named by ``"module:function"``, e.g. ``"nerfpipe.stages:default_stages"``."""
    module, _, function = ref.partition(":")
    return list(getattr(importlib.import_module(module), function)())


@dataclass(frozen=True)
class StageJob:
    """Everything a worker needs to run one stage of one capture; plain values, so it pickles."""

    capture: str
    stage: str
    source: str
    run_dir: str
    stages: str
    preset: str | None = None
    overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    def pipeline(self) -> Pipeline:
        return Pipeline(load_stages(self.stages), Path(self.source), Path(self.run_dir), self.preset, self.overrides)


def run_stage_task(job: StageJob, *upstream: Mapping[str, Any]) -> dict[str, Any]:
    """Run ``job.stage`` unless an upstream task failed. Returns what happened, errors included.

    A user error (``NerfpipeError``) is reported by its one line; any other exception by its type, message
    and the log file that holds its traceback. Neither is raised: Ray retries only lost workers.
    """
    base = {"capture": job.capture, "stage": job.stage, "host": socket.gethostname(), "pid": os.getpid()}
    for up in upstream:
        if not up["ok"]:
            return {**base, "ok": False, "skipped": True, "error": f"upstream stage {up['stage']} failed"}
    pipe = None
    started = time.time()
    try:
        pipe = job.pipeline()
        outcome = pipe.run_stage(job.stage)
    except NerfpipeError as err:
        return {**base, "ok": False, "error": str(err), "log": _log_of(pipe)}
    except Exception as err:
        log.debug("%s", traceback.format_exc())
        return {**base, "ok": False, "error": f"{type(err).__name__}: {err} (a bug; the traceback is in the log)",
                "traceback": traceback.format_exc(), "log": _log_of(pipe)}
    return {**base, "ok": True, "action": outcome.action, "seconds": round(outcome.seconds, 3), "key": outcome.key,
            "wall_seconds": round(time.time() - started, 3), "log": _log_of(pipe)}


def _log_of(pipe: Pipeline | None) -> str | None:
    return None if pipe is None or pipe.log_path is None else str(pipe.log_path)


def find_captures(root: Path) -> list[Path]:
    """The capture folders of a batch: the folders directly inside ``root``, by name (hidden ones skipped)."""
    if not root.is_dir():
        raise InputError(root, "does not exist" if not root.exists() else "is not a folder",
                         "pass a folder that holds one folder per capture")
    captures = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    for capture in captures:
        if capture.name == SUMMARY:  # its run directory would be the batch's summary file
            raise InputError(capture, f"is named like the batch's summary file {SUMMARY}",
                             "rename the capture folder")
    if not captures:
        raise InputError(root, "has no capture folders inside", "put each capture's photos in a folder of its own there")
    return captures


@dataclass
class CaptureState:
    """Where one capture of a batch is."""

    name: str
    source: Path
    run_dir: Path
    state: str = "queued"  # queued | running | done | failed
    stage: str | None = None  # the stage running now, or the one that failed
    stages: list[str] = field(default_factory=list)  # the selected stages, in order
    finished: dict[str, dict[str, Any]] = field(default_factory=dict)  # stage -> task result
    error: str | None = None
    log: str | None = None
    started: float | None = None
    ended: float | None = None
    tasks: dict[str, Handle] = field(default_factory=dict, repr=False)  # stage -> its task, for stages not fresh
    _lock: RunLock | None = field(default=None, repr=False)

    @property
    def seconds(self) -> float:
        if self.started is None:
            return 0.0
        return (self.ended or time.time()) - self.started

    def count(self, action: str) -> int:
        return sum(1 for r in self.finished.values() if r.get("action") == action)

    def summary(self) -> dict[str, Any]:
        return {
            "capture": self.name, "source": str(self.source), "run_dir": str(self.run_dir), "state": self.state,
            "stage": self.stage, "error": self.error, "log": self.log, "seconds": round(self.seconds, 2),
            "stages": {name: {k: r.get(k) for k in ("action", "seconds", "host", "error") if r.get(k) is not None}
                       for name, r in self.finished.items()},
        }


@dataclass(frozen=True)
class BatchSettings:
    stages: str = "nerfpipe.stages:default_stages"
    preset: str | None = None
    overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    until: str | None = None
    max_parallel: int = 0  # captures in progress at once; 0: all (the executor's resources decide)


class Batch:
    """Runs captures through an executor; ``on_change(states)`` is called whenever one moves on."""

    def __init__(self, sources: Sequence[Path], runs_root: Path, executor: Executor, settings: BatchSettings,
                 on_change: Callable[[list[CaptureState]], None] = lambda states: None) -> None:
        self.runs_root = Path(runs_root)
        self.executor = executor
        self.settings = settings
        self.on_change = on_change
        names = [Path(s).name for s in sources]
        if len(set(names)) != len(names):
            raise InputError(None, "two captures share a folder name", "give each capture folder a unique name")
        self.captures = [CaptureState(p.name, Path(p), self.runs_root / p.name) for p in map(Path, sources)]
        self._stages = load_stages(settings.stages)
        self._owner: dict[Handle, tuple[CaptureState, str]] = {}  # each task's capture and stage
        # bad flags fail here, once, rather than once per capture
        dag = Dag(self._stages)
        if settings.until is not None:
            dag.check_name(settings.until)
        Pipeline(self._stages, self.runs_root, self.runs_root, settings.preset, settings.overrides)
        for name in dag.order:
            stage = dag.stages[name]
            build_params(name, stage.Params, stage.presets, settings.preset, settings.overrides.get(name, {}))

    def run(self) -> list[CaptureState]:
        self.runs_root.mkdir(parents=True, exist_ok=True)
        waiting = list(self.captures)
        active: list[CaptureState] = []
        limit = self.settings.max_parallel or len(waiting)
        try:
            while waiting or active:
                while waiting and len(active) < limit:
                    capture = waiting.pop(0)
                    self._start(capture)
                    if capture.state == "running":
                        active.append(capture)
                    else:
                        self._settle(capture)
                    self._changed()
                pending = [h for c in active for h in c.tasks.values() if not h.done]
                for handle in self.executor.wait(pending, timeout=1.0) if pending else []:
                    self._record(handle)
                for capture in [c for c in active if all(h.done for h in c.tasks.values())]:
                    self._settle(capture)
                    active.remove(capture)
                self._changed()
        finally:
            for capture in self.captures:
                if capture._lock is not None:
                    capture._lock.release()
            self._write_summary()
        return self.captures

    # -- one capture ----------------------------------------------------------------------------
    def _start(self, capture: CaptureState) -> None:
        """Plan the capture, restore its fresh stages here and submit a task for each other one."""
        capture.started = time.time()
        capture.state = "running"
        settings = self.settings
        try:
            check_run_dir(capture.source, capture.run_dir)
            ArtifactStore(capture.run_dir).prepare()  # refuses a folder of the user's before the lock file lands in it
            lock = RunLock(capture.run_dir)
            lock.acquire()
            capture._lock = lock
            pipe = Pipeline(self._stages, capture.source, capture.run_dir, settings.preset, settings.overrides)
            selected = pipe.dag.select(until=settings.until)
            fresh = {s.name for s in pipe.status() if s.state == "fresh"}
            pipe.save_config()
        except NerfpipeError as err:
            return self._fail(capture, None, str(err))
        capture.stages = selected
        for name in selected:
            stage = pipe.dag.stages[name]
            upstream = [capture.tasks[up] for up in pipe.dag.upstream[name] if up in capture.tasks]
            if name in fresh and not upstream:
                outcome = pipe.restore(name)  # a cache hit: no task; at most its latest pointer moves
                if outcome is not None:
                    capture.finished[name] = {"ok": True, "stage": name, "action": outcome.action, "seconds": 0.0}
                    continue
            job = StageJob(capture.name, name, str(capture.source.resolve()), str(capture.run_dir.resolve()),
                           settings.stages, settings.preset, settings.overrides)
            capture.tasks[name] = handle = self.executor.submit(
                run_stage_task, (job,), upstream, cpus=stage.cpus, gpus=1 if stage.accelerated else 0,
                label=f"{capture.name}:{name}",
            )
            self._owner[handle] = (capture, name)
        self._advance(capture)

    def _record(self, handle: Handle) -> None:
        capture, name = self._owner.pop(handle)
        value = handle.value
        if isinstance(value, TaskFailure):
            value = {"ok": False, "stage": name, "error": value.reason, "lost": value.lost}
        capture.finished[name] = value
        if not value["ok"] and not value.get("skipped") and capture.error is None:
            self._fail(capture, name, value["error"], value.get("log"))
        self._advance(capture)

    def _advance(self, capture: CaptureState) -> None:
        if capture.state == "running":
            capture.stage = next((n for n in capture.stages if n not in capture.finished), None)

    def _fail(self, capture: CaptureState, stage: str | None, error: str, log_path: str | None = None) -> None:
        capture.state, capture.stage, capture.error, capture.log = "failed", stage, error, log_path
        capture.ended = time.time()

    def _settle(self, capture: CaptureState) -> None:
        if capture.state == "running":
            capture.state, capture.stage = "done", None
        capture.ended = capture.ended or time.time()
        if capture._lock is not None:
            capture._lock.release()
            capture._lock = None

    def _changed(self) -> None:
        self.on_change(self.captures)

    def _write_summary(self) -> None:
        write_json_atomic(self.runs_root / SUMMARY, {
            "executor": self.executor.name,
            "settings": {"preset": self.settings.preset, "overrides": self.settings.overrides,
                         "until": self.settings.until, "max_parallel": self.settings.max_parallel},
            "captures": [c.summary() for c in self.captures],
        })
