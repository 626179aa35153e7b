"""The run lock: a second run fails at once, and a killed holder does not leave it stuck."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from nerfpipe.pipeline import RunLockedError
from nerfpipe.pipeline.lock import RunLock
from tests.helpers import run_cli

HOLD = """
import sys, time
from pathlib import Path
from nerfpipe.pipeline.lock import RunLock
RunLock(Path(sys.argv[1])).acquire()
print("held", flush=True)
time.sleep(600)
"""


def hold_lock(run_dir):
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(run_dir)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_in_process_lock_is_exclusive_and_released(tmp_path):
    with RunLock(tmp_path):
        with pytest.raises(RunLockedError, match=r"run directory is in use by pid \d+ on .*; wait for that run"):
            RunLock(tmp_path).acquire()
    with RunLock(tmp_path):
        pass


def test_second_run_fails_at_once_and_a_killed_holder_releases(capture, tmp_path):
    run_dir = tmp_path / "run"
    holder = hold_lock(run_dir)
    try:
        # the holder never lets go while it lives: a run that waited for it would hit run_cli's timeout
        result = run_cli("run", capture, "--out", run_dir, "--until", "ingest")
        assert result.returncode != 0
        assert f"run directory is in use by pid {holder.pid}" in result.stderr
        assert "Traceback" not in result.stderr
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    result = run_cli("run", capture, "--out", run_dir, "--until", "ingest")
    assert result.returncode == 0, result.stderr
