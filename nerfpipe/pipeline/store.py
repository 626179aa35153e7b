"""The artifact store: one folder per (stage, cache key), committed by an atomic rename.

Layout of a run directory::

    .nerfpipe-run                 the marker: nerfpipe made this folder, and may replace what it made in it
    run.json                      the capture folder and settings of the last `nerfpipe run`
    stages/<stage>/<key>/         a committed result; manifest.json is always written last
    stages/<stage>/latest.json    which key the last run used
    stages/<stage>/failed.json    the key and error of its last failed attempt, until that key is committed
    broken/<stage>-<key12>-<time>/ a committed result found damaged, moved aside (REASON.txt says why)
    .work/<stage>-<key16>/        a stage being written; never read as a result
    .cache/fingerprints.json      (size, mtime) -> sha256 of input files
    logs/run-<time>.log           the full log of each run

A result exists only once ``os.rename`` has moved its finished folder, manifest included, into
``stages/<stage>/``. A process killed before that leaves at most a ``.work`` folder, which the next run
of that stage wipes (a resumable stage, such as training, resumes from its checkpoints there instead)
and ``nerfpipe clean`` removes.

A committed result is reused only while its files are what the manifest recorded (DVC's promise): every
read checks each output's size and modification time against the manifest, hashing a file again only
when its time differs, and ``verify`` hashes every output. A result that fails is damaged: it is never
returned as a result, and the runner moves it aside before computing it again.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import shutil
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nerfpipe.pipeline.errors import InputError
from nerfpipe.pipeline.hashing import sha256_file

MANIFEST = "manifest.json"
BROKEN = "broken"
RUN_MARKER = ".nerfpipe-run"
LOCK_NAME = ".lock"  # ``RunLock``'s file
FAILED = "failed.json"  # in stages/<stage>/: the key and error of the last failed attempt
# the folders of a run directory that nerfpipe writes, and replaces whole (exports/, report/): a capture
# inside one of them would be read while it is being replaced
MANAGED = ("stages", ".work", BROKEN, ".cache", "logs", "exports", "report", "report.earlier", "bench")


def is_run_dir(folder: Path) -> bool:
    """Whether nerfpipe made ``folder``: it carries the marker, or it is a run directory from before the marker
    (``run.json`` and ``stages/`` beside it)."""
    return (folder / RUN_MARKER).is_file() or ((folder / "run.json").is_file() and (folder / "stages").is_dir())


def require_run_dir(folder: Path, what: str) -> None:
    """Raise ``InputError`` unless nerfpipe made ``folder``: ``what`` (e.g. "the report") is replaced only
    inside a run directory, never in a folder of the user's."""
    if not is_run_dir(folder):
        raise InputError(folder, f"is not a folder nerfpipe made (no {RUN_MARKER}), so {what} is not written "
                                 "into it", "pass the --out folder of a run, or a new folder")


def write_json_atomic(path: Path, value: Any) -> None:
    """Write JSON so readers see the old file or the new one, never half of either."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(value, f, indent=2, ensure_ascii=False)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:  # a full disk, an interrupt: no half-written file stays behind
        tmp.unlink(missing_ok=True)
        raise


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def describe_outputs(folder: Path) -> dict[str, dict[str, Any]]:
    """Every file under ``folder`` (but the manifest) with its size, modification time (ns) and sha256."""
    outputs = {}
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        rel = path.relative_to(folder).as_posix()
        if rel != MANIFEST:
            stat = path.stat()
            outputs[rel] = {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns, "sha256": sha256_file(path)}
    return outputs


@dataclass(frozen=True)
class Damage:
    """Why a committed result may not be reused: its folder, the file at fault and what is wrong with it."""

    path: Path
    file: str
    problem: str

    def __str__(self) -> str:
        return f"{self.file} {self.problem}"


def verify_outputs(folder: Path, outputs: dict[str, dict[str, Any]], full: bool = False) -> Damage | None:
    """The first output of ``folder`` that is not what ``outputs`` (a manifest's) recorded, or ``None``.

    The cheap check compares sizes and modification times; a file whose time differs but whose size does
    not (a copied run directory, a ``touch``) is hashed and passes if its sha256 is unchanged. ``full``
    hashes every file. Manifests written before times were recorded are checked by size alone.
    """
    for rel, meta in outputs.items():
        path = folder / rel
        try:
            stat = path.stat()
        except OSError:
            return Damage(folder, rel, "is missing")
        if stat.st_size != meta["size"]:
            return Damage(folder, rel, f"changed size ({meta['size']} -> {stat.st_size} bytes)")
        if full or meta.get("mtime_ns", stat.st_mtime_ns) != stat.st_mtime_ns:
            if sha256_file(path) != meta["sha256"]:
                return Damage(folder, rel, "changed content (its sha256 is not the manifest's)")
    return None


def _well_formed(manifest: Any) -> bool:
    """A manifest of the shape ``commit`` writes: its key, its sections as objects, and every output's size,
    time and sha256."""
    if not isinstance(manifest, dict) or not isinstance(manifest.get("key"), str):
        return False
    if any(not isinstance(manifest.get(k, {}), dict) for k in ("params", "upstream", "upstream_commits",
                                                                 "upstream_contents", "inputs", "summary", "timings")):
        return False
    outputs = manifest.get("outputs")
    return isinstance(outputs, dict) and all(
        isinstance(meta, dict) and isinstance(meta.get("size"), int) and isinstance(meta.get("sha256"), str)
        and isinstance(meta.get("mtime_ns", 0), int) for meta in outputs.values())


@dataclass(frozen=True)
class Committed:
    """A committed result: its folder and its manifest."""

    path: Path
    manifest: dict[str, Any]

    @property
    def key(self) -> str:
        return self.manifest["key"]

    @property
    def commit_id(self) -> str:
        """Unique to this commit: a result computed again under the same key gets a new one."""
        return self.manifest.get("commit") or f"{self.key}@{self.manifest.get('timings', {}).get('finished')}"

    @property
    def content_id(self) -> str:
        """The same for two commits whose outputs are byte-identical: a hash of each output's path and sha256."""
        outputs = self.manifest.get("outputs", {})
        listing = "\n".join(f"{rel}\t{outputs[rel]['sha256']}" for rel in sorted(outputs))
        return hashlib.sha256(listing.encode("utf-8")).hexdigest()


class ArtifactStore:
    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self.stages_dir = run_dir / "stages"
        self.work_dir = run_dir / ".work"

    # -- reading -------------------------------------------------------------------------------
    def result_dir(self, stage: str, key: str) -> Path:
        return self.stages_dir / stage / key

    def inspect(self, stage: str, key: str, full: bool = False) -> Committed | Damage | None:
        """The result of (stage, key) if it is intact, what is wrong with it if not, ``None`` if there is none."""
        folder = self.result_dir(stage, key)
        if not folder.is_dir():
            return None
        try:
            manifest = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
        except FileNotFoundError:
            return Damage(folder, MANIFEST, "is missing")
        except (OSError, ValueError):
            return Damage(folder, MANIFEST, "is not readable JSON")
        if not _well_formed(manifest):
            return Damage(folder, MANIFEST, "has no key or outputs, or an output without its size and sha256")
        if manifest["key"] != key or manifest.get("stage", stage) != stage:
            return Damage(folder, MANIFEST, f"belongs to another result ({manifest.get('stage', stage)} "
                                            f"{manifest['key'][:12]}), not to the folder {stage}/{key[:12]}")
        return verify_outputs(folder, manifest["outputs"], full) or Committed(folder, manifest)

    def get(self, stage: str, key: str) -> Committed | None:
        """The intact result of (stage, key), by the cheap check, or ``None``."""
        found = self.inspect(stage, key)
        return found if isinstance(found, Committed) else None

    def latest_key(self, stage: str) -> str | None:
        """The key the last run of ``stage`` used, whatever became of its result."""
        try:
            key = json.loads((self.stages_dir / stage / "latest.json").read_text())["key"]
        except (OSError, ValueError, KeyError, TypeError, IndexError):
            return None  # a damaged pointer only loses which key ran last
        return key if isinstance(key, str) else None

    def latest(self, stage: str) -> Committed | None:
        """The intact result the last run of ``stage`` used, if any."""
        key = self.latest_key(stage)
        return None if key is None else self.get(stage, key)

    def keys(self, stage: str) -> list[str]:
        folder = self.stages_dir / stage
        if not folder.is_dir():
            return []
        return sorted(p.name for p in folder.iterdir() if p.is_dir() and (p / MANIFEST).is_file())

    # -- writing -------------------------------------------------------------------------------
    def prepare(self) -> None:
        """Make the run directory, or raise ``InputError`` saying why it cannot be one."""
        where = self.run_dir
        existing = next(p for p in (where, *where.parents) if p.exists() or p == p.parent)
        if existing.exists() and not existing.is_dir():
            advice = ("pass --out a new folder or the folder of an earlier run" if existing == where
                      else f"pass --out a path that does not run through a file (not {where})")
            raise InputError(existing, "is a file, not a folder", advice)
        try:
            where.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            why = "it is on a read-only filesystem" if err.errno == errno.EROFS else err.strerror or str(err)
            raise InputError(where, f"cannot be made in {existing} ({why})",
                             "pass --out a folder on a writable disk") from None
        if os.statvfs(where).f_flag & os.ST_RDONLY:
            raise InputError(where, "is on a read-only filesystem", "pass --out a folder on a writable disk")
        if not os.access(where, os.W_OK | os.X_OK):
            raise InputError(where, "cannot be written to (permission denied)", "pass --out a folder you may write to")
        self._claim()

    def _claim(self) -> None:
        """Mark a new or empty folder as nerfpipe's; refuse a folder of the user's that holds anything, since a
        run replaces its ``exports/``, ``report/``, ``logs/`` and ``stages/`` whole."""
        where = self.run_dir
        if (where / RUN_MARKER).is_file():
            return
        if not is_run_dir(where):
            entries = sorted(p.name for p in where.iterdir() if p.name != LOCK_NAME)  # a racing run's lock is ours
            if entries:
                shown = ", ".join(entries[:3]) + (f" and {len(entries) - 3} more" if len(entries) > 3 else "")
                raise InputError(where, f"is a folder nerfpipe did not make, and holds {shown}",
                                 "pass --out a new or empty folder, or the folder of an earlier run")
        write_json_atomic(where / RUN_MARKER, {"made_by": "nerfpipe", "at": time.time()})

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
        key leave one complete result. A damaged result of this key is moved aside (``set_aside``) first.
        """
        manifest = {**manifest, "commit": uuid.uuid4().hex, "outputs": describe_outputs(work)}
        write_json_atomic(work / MANIFEST, manifest)
        _fsync_dir(work)
        target = self.result_dir(stage, key)
        target.parent.mkdir(parents=True, exist_ok=True)
        found = self.inspect(stage, key)
        if isinstance(found, Damage):
            self.set_aside(stage, key, found)
        elif replace and found is not None:
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
        if self.failure(stage, key) is not None:
            (self.stages_dir / stage / FAILED).unlink(missing_ok=True)
        return Committed(target, json.loads((target / MANIFEST).read_text(encoding="utf-8")))

    def set_aside(self, stage: str, key: str, damage: Damage) -> Path:
        """Move the damaged result of (stage, key) out of the store, into ``broken/``, and say why there.

        Nothing is deleted: the folder keeps whatever is left of the result, for the user to look at;
        ``nerfpipe clean`` removes it.
        """
        aside = self.run_dir / BROKEN / f"{stage}-{key[:12]}-{time.strftime('%Y%m%d-%H%M%S')}-{uuid.uuid4().hex[:4]}"
        aside.parent.mkdir(parents=True, exist_ok=True)
        os.rename(self.result_dir(stage, key), aside)
        (aside / "REASON.txt").write_text(f"{stage} result {key}: {damage}\n", encoding="utf-8")
        return aside

    def set_aside_as(self, stage: str, key: str) -> Path | None:
        """The latest folder ``set_aside`` moved the result of (stage, key) to, if any is still there."""
        folder = self.run_dir / BROKEN
        found = sorted(folder.glob(f"{stage}-{key[:12]}-*")) if folder.is_dir() else []
        return found[-1] if found else None

    def record_failure(self, stage: str, key: str, error: str) -> None:
        """Remember that computing (stage, key) failed, and why, for ``status``; a commit of the key forgets it."""
        (self.stages_dir / stage).mkdir(parents=True, exist_ok=True)
        write_json_atomic(self.stages_dir / stage / FAILED, {"key": key, "error": error, "at": time.time()})

    def failure(self, stage: str, key: str) -> str | None:
        """Why the last attempt at (stage, key) failed, if it did and nothing has been committed for it since."""
        try:
            record = json.loads((self.stages_dir / stage / FAILED).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        if not isinstance(record, dict) or record.get("key") != key or not isinstance(record.get("error"), str):
            return None
        return record["error"]

    def set_latest(self, stage: str, key: str) -> None:
        write_json_atomic(self.stages_dir / stage / "latest.json", {"key": key, "at": time.time()})

    def abandon(self, work: Path) -> None:
        shutil.rmtree(work, ignore_errors=True)

    # -- pruning -------------------------------------------------------------------------------
    def clean(self, keep_all_keys: bool = False) -> tuple[int, int]:
        """Remove results other than each stage's latest, work folders and results set aside as broken: only
        what the store made, known by its names (a user's own files in these folders stay).

        Returns (entries removed, bytes freed).
        """
        victims: list[Path] = []
        for scratch, made in ((self.work_dir, _WORK_NAME), (self.run_dir / BROKEN, _BROKEN_NAME)):
            if scratch.is_dir():
                victims.extend(p for p in scratch.iterdir() if made.fullmatch(p.name) and not p.is_symlink())
        if not keep_all_keys and self.stages_dir.is_dir():
            for stage_dir in self.stages_dir.iterdir():
                if not stage_dir.is_dir() or stage_dir.is_symlink():
                    continue
                latest = self.latest(stage_dir.name)
                for child in stage_dir.iterdir():
                    if (_KEY_NAME.fullmatch(child.name) and child.is_dir() and not child.is_symlink()
                            and (latest is None or child.name != latest.key)):
                        victims.append(child)
        freed = 0
        for victim in victims:
            if victim.is_dir():
                freed += sum(p.lstat().st_size for p in victim.rglob("*") if p.is_file() and not p.is_symlink())
                shutil.rmtree(victim)
            else:
                freed += victim.lstat().st_size
                victim.unlink()
        return len(victims), freed


# the names the store gives what ``clean`` may remove: work folders ``begin`` and ``commit`` make, results
# ``set_aside`` moved, and result folders (a 64-hex key)
_WORK_NAME = re.compile(r"[a-z0-9_]+-[0-9a-z]{16}|trash-[a-z0-9_]+-[0-9a-f]{8}")
_BROKEN_NAME = re.compile(r"[a-z0-9_]+-[0-9a-z]{12}-\d{8}-\d{6}-[0-9a-f]{4}")
_KEY_NAME = re.compile(r"[0-9a-z]{64}")
