"""Typed errors.

``NerfpipeError`` and its subclasses are *user* errors: bad photos, bad pose files, bad flags, a run
directory in use. The CLI prints them as one line and exits non-zero; ``--debug`` adds the traceback.
Any other exception is a bug in nerfpipe and is shown with its traceback.
"""

from __future__ import annotations

import errno
import shutil
from pathlib import Path


class NerfpipeError(Exception):
    """A problem the user can fix. ``str(err)`` is the one line the CLI prints."""

    exit_code = 1


class ParamError(NerfpipeError):
    """An unknown stage, parameter or preset, or a value of the wrong type or range."""

    exit_code = 2


class InputError(NerfpipeError):
    """A problem with the user's input files or folders."""

    def __init__(self, path: Path | str | None, problem: str, advice: str = "") -> None:
        self.path = Path(path) if path is not None else None
        self.problem = problem
        self.advice = advice
        where = f"{self.path}: " if self.path is not None else ""
        tail = f"; {advice}" if advice else ""
        super().__init__(f"{where}{problem}{tail}")


class BadPhotoError(InputError):
    """One photo cannot be used (corrupt, truncated, empty, unsupported, duplicate)."""


class RunLockedError(NerfpipeError):
    """Another nerfpipe process is using the run directory."""


class StageError(NerfpipeError):
    """A stage could not produce its result for a reason the user can act on."""


class UpstreamNotReadyError(NerfpipeError):
    """``--only STAGE`` was asked for while an upstream stage has no result for the current settings."""


class DiskFullError(NerfpipeError):
    """The disk holding the run directory is full, or too full for what a stage is about to write."""

    def __init__(
        self, path: Path | str, needed: int | None = None, free: int | None = None, stage: str | None = None
    ) -> None:
        self.path = Path(path)
        self.needed, self.free = needed, free
        if needed is not None and free is not None:
            problem = (f"not enough free space{f' for {stage}' if stage else ''} "
                       f"(needs about {format_bytes(needed)}, {format_bytes(free)} free)")
        else:
            problem = "the disk is full" + (f" (it filled up while {stage} was writing)" if stage else "")
        super().__init__(f"{self.path}: {problem}; free some space, or pass --out a folder on a disk with more room")


# errno values that mean "the disk cannot take more": no space, and over a user's quota
DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})


def format_bytes(n: int) -> str:
    """``1536`` -> ``'1.5 KB'``; decimal units, as ``df -H`` and file managers show them."""
    value = float(n)
    for unit in ("bytes", "KB", "MB", "GB"):
        if abs(value) < 1000 or unit == "GB":
            return f"{value:.0f} {unit}" if unit == "bytes" else f"{value:.1f} {unit}"
        value /= 1000
    raise AssertionError("unreachable")


def os_error_to_user_error(err: OSError, where: Path | str) -> NerfpipeError | None:
    """The one-line user error for an ``OSError`` raised while writing under ``where``, or ``None``.

    A full disk or quota and a read-only filesystem are the user's to fix; anything else is left alone.
    """
    if err.errno in DISK_FULL_ERRNOS:
        return DiskFullError(where)
    if err.errno == errno.EROFS:
        return InputError(where, "is on a read-only filesystem", "pass --out a folder on a writable disk")
    return None


DISK_NEARLY_FULL = 1 << 20  # bytes: a stage failing with less than this left is taken to have filled the disk


def disk_full(err: BaseException, work: Path, run_dir: Path, stage: str) -> DiskFullError | None:
    """``DiskFullError`` if ``err`` came from a full disk: ENOSPC, or any failure (libraries that write
    natively, like torch.save, raise their own errors) while the disk has less than a MiB left."""
    if isinstance(err, OSError) and err.errno in DISK_FULL_ERRNOS:
        return DiskFullError(run_dir, stage=stage)
    if not isinstance(err, Exception):
        return None
    try:
        free = shutil.disk_usage(work if work.exists() else run_dir).free
    except OSError:
        return None
    return DiskFullError(run_dir, stage=stage) if free < DISK_NEARLY_FULL else None


def out_of_memory(err: BaseException, stage: str) -> StageError | None:
    """``StageError`` if ``err`` is a stage running out of memory: Python's ``MemoryError``, or the allocation
    failure a native library raises as its own error (torch: ``can't allocate memory``), as one line."""
    text = str(err)
    if isinstance(err, MemoryError) or "can't allocate memory" in text or "out of memory" in text.lower():
        detail = text.strip().splitlines()[-1][:160] if text.strip() else type(err).__name__
        return StageError(f"{stage}: ran out of memory ({detail}); lower the sizes it works at (`nerfpipe stages "
                          f"{stage}` lists them), or run it where more memory is free")
    return None
