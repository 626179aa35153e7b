"""Locks the kernel releases when their process dies: one writer per run directory, one per stage result.

``flock`` belongs to the open file description, so a crashed or killed process cannot leave a lock
stuck: the next one takes it at once. Each lock file also records who holds it, for messages.

On a shared filesystem Linux maps ``flock`` onto POSIX byte-range locks (NFSv4, and NFSv3 with lockd;
Lustre and CephFS with their lock options), so the same locks hold across the nodes of a cluster. A
node that dies there keeps its locks until the server's lease runs out (90 s by default for NFSv4).
"""

from __future__ import annotations

import fcntl
import logging
import os
import socket
import time
from pathlib import Path

from nerfpipe.pipeline.errors import RunLockedError
from nerfpipe.pipeline.store import LOCK_NAME

log = logging.getLogger("nerfpipe")


class FileLock:
    """An exclusive ``flock`` on ``path``; the file says ``pid N on HOST since HH:MM:SS`` while held."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd: int | None = None

    def try_acquire(self) -> str | None:
        """Take the lock if it is free and return None; else return who holds it."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 512, 0).decode("utf-8", "replace").strip() or "another process"
            os.close(fd)
            return holder
        self._claim(fd)
        return None

    def acquire_waiting(self) -> None:
        """Take the lock, waiting for its holder to finish (or die) first."""
        holder = self.try_acquire()
        if holder is None:
            return
        log.info("%s: waiting for %s", self.path.name, holder)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        fcntl.flock(fd, fcntl.LOCK_EX)
        self._claim(fd)

    def _claim(self, fd: int) -> None:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()} since {time.strftime('%H:%M:%S')}".encode(), 0)
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            os.ftruncate(self._fd, 0)
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __exit__(self, *exc: object) -> None:
        self.release()


class RunLock(FileLock):
    """One run at a time in a run directory: a second one fails at once, naming the holder."""

    def __init__(self, run_dir: Path) -> None:
        super().__init__(run_dir / LOCK_NAME)

    def acquire(self) -> None:
        holder = self.try_acquire()
        if holder is not None:
            raise RunLockedError(
                f"{self.path.parent}: run directory is in use by {holder}; wait for that run to finish "
                f"or use another --out"
            )

    def __enter__(self) -> "RunLock":
        self.acquire()
        return self


class StageLock(FileLock):
    """One writer per (stage, cache key): a second one waits, then finds the first one's result.

    Lock files live in ``.locks/`` (never in ``.work/``, which ``clean`` empties: a lock file deleted while
    held would let the next writer lock a new file beside the old holder).
    """

    def __init__(self, run_dir: Path, stage: str, key: str) -> None:
        super().__init__(run_dir / ".locks" / f"{stage}-{key[:16]}.lock")

    def __enter__(self) -> "StageLock":
        self.acquire_waiting()
        return self
