"""COLMAP's glog output captured to a file while pycolmap runs."""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path
from typing import Iterator

import pycolmap


@contextlib.contextmanager
def colmap_log(path: Path) -> Iterator[None]:
    """Send what COLMAP writes to stderr (its glog output) to ``path`` instead of the terminal.

    glog picks its log file once per process, so instead of its file destination the process-level
    stderr is pointed at the stage's log for the duration of each COLMAP call.
    """
    pycolmap.logging.logtostderr = True
    pycolmap.logging.minloglevel = 0
    sys.stderr.flush()
    saved = os.dup(2)
    with open(path, "ab") as log_file:
        os.dup2(log_file.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
