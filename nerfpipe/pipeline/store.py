"""The artifact store: one folder per (stage, cache key), committed by an atomic rename.

Layout of a run directory::

    run.json                      the capture folder and settings of the last `nerfpipe run`
    stages/<stage>/<key>/         a committed result; manifest.json is always written last
    stages/<stage>/latest.json    which key the last run used
    .work/<stage>-<key16>/        a stage being written; never read as a result
    .cache/fingerprints.json      (size, mtime) -> sha256 of input files
    logs/run-<time>.log           the full log of each run

A result exists only once ``os.rename`` has moved its finished folder, manifest included, into
``stages/<stage>/``. A process killed before that leaves at most a ``.work`` folder, which the next run
of that stage wipes (a resumable stage, such as training, resumes from its checkpoints there instead)
and ``nerfpipe clean`` removes.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nerfpipe.pipeline.hashing import sha256_file

MANIFEST = "manifest.json"


def write_json_atomic(path: Path, value: Any) -> None:
    """Write JSON so readers see the old file or the new one, never half of either."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(value, f, indent=2, ensure_ascii=False)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def describe_outputs(folder: Path) -> dict[str, dict[str, Any]]:
    """Every file under ``folder`` (but the manifest) with its size and sha256."""
    outputs = {}
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        rel = path.relative_to(folder).as_posix()
        if rel != MANIFEST:
            outputs[rel] = {"size": path.stat().st_size, "sha256": sha256_file(path)}
    return outputs


@dataclass(frozen=True)
class Committed:
    """A committed result: its folder and its manifest."""

    path: Path
    manifest: dict[str, Any]

    @property
    def key(self) -> str:
        return self.manifest["key"]


class ArtifactStore:
    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self.stages_dir = run_dir / "stages"
        self.work_dir = run_dir / ".work"

    # -- reading -------------------------------------------------------------------------------
    def result_dir(self, stage: str, key: str) -> Path:
        return self.stages_dir / stage / key

    def get(self, stage: str, key: str) -> Committed | None:
        manifest_path = self.result_dir(stage, key) / MANIFEST
        try:
            return Committed(manifest_path.parent, json.loads(manifest_path.read_text(encoding="utf-8")))
        except (FileNotFoundError, ValueError):
            return None

    def latest(self, stage: str) -> Committed | None:
        try:
            key = json.loads((self.stages_dir / stage / "latest.json").read_text())["key"]
        except (FileNotFoundError, ValueError, KeyError):
            return None
        return self.get(stage, key)

    def keys(self, stage: str) -> list[str]:
        folder = self.stages_dir / stage
        if not folder.is_dir():
            return []
        return sorted(p.name for p in folder.iterdir() if p.is_dir() and (p / MANIFEST).is_file())

    # -- writing -------------------------------------------------------------------------------
    def begin(self, stage: str, key: str, resume: bool = False) -> Path:
        """The work folder for (stage, key), inside the run directory (same filesystem).

        Empty unless ``resume``: a resumable stage (training) finds what a killed earlier attempt at the
        same key left there, its checkpoints, and carries on. It is never a result either way.
        """
        work = self.work_dir / f"{stage}-{key[:16]}"
        if work.exists() and not resume:
            shutil.rmtree(work)  # what a killed earlier attempt left
        work.mkdir(parents=True, exist_ok=True)
        return work

    def commit(self, stage: str, key: str, work: Path, manifest: dict[str, Any], replace: bool = False) -> Committed:
        """Write the manifest last, then move the work folder into place with one atomic rename.

        If a result of this key already exists, ``replace`` (a forced rerun) swaps it for the new one;
        otherwise the existing result stands and the new work is discarded: two writers racing on one
        key leave one complete result.
        """
        manifest = {**manifest, "outputs": describe_outputs(work)}
        write_json_atomic(work / MANIFEST, manifest)
        _fsync_dir(work)
        target = self.result_dir(stage, key)
        target.parent.mkdir(parents=True, exist_ok=True)
        if replace and target.exists():
            trash = self.work_dir / f"trash-{stage}-{uuid.uuid4().hex[:8]}"
            os.rename(target, trash)
            shutil.rmtree(trash)
        try:
            os.rename(work, target)
        except OSError as err:
            if err.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                raise
            shutil.rmtree(work)  # another writer committed the same key first; its result stands
        _fsync_dir(target.parent)
        self.set_latest(stage, key)
        return Committed(target, json.loads((target / MANIFEST).read_text(encoding="utf-8")))

    def set_latest(self, stage: str, key: str) -> None:
        write_json_atomic(self.stages_dir / stage / "latest.json", {"key": key, "at": time.time()})

    def abandon(self, work: Path) -> None:
        shutil.rmtree(work, ignore_errors=True)

    # -- pruning -------------------------------------------------------------------------------
    def clean(self, keep_all_keys: bool = False) -> tuple[int, int]:
        """Remove results other than each stage's latest, and any work folders. Returns (folders, bytes)."""
        removed, freed = 0, 0
        victims: list[Path] = []
        if self.work_dir.exists():
            victims.extend(self.work_dir.iterdir())
        if not keep_all_keys and self.stages_dir.is_dir():
            for stage_dir in self.stages_dir.iterdir():
                latest = self.latest(stage_dir.name)
                for child in stage_dir.iterdir():
                    if child.is_dir() and (latest is None or child.name != latest.key):
                        victims.append(child)
        for victim in victims:
            freed += sum(p.stat().st_size for p in victim.rglob("*") if p.is_file()) if victim.is_dir() else 0
            shutil.rmtree(victim) if victim.is_dir() else victim.unlink()
            removed += 1
        return removed, freed
