"""What the runner plans and reports: each stage's parameters, inputs and cache key (PlannedStage), its state
and why (StageStatus, stale_reasons), and what a run did with it (StageOutcome)."""

from __future__ import annotations

import importlib.metadata
import logging
import os
import platform
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Mapping, Sequence

from nerfpipe.pipeline.budget import takes_part
from nerfpipe.pipeline.dag import Dag
from nerfpipe.pipeline.errors import ParamError
from nerfpipe.pipeline.fingerprint import Fingerprint, FingerprintCache, diff_inputs
from nerfpipe.pipeline.hashing import cache_key
from nerfpipe.pipeline.params import build_params, cache_view, describe_changes
from nerfpipe.pipeline.stage import Stage, capture_root
from nerfpipe.pipeline.store import MANAGED, ArtifactStore, Committed, Damage, is_run_dir

log = logging.getLogger("nerfpipe.pipeline.plan")


@dataclass(frozen=True)
class PlannedStage:
    """A stage with its resolved parameters, fingerprinted inputs and cache key."""

    stage: Stage
    params: Any
    files: tuple[Fingerprint, ...]
    material: dict[str, Any]
    key: str
    elastic: bool = False  # whether it takes what the job's budget leaves (``Stage.elastic``)

    @property
    def name(self) -> str:
        return self.stage.name


def check_run_dir(source: Path, run_dir: Path) -> None:
    """Refuse a run directory that is the capture folder or lies inside it (its renders and screenshots would be
    read as photos by the next run), and a capture inside a folder the run replaces (``exports/``, ``report/``,
    ``logs/``, ``stages/``...: the run would delete the photos it reads)."""
    root, out = source.resolve(), run_dir.resolve()
    for part in out.parts:
        if len(os.fsencode(part)) > NAME_MAX:
            raise ParamError(f"--out {_clip(run_dir)}: the name {_clip(part)} is {len(os.fsencode(part))} bytes, more than "
                             f"the {NAME_MAX} a file name may have; choose a shorter one")
    if len(os.fsencode(str(out))) > PATH_MAX - RUN_PATH_ROOM:
        raise ParamError(f"--out {_clip(run_dir)}: the path is {len(os.fsencode(str(out)))} bytes; a run needs "
                         f"{RUN_PATH_ROOM} more for its stage folders, within the {PATH_MAX} a path may have; "
                         "choose a shorter one")
    if source.is_dir() and (out == root or root in out.parents):
        raise ParamError(f"--out {run_dir} lies inside the capture folder {source}: what a run writes there would "
                         "be read as photos; choose a folder outside it")
    for managed in MANAGED:
        folder = out / managed
        if root == folder or folder in root.parents:
            raise ParamError(f"the capture {source} lies inside {folder}, which a run into --out {run_dir} writes "
                             "and replaces; copy the photos elsewhere, or choose another --out")


NAME_MAX, PATH_MAX = 255, 4096  # Linux's limits on a file name and a path, in bytes
RUN_PATH_ROOM = 400  # what a run adds below --out: stages/<stage>/<64-hex key>/ and the deepest artifact names


def _clip(text: object, keep: int = 40) -> str:
    text = str(text)
    return text if len(text) <= keep else f"{text[:keep]}..."


def plan_stages(dag: Dag, source: Path, run_dir: Path, preset: str | None,
                overrides: Mapping[str, Mapping[str, Any]], budget: float | str | None,
                rehash: bool = False, fingerprints: FingerprintCache | None = None) -> dict[str, PlannedStage]:
    """Every stage's parameters, fingerprinted capture files and cache key, in the DAG's order. The key hashes
    the stage's name, version and parameters (but those declared ``keyed=False``: a device, a chunk size), its
    upstream keys, its files' fingerprints and, for a stage that takes part in the job's time ``budget``, the
    budget as given. ``preset``: the job's, or None for each stage's own for this machine (``Stage.machine_preset``),
    or "" for none. ``rehash``: hash every capture file, trusting no cached fingerprint."""
    fingerprints = fingerprints or FingerprintCache(run_dir / ".cache" / "fingerprints.json", rehash)
    root = capture_root(source)
    planned: dict[str, PlannedStage] = {}
    for name in dag.order:
        stage = dag.stages[name]
        named = preset
        if preset is None and (own := stage.machine_preset(overrides.get(name, {}))) is not None:
            named = own[0]
            log.info("%s: preset %s, %s", name, *own)
        params = build_params(name, stage.Params, stage.presets, named, overrides.get(name, {}))
        files = tuple(fingerprints.fingerprint(p, root) for p in stage.input_files(source, params))
        material = {
            "stage": name,
            "version": stage.version,
            "params": cache_view(params),  # less what cannot change a result (``param(keyed=False)``)
            "upstream": {up: planned[up].key for up in dag.upstream[name]},
            "inputs": {fp.relpath: fp.sha256 for fp in files},
        }
        chosen = [*overrides.get(name, {}), *stage.presets.get(named or "", {})]
        budgeted, elastic = takes_part(stage.budget_share, stage.elastic, chosen)
        if budget is not None and budgeted:
            material["budget"] = budget
        planned[name] = PlannedStage(stage, params, files, material, cache_key(material), elastic and budget is not None)
    if is_run_dir(run_dir):  # never into a folder nerfpipe has not made its own
        fingerprints.save()
    return planned


@dataclass(frozen=True)
class StageStatus:
    """``fresh``: its result for the current settings is intact and built on its upstream's current results.
    ``stale``: settings, inputs or an upstream result changed. ``broken``: its result is damaged (``damage``
    says which file and how) and will be computed again. ``missing``: never run with these settings."""

    name: str
    state: Literal["fresh", "stale", "broken", "missing"]
    reasons: tuple[str, ...]
    key: str
    result: Committed | None  # the result for ``key`` when fresh, else the latest one, if any
    damage: Damage | None = None


@dataclass(frozen=True)
class StageOutcome:
    name: str
    action: Literal["cached", "restored", "ran", "failed", "skipped"]  # the last two: an optional stage, or after one
    key: str
    path: Path
    seconds: float
    reasons: tuple[str, ...] = ()
    summary: Mapping[str, Any] = field(default_factory=dict)


def upstream_problem(
    result: Committed, upstream: Mapping[str, Committed | None], states: Mapping[str, str] | None = None
) -> str | None:
    """Why ``result`` may not be reused although its key matches: an upstream result it was built on
    is missing or damaged, or was computed again since with other outputs (its commit id differs from the
    one recorded, and its outputs' content too). An upstream computed again to the same bytes is no
    problem: the early cutoff of ``same_outputs``."""
    built_on = result.manifest.get("upstream_commits")
    for up, current in upstream.items():
        if current is None:
            return f"upstream {up} is {(states or {}).get(up, 'missing')}"
        if built_on is not None and built_on.get(up) != current.commit_id and up not in same_outputs(result, upstream):
            return f"upstream {up} was computed again after this result"
    return None


def same_outputs(result: Committed, upstream: Mapping[str, Committed | None]) -> list[str]:
    """The upstream stages computed again since ``result`` was built on them whose outputs came out
    byte-identical (their ``content_id`` is the one recorded): ``result`` stays valid, as DVC stops a rerun
    whose stage outputs hash the same."""
    commits, contents = result.manifest.get("upstream_commits") or {}, result.manifest.get("upstream_contents") or {}
    return [up for up, current in upstream.items()
            if current is not None and commits.get(up) not in (None, current.commit_id)
            and contents.get(up) == current.content_id]


def stale_reasons(planned: PlannedStage, previous: Mapping[str, Any], inputs_label: str) -> list[str]:
    """Why ``planned`` differs from the ``previous`` manifest, e.g. ``params changed: ingest.max_size 1600 -> 800``."""
    reasons = []
    if previous.get("version") != planned.material["version"]:
        reasons.append(f"code changed: {planned.name} version {previous.get('version')} -> {planned.material['version']}")
    changes = describe_changes(planned.name, previous.get("params", {}), planned.material["params"])
    if changes:
        reasons.append("params changed: " + ", ".join(changes))
    if previous.get("budget") != planned.material.get("budget"):
        reasons.append(f"budget changed: {previous.get('budget', 'none')} -> {planned.material.get('budget', 'none')}")
    old_up, new_up = previous.get("upstream", {}), planned.material["upstream"]
    for up in sorted(set(old_up) | set(new_up)):
        if old_up.get(up) != new_up.get(up):
            reasons.append(f"upstream {up} changed")
    old_inputs = {rel: meta["sha256"] for rel, meta in previous.get("inputs", {}).items()}
    added, removed, modified = diff_inputs(old_inputs, planned.material["inputs"])
    if added or removed or modified:
        parts = [f"{len(v)} {word}" + (f" ({', '.join(v)})" if len(v) <= 3 else "")
                 for v, word in ((added, "added"), (modified, "modified"), (removed, "removed")) if v]
        reasons.append(f"{inputs_label} changed: " + ", ".join(parts))
    return reasons or ["cache key changed"]


def running_because(reasons: Sequence[str]) -> str:
    """The log line that starts a stage: ``running for the first time``, ``running again: params changed: ...``."""
    if list(reasons) == ["not run yet"]:
        return "running for the first time"
    if list(reasons) == ["forced"]:
        return "running again, as --force asked"
    return "running again: " + "; ".join(reasons)


def library_versions(names: Sequence[str]) -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in ("nerfpipe", *names):
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def stage_statuses(plan: Mapping[str, PlannedStage], store: ArtifactStore, dag: Dag,
                   verify: bool = False) -> list[StageStatus]:
    """Each planned stage's state in ``store``, checking every result it would reuse: sizes and times, or
    ``verify`` sha256."""
    statuses: dict[str, StageStatus] = {}
    for name, planned in plan.items():
        found = store.inspect(name, planned.key, full=verify)
        if isinstance(found, Committed):
            upstream = {up: statuses[up].result if statuses[up].state == "fresh" else None for up in dag.upstream[name]}
            problem = upstream_problem(found, upstream, {up: statuses[up].state for up in upstream})
            if problem is not None:
                statuses[name] = StageStatus(name, "stale", (problem,), planned.key, found)
            else:
                reasons = () if store.latest_key(name) == planned.key else ("cached by an earlier run",)
                reasons += tuple(f"upstream {up} was computed again to the same outputs: kept"
                                 for up in same_outputs(found, upstream))
                statuses[name] = StageStatus(name, "fresh", reasons, planned.key, found)
        elif isinstance(found, Damage):
            statuses[name] = StageStatus(name, "broken", (f"damaged result: {found}",), planned.key, None, found)
        elif (latest := store.latest(name)) is not None:
            why = stale_reasons(planned, latest.manifest, planned.stage.inputs_label)
            statuses[name] = StageStatus(name, "stale", tuple(why), planned.key, latest)
        else:
            statuses[name] = StageStatus(name, "missing", (never_ran(store, planned),), planned.key, None)
    return list(statuses.values())


def never_ran(store: ArtifactStore, planned: PlannedStage) -> str:
    """Why a stage with no result and no earlier run to compare with is missing."""
    aside = store.set_aside_as(planned.name, planned.key)
    if aside is not None:
        return f"its damaged result was moved aside to {aside}"
    failure = store.failure(planned.name, planned.key)
    return f"failed in the last run: {failure}" if failure is not None else "not run yet"
