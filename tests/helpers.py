"""Helpers shared by the tests: where the data is, how to run the CLI, a small downstream stage."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from nerfpipe.geometry import cameras
from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.pipeline import Stage
from nerfpipe.pipeline.params import param
from nerfpipe.stages import IngestStage

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
TEMPLE = REPO / "samples" / "templeSparseRing"


def shared(*parts: str) -> Path:
    """A path under ../shared/data; skipped, saying so, when it is absent, and failed instead when ``CI=true``."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        message = f"shared data not found at {path}"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{message}: CI runs beside ../shared", pytrace=False)
        pytest.skip(message)
    return path


def interruptible() -> None:
    """``preexec_fn`` of a subprocess a test will send SIGINT: Ctrl-C's default action restored, since a test
    run started in the background by a script (``cmd &``) inherits SIGINT ignored, and so would the child."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_cli(*args: str, cwd: Path | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    """`python -m nerfpipe ARGS` in a fresh interpreter, as a user would run it."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"}
    return subprocess.run(
        [sys.executable, "-m", "nerfpipe", *map(str, args)],
        capture_output=True, text=True, cwd=cwd, env=env, timeout=timeout,
    )


def temple_subset(root: Path, name: str, indices: list[int]) -> Path:
    """Some of the bundled temple photos with the rows of templeSR_par.txt that calibrate them."""
    folder = root / name
    folder.mkdir(parents=True)
    rows = (TEMPLE / "templeSR_par.txt").read_text().splitlines()[1:]
    kept = [rows[i - 1] for i in indices]
    for i in indices:
        shutil.copy2(TEMPLE / f"templeSR{i:04d}.png", folder)
    (folder / "templeSR_par.txt").write_text("\n".join([str(len(kept)), *kept]) + "\n")
    return folder


def contents(outputs: dict) -> dict[str, tuple[int, str]]:
    """A manifest's outputs as (size, sha256) per file: what two computations of one result share
    (their modification times differ)."""
    return {rel: (meta["size"], meta["sha256"]) for rel, meta in outputs.items()}


@dataclass(frozen=True)
class CountParams:
    label: str = "count"
    chunk: int = param(64, "images read at a time: cannot change the count", bounds=(1, 1000), keyed=False)


class CountStage(Stage):
    """Count the ingested images: a tiny downstream stage, so the engine is tested as a real DAG."""

    name = "count"
    version = 1
    Params = CountParams
    presets = {"draft": {"label": "draft"}}
    requires = ("images_json",)
    provides = {"count": "count.json"}

    def run(self, inputs, out, params, ctx):
        images = json.loads(inputs["images_json"].read_text())["images"]
        (out / "count.json").write_text(json.dumps({params.label: len(images)}))
        return {"images": len(images)}


def two_stages() -> list[Stage]:
    return [IngestStage(), CountStage()]


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """OpenCV c2w (x right, y down, z forward) of a level camera at ``eye`` looking at ``target``, world z up."""
    return cameras.look_at(eye, target, down=np.array([0.0, 0.0, -1.0]))


@dataclass(frozen=True)
class SavedCamerasParams:
    tag: str = ""  # e.g. a digest of the camera set, so the cache key follows its content


class SavedCameras(Stage):
    """Test-only stand-in for sfm / undistort: saves a CameraSet the test made as ``artifact`` and, when
    given, images (name -> BGR pixels) as ``images_artifact``."""

    version = 1
    Params = SavedCamerasParams

    def __init__(self, cameras: CameraSet, name: str = "poses", artifact: str = "pinhole",
                 requires: tuple[str, ...] = (), images: dict | None = None, images_artifact: str | None = None,
                 check_frames: bool = False) -> None:
        self.cameras, self.name, self.artifact, self.requires = cameras, name, artifact, tuple(requires)
        self.check_frames = check_frames
        self.images, self.images_artifact = images or {}, images_artifact
        self.provides = {artifact: artifact, **({images_artifact: images_artifact} if images_artifact else {})}

    def run(self, inputs, out, params, ctx):
        import cv2

        if self.check_frames:
            names = {r["name"] for r in json.loads(inputs["images_json"].read_text())["images"]}
            assert {f.name for f in self.cameras.frames} <= names, "saved frames must be ingested images"
        (out / self.artifact).mkdir()
        self.cameras.save(out / self.artifact)
        if self.images_artifact:
            (out / self.images_artifact).mkdir()
            for name, pixels in self.images.items():
                cv2.imwrite(str(out / self.images_artifact / name), pixels)
        return {"frames": len(self.cameras.frames)}


# -- batch and executors: module-level, so spawned worker processes and Ray workers can import them ----
def add(a: int, b: int = 0, *upstream: int) -> int:
    """A task: a + b + the results of the tasks it ran after."""
    return a + b + sum(upstream)


def fail_with(message: str) -> int:
    raise ValueError(message)


def die_until(marker: str, deaths: int) -> int:
    """Kill the worker process running it, ``deaths`` times over (counted in the file ``marker``), then return 7."""
    import signal

    path = Path(marker)
    seen = int(path.read_text()) if path.exists() else 0
    if seen < deaths:
        path.write_text(str(seen + 1))
        os.kill(os.getpid(), signal.SIGKILL)
    return 7


@dataclass(frozen=True)
class SlowParams:
    seconds: float = 1.0


class SlowCountStage(CountStage):
    """CountStage that takes ``seconds`` first, so two processes running it overlap."""

    name = "slow_count"
    Params = SlowParams
    presets = {}
    provides = {"slow_count": "count.json"}

    def run(self, inputs, out, params, ctx):
        import time

        (out / "started").write_text(str(os.getpid()))
        time.sleep(params.seconds)
        images = json.loads(inputs["images_json"].read_text())["images"]
        (out / "count.json").write_text(json.dumps({"images": len(images)}))
        return {"images": len(images), "pid": os.getpid()}


def slow_stages() -> list[Stage]:
    return [IngestStage(), SlowCountStage()]


@dataclass(frozen=True)
class VideoInfo:
    codec: str
    pix_fmt: str
    frames: int  # decoded, not the container's claim
    width: int
    height: int
    index_first: bool  # the MP4 index (moov) before the data (mdat): a browser starts playing at once


def video_info(path: Path) -> VideoInfo:
    """A video as a browser would meet it, read by FFmpeg's decoders (PyAV)."""
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = sum(1 for _ in container.decode(stream))
        info = (stream.codec_context.name, stream.codec_context.pix_fmt, frames, stream.width, stream.height)
    data = Path(path).read_bytes()
    return VideoInfo(*info, index_first=0 <= data.find(b"moov") < data.find(b"mdat"))


def read_mp4(path: Path) -> list[np.ndarray]:
    """Every frame of a video, RGB (H, W, 3) uint8."""
    import cv2

    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
    capture.release()
    return frames


def count_progress(calls: list) -> object:
    """A progress factory that records (total, description) and every advance."""
    import contextlib

    @contextlib.contextmanager
    def progress(total: int, description: str):
        calls.append((total, description))
        yield lambda n=1, info=None: calls.append(n)

    return progress
