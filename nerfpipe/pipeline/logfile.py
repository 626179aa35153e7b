"""A run's log file: every message of the run at DEBUG level, in ``RUN_DIR/logs/``."""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Iterator
from pathlib import Path

log = logging.getLogger("nerfpipe")


class LogFileHandler(logging.FileHandler):
    """The run's log file. When it cannot be written (the disk filled up), it stops writing instead of
    printing logging's "--- Logging error ---" traceback: the terminal still gets the messages, and the
    error that follows says what happened."""

    def handleError(self, record: logging.LogRecord) -> None:
        self.close()
        self.setLevel(logging.CRITICAL + 1)


@contextlib.contextmanager
def log_to_file(logs: Path, label: str = "run") -> Iterator[Path]:
    """Log everything under ``nerfpipe`` into a new file in ``logs`` while the block runs; yields its path."""
    logs.mkdir(parents=True, exist_ok=True)
    path = logs / f"{label}-{time.strftime('%Y%m%d-%H%M%S')}-{int(time.time() * 1000) % 1000:03d}-{os.getpid()}.log"
    handler = LogFileHandler(path, encoding="utf-8")
    handler.setLevel(logging.DEBUG)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)-7s %(name)s: %(message)s"))
    root = logging.getLogger("nerfpipe")
    previous_level = root.level
    root.setLevel(logging.DEBUG)
    root.addHandler(handler)
    try:
        yield path
    except BaseException as err:
        log.debug("run ended by %s", type(err).__name__, exc_info=True)
        raise
    finally:
        root.removeHandler(handler)
        root.setLevel(previous_level)
        handler.close()
