"""A stage killed mid-write (SIGKILL) leaves no committed result, and the next run completes."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

from nerfpipe.pipeline import ArtifactStore, Pipeline
from nerfpipe.stages import default_stages
from tests.helpers import interruptible, shared


def start_and_interrupt(run_dir, sig) -> subprocess.Popen:
    """Start ingest of the 100 lego photos and send ``sig`` once a few of its PNGs are on disk."""
    lego = shared("nerf_synthetic_lego_400", "train")
    cmd = [sys.executable, "-m", "nerfpipe", "run", str(lego), "--out", str(run_dir), "--until", "ingest",
           "--set", "ingest.workers=1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=interruptible)
    written: list = []
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        written = list((run_dir / ".work").glob("ingest-*/images/*.png"))
        if len(written) >= 5:
            break
        time.sleep(0.005)
    assert proc.poll() is None, "ingest finished before it could be killed: " + proc.stderr.read().decode()
    proc.send_signal(sig)
    proc.wait(timeout=60)
    assert len(written) >= 5  # it really was stopped in the middle of writing its images
    return proc


def test_sigkill_mid_write_leaves_nothing_committed_and_the_next_run_completes(tmp_path):
    run_dir = tmp_path / "run"
    start_and_interrupt(run_dir, signal.SIGKILL)
    store = ArtifactStore(run_dir)
    assert store.keys("ingest") == [] and store.latest("ingest") is None
    assert not (run_dir / "stages" / "ingest" / "latest.json").exists()
    pipe = Pipeline.from_run_dir(default_stages(), run_dir)
    assert pipe.status()[0].state == "missing"

    outcome = pipe.run(until="ingest")[0]  # the lock of the killed run is not stuck either
    assert outcome.action == "ran"
    images = json.loads((outcome.path / "images.json").read_text())["images"]
    assert len(images) == 100 and len(list((outcome.path / "images").iterdir())) == 100
    assert not list((run_dir / ".work").glob("ingest-*"))


def test_ctrl_c_stops_promptly_says_so_and_commits_nothing(tmp_path):
    run_dir = tmp_path / "run"
    proc = start_and_interrupt(run_dir, signal.SIGINT)
    stderr = proc.stderr.read().decode()
    assert proc.returncode == 130 and "interrupted" in stderr and "Traceback" not in stderr
    assert ArtifactStore(run_dir).keys("ingest") == []
    assert not list((run_dir / ".work").glob("ingest-*"))  # the work folder was removed on the way out
