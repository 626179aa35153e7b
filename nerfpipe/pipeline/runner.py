"""Plan, inspect and run a pipeline of stages over one capture folder and one run directory.

Every cache key is computed before anything runs: a stage's key hashes its name, version, parameters,
the keys of its upstream stages and the fingerprints of the capture files it reads. So ``status`` can
say what would rerun, and why, without running anything, and a rerun with nothing changed only stats
the input files.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
import time
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

from nerfpipe.pipeline.budget import Allotment, JobBudget, check_least_seconds
from nerfpipe.pipeline.dag import Dag
from nerfpipe.pipeline.errors import (DiskFullError, InputError, NerfpipeError, ParamError, StageError,
                                      UpstreamNotReadyError, disk_full, os_error_to_user_error, out_of_memory)
from nerfpipe.pipeline.lock import RunLock, StageLock
from nerfpipe.pipeline.fingerprint import FingerprintCache
from nerfpipe.pipeline.logfile import log_to_file
from nerfpipe.pipeline.plan import (
    check_run_dir,
    PlannedStage,
    StageOutcome,
    StageStatus,
    library_versions,
    never_ran,
    plan_stages,
    running_because,
    stage_statuses,
    same_outputs,
    stale_reasons,
    upstream_problem,
)
from nerfpipe.pipeline.run_config import RunConfig, run_command
from nerfpipe.pipeline.stage import LaterStage, ProgressFactory, Stage, StageContext, StageInputs, _no_progress
from nerfpipe.pipeline.store import ArtifactStore, Committed, Damage
from nerfpipe.pipeline.summary import as_json

log = logging.getLogger("nerfpipe")



class Pipeline:
    """A DAG of stages bound to a capture folder (``source``) and a run directory.

    ``overrides`` maps stage name -> {param: value}; values may be text (from ``--set``) or Python values.
    """

    def __init__(
        self,
        stages: Sequence[Stage],
        source: Path,
        run_dir: Path,
        preset: str | None = None,
        overrides: Mapping[str, Mapping[str, Any]] | None = None,
        progress: ProgressFactory = _no_progress,
        debug: bool = False,
        extra: Mapping[str, Any] | None = None,
        budget: float | str | None = None,
        budget_rule: Callable[["Pipeline"], float] | None = None,
    ) -> None:
        self.dag, self.source, self.run_dir, self.preset = Dag(stages), Path(source), Path(run_dir), preset
        self.overrides = {k: dict(v) for k, v in (overrides or {}).items()}
        self.progress, self.debug = progress, debug
        # what the caller hands every running stage besides its inputs (``StageContext.extra``); not part of
        # any cache key, so it must not change what a stage writes (e.g. a viewer to watch training in)
        self.extra = dict(extra or {})
        # the job's time budget (seconds, ``auto`` sized by ``budget_rule``, or None), and the stages still to
        # run after the current one, which an elastic stage leaves their shares to
        self.budget, self.budget_rule = budget, budget_rule
        self._job: JobBudget | None = None
        self._pending: list[str] = []
        self.log_path: Path | None = None  # the log file of the latest run or run_stage
        self.store = ArtifactStore(self.run_dir)
        for stage_name in self.overrides:
            self.dag.check_name(stage_name)
        if preset and not any(preset in s.presets for s in stages):  # "": no preset, not even a machine's
            known = sorted({p for s in stages for p in s.presets})
            raise ParamError(f"unknown preset {preset!r}; presets are: {', '.join(known)}")
        self._plan: dict[str, PlannedStage] | None = None
        self._fingerprints: FingerprintCache | None = None

    @classmethod
    def from_run_dir(
        cls,
        stages: Sequence[Stage],
        run_dir: Path,
        preset: str | None = None,
        overrides: Mapping[str, Mapping[str, Any]] | None = None,
        **kwargs: Any,
    ) -> "Pipeline":
        """The pipeline as the last ``run`` in ``run_dir`` configured it, with optional changes on top."""
        config = RunConfig.load(run_dir)
        merged = {k: dict(v) for k, v in config.overrides.items()}
        for stage_name, values in (overrides or {}).items():
            merged.setdefault(stage_name, {}).update(values)
        kwargs.setdefault("budget", config.budget)
        return cls(stages, Path(config.source), run_dir, preset or config.preset, merged, **kwargs)

    # -- planning ------------------------------------------------------------------------------
    def plan(self, rehash: bool = False) -> dict[str, PlannedStage]:
        """Every stage's parameters and key; ``rehash`` hashes the capture's files again (planned anew)."""
        if self._plan is not None and not rehash:
            return self._plan
        if not self.source.exists():
            raise InputError(self.source, "capture folder does not exist", "pass a folder of photos, or a video")
        self._fingerprints = FingerprintCache(self.run_dir / ".cache" / "fingerprints.json", rehash)
        self._plan = plan_stages(self.dag, self.source, self.run_dir, self.preset, self.overrides, self.budget, rehash,
                                 self._fingerprints)
        return self._plan

    def status(self, verify: bool = False) -> list[StageStatus]:
        """Each stage's state, checking every result it would reuse: sizes and times, or ``verify`` sha256."""
        return stage_statuses(self.plan(), self.store, self.dag, verify)

    def verify(self) -> list[tuple[StageStatus, Path]]:
        """Hash every capture file and every output of every result the current settings use; move the damaged
        results aside (a changed photo makes the stages that read it stale).

        Returns each damaged stage's status and where its folder went; the next ``run`` computes it again.
        """
        moved = []
        self.plan(rehash=True)
        self.store.prepare()
        with RunLock(self.run_dir):
            for status in self.status(verify=True):
                if status.damage is not None:
                    moved.append((status, self.store.set_aside(status.name, status.key, status.damage)))
        return moved

    def result(self, stage: str) -> Committed | None:
        """The committed result of ``stage`` for the current settings, if there is one."""
        return self.store.get(stage, self.plan()[self.dag.check_name(stage)].key)

    def artifact(self, name: str, what: str | None = None) -> Path:
        """The path of artifact ``name`` in the current result of the stage that provides it.

        Raises ``InputError`` naming the run and the command that makes it when that stage has no result
        for the current settings (``what``: the artifact as the message names it)."""
        stage = self.dag.provider.get(name)
        if stage is None:
            raise ValueError(f"no stage provides an artifact named {name!r}")
        result = self.result(stage)
        if result is None:
            raise InputError(self.run_dir, f"has no {what or name} for its current settings",
                             f"run `{self.command(until=stage)}` first")
        return result.path / self.dag.stages[stage].provides[name]

    def command(self, until: str | None = None) -> str:
        """The ``nerfpipe run`` command line that repeats this pipeline's settings (``run_command``)."""
        return run_command(self.source, self.run_dir, self.preset, self.overrides, self.budget, until)

    def optional_artifact(self, name: str) -> Path | None:
        """``artifact``, or None where its stage has no current result (or this pipeline has no such stage)."""
        stage = self.dag.provider.get(name)
        result = None if stage is None else self.result(stage)
        return None if result is None else result.path / self.dag.stages[stage].provides[name]

    def describe(self, status: StageStatus) -> list[str]:
        """What the stage says about its committed result (``Stage.describe``), for ``nerfpipe status``."""
        if status.result is None:
            return []
        return self.dag.stages[status.name].describe(status.result.path, status.result.manifest)

    def stage_inputs(self, name: str) -> StageInputs:
        """What stage ``name`` reads, from its upstream results for the current settings.

        Raises ``UpstreamNotReadyError`` when an upstream stage has no intact result for them.
        """
        return self._inputs(name, self._upstream_results(name))

    def _upstream_results(self, name: str) -> dict[str, Committed]:
        results = {}
        for up in self.dag.upstream[self.dag.check_name(name)]:
            up_result = self.store.get(up, self.plan()[up].key)
            if up_result is None:  # only reachable with --only: otherwise upstream ran just before
                status = next(s for s in self.status() if s.name == up)
                raise UpstreamNotReadyError(
                    f"--only {name}: upstream stage {up} is {status.state} ({'; '.join(status.reasons)}); "
                    f"run it first, e.g. with --until {up}"
                )
            results[up] = up_result
        return results

    def _inputs(self, name: str, upstream: Mapping[str, Committed]) -> StageInputs:
        planned = self.plan()[name]
        artifacts: dict[str, Path] = {}
        for up, up_result in upstream.items():
            for artifact in planned.stage.requires:
                if self.dag.provider[artifact] == up:
                    artifacts[artifact] = up_result.path / self.dag.stages[up].provides[artifact]
        return StageInputs(artifacts, self.source, planned.files)

    # -- running -------------------------------------------------------------------------------
    def run(self, until: str | None = None, only: str | None = None, force: Sequence[str] = ()) -> list[StageOutcome]:
        """Run what is not fresh among the selected stages. ``force`` reruns those stages; their downstream runs
        again only where a forced stage's outputs came out different (early cutoff, ``same_outputs``)."""
        selected = self.dag.select(until=until, only=only)
        forced: set[str] = set()
        for name in force:
            if self.dag.check_name(name) not in selected:
                chosen = f"--until {until}" if until else f"--only {only}"
                raise ParamError(f"--force {name}: not among the stages {chosen} runs; drop --force or choose stages that include it")
            forced.add(name)
        check_run_dir(self.source, self.run_dir)
        self.plan()  # a capture that cannot be read is refused before the run directory is made
        ceiling = getattr(self.budget_rule, "ceiling", None)  # the most --budget auto can give
        check_least_seconds([self.plan()[name] for name in selected], self.budget, ceiling)
        self.store.prepare()
        if self._fingerprints is not None:
            self._fingerprints.save()  # planned before the folder was nerfpipe's: the hashes are kept now
        with self._user_os_errors(), RunLock(self.run_dir), self._log_to_file():
            planned = self.plan()
            self.save_config()
            if self.budget is not None:
                rule = self.budget_rule
                self._job = JobBudget(self.budget, (lambda: rule(self)) if rule is not None else None)
            outcomes: list[StageOutcome] = []
            for i, name in enumerate(selected):
                self._pending = list(selected[i + 1:])
                missing = [o.name for o in outcomes if o.action in ("failed", "skipped") and o.name in self.dag.ancestors(name)]
                if missing:  # an optional stage upstream made nothing
                    log.warning("%s: skipped, since %s made nothing", name, missing[0])
                    outcomes.append(StageOutcome(name, "skipped", planned[name].key, self.run_dir, 0.0, (f"{missing[0]} failed",)))
                    continue
                try:
                    outcomes.append(self._run_one(planned[name], forced=name in forced))
                except StageError as err:
                    if not planned[name].stage.optional:
                        raise
                    log.warning("%s (the run goes on without it)", err)
                    outcomes.append(StageOutcome(name, "failed", planned[name].key, self.run_dir, 0.0, (str(err),)))
            return outcomes

    def run_stage(self, name: str, force: bool = False) -> StageOutcome:
        """Run one stage whose upstream results exist, in whichever process or node this is.

        What a batch executor calls for each (capture, stage). It holds no run lock (the batch's driver
        does): only the stage lock, so stages of one capture may run at once in different processes.
        Raises ``UpstreamNotReadyError`` when an upstream stage has no result.
        """
        planned = self.plan()[self.dag.check_name(name)]
        self.store.prepare()
        with self._user_os_errors(), self._log_to_file(name):
            return self._run_one(planned, forced=force)

    @contextlib.contextmanager
    def _user_os_errors(self) -> Iterator[None]:
        """A full disk or a read-only filesystem while writing the run directory is a one-line user error."""
        try:
            yield
        except OSError as err:
            user_error = os_error_to_user_error(err, self.run_dir)
            if user_error is None:
                raise
            raise user_error from err

    def _run_one(self, planned: PlannedStage, forced: bool) -> StageOutcome:
        # Two writers of one (stage, key), in two processes or on two nodes of a cluster: the second
        # waits here, then finds the first one's result. A killed holder's lock goes with it.
        with StageLock(self.run_dir, planned.name, planned.key):
            return self._run_locked(planned, forced)

    def restore(self, name: str) -> StageOutcome | None:
        """If stage ``name`` has a result for the current settings, make it the latest and say so; else None."""
        return self._restore(self.plan()[self.dag.check_name(name)])

    def _restore(self, planned: PlannedStage) -> StageOutcome | None:
        name = planned.name
        hit = self.store.get(name, planned.key)
        current = self._current_upstream(name)
        if hit is None or upstream_problem(hit, current) is not None:
            return None
        if self.store.latest_key(name) == planned.key:
            same = same_outputs(hit, current)  # early cutoff: what it was built on came out the same
            log.info("%s: %s", name, f"{' and '.join(same)} computed again to the same outputs; its result stands"
                     if same else "up to date, reusing its result")
            return StageOutcome(name, "cached", planned.key, hit.path, 0.0)
        self.store.set_latest(name, planned.key)
        log.info("%s: reusing the result of an earlier run with these settings", name)
        return StageOutcome(name, "restored", planned.key, hit.path, 0.0)

    def _current_upstream(self, name: str) -> dict[str, Committed | None]:
        return {up: self.store.get(up, self.plan()[up].key) for up in self.dag.upstream[name]}

    def _why_run(self, planned: PlannedStage, forced: bool) -> tuple[list[str], bool]:
        """Why ``planned`` runs, and whether its new result replaces one of the same key.

        A damaged result is moved aside first (and said so); an intact one built on upstream results that
        have since been computed again is replaced.
        """
        name = planned.name
        if forced:
            return ["forced"], True
        found = self.store.inspect(name, planned.key)
        if isinstance(found, Damage):
            aside = self.store.set_aside(name, planned.key, found)
            log.warning("%s: its cached result is damaged (%s); moved it aside to %s", name, found, aside)
            return [f"its cached result was damaged: {found}"], False
        if isinstance(found, Committed):
            problem = upstream_problem(found, self._current_upstream(name))
            return [problem or "cache key changed"], True
        latest = self.store.latest(name)
        if latest is None:
            return [never_ran(self.store, planned)], False
        return stale_reasons(planned, latest.manifest, planned.stage.inputs_label), False

    def _run_locked(self, planned: PlannedStage, forced: bool) -> StageOutcome:
        name, key = planned.name, planned.key
        restored = None if forced else self._restore(planned)
        if restored is not None:
            return restored
        upstream = self._upstream_results(name)
        inputs = self._inputs(name, upstream)
        for up in upstream:
            self.store.set_latest(up, self.plan()[up].key)

        reasons, replace = self._why_run(planned, forced)
        log.info("%s: %s", name, running_because(reasons))

        self._check_space(planned, inputs)
        work = self.store.begin(name, key, resume=planned.stage.resumable and not forced)
        started = time.time()
        ctx = StageContext(log=logging.getLogger(f"nerfpipe.stages.{name}"), progress=self.progress, debug=self.debug,
                           extra=self.extra, allotment=self._allotment(planned), later=self._later(planned))
        try:
            summary = as_json(planned.stage.run(inputs, work, planned.params, ctx))
            missing = [rel for rel in planned.stage.provides.values() if not (work / rel).exists()]
            if missing:
                raise RuntimeError(f"stage {name} did not write its declared artifacts {missing}")
        except NerfpipeError as err:
            # Kept for the user to inspect (logs the error message may point at) unless empty; it is not a
            # result, and the next attempt at this key wipes it. ``status`` says the stage failed, and why.
            self.store.record_failure(name, key, str(err))
            if work.is_dir() and not any(work.iterdir()):
                self.store.abandon(work)
            raise
        except BaseException as err:
            full = disk_full(err, work, self.run_dir, name) or out_of_memory(err, name)
            if not planned.stage.resumable:
                self.store.abandon(work)
            if full is not None:
                raise full from err
            raise
        finished = time.time()
        manifest = {
            **planned.material,
            "key": key,
            "upstream_commits": {up: result.commit_id for up, result in upstream.items()},
            "upstream_contents": {up: result.content_id for up, result in upstream.items()},
            "inputs": {fp.relpath: {"size": fp.size, "sha256": fp.sha256} for fp in planned.files},
            "timings": {"started": started, "finished": finished, "seconds": round(finished - started, 4),
                        **(ctx.allotment.record() if ctx.allotment else {})},
            "libraries": library_versions(planned.stage.libraries),
            "summary": summary,
        }
        committed = self.store.commit(name, key, work, manifest, replace=replace)
        log.info("%s: done in %.1f s -> %s", name, finished - started, committed.path)
        return StageOutcome(name, "ran", key, committed.path, finished - started, tuple(reasons), summary)

    def _allotment(self, planned: PlannedStage) -> Allotment | None:
        """The part of the job's budget ``planned`` may take, when the job has one and the stage takes part."""
        job = self._job
        if job is None or "budget" not in planned.material:
            return None
        shares, own = [self.dag.stages[n].budget_share for n in self._pending], planned.stage.budget_share
        if planned.elastic:
            return Allotment(job.remainder(shares), job.seconds, True)
        return Allotment(job.share(own), job.seconds, spare=job.spare(own, shares))

    def _later(self, planned: PlannedStage) -> tuple[LaterStage, ...]:
        """The stages with a share of the job's budget still to run after the elastic ``planned`` (none for others)."""
        plan, job = self.plan(), self._job
        return () if job is None or not planned.elastic else tuple(
            LaterStage(plan[n].stage, plan[n].params, job.share(plan[n].stage.budget_share)) for n in self._pending
            if "budget" in plan[n].material and plan[n].stage.budget_share > 0)

    def _check_space(self, planned: PlannedStage, inputs: StageInputs) -> None:
        """Refuse to start a stage whose outputs, as it predicts them, do not fit on the disk."""
        needed = planned.stage.expected_bytes(inputs, planned.params)
        if needed:
            free = shutil.disk_usage(self.run_dir).free
            if needed > free:
                raise DiskFullError(self.run_dir, needed, free, planned.name)

    def save_config(self) -> None:
        """Record the capture folder and settings in run.json, for ``status``, ``report`` and ``view``."""
        RunConfig(str(self.source.resolve()), self.preset, self.overrides, self.budget).save(self.run_dir)

    @contextlib.contextmanager
    def _log_to_file(self, label: str = "run") -> Iterator[Path]:
        with log_to_file(self.run_dir / "logs", label) as path:
            self.log_path = path
            log.debug("run of %s into %s (preset %s, overrides %s)", self.source, self.run_dir, self.preset, self.overrides)
            yield path
