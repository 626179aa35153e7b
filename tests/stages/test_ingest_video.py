"""`nerfpipe run clip.mp4`: a phone video made here from the shared beer capture's 71 frames becomes a
capture whose frames SfM registers; a cut-off video fails with one line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import pytest

from nerfpipe.export.video import write_mp4
from tests.cli.test_bad_input import assert_one_clear_error
from tests.helpers import run_cli, shared

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    """The beer frames as a 10 fps portrait H.264 video at 360x640."""
    frames = sorted(shared("colmap_beer_yhuoyuh", "images").glob("*.jpg"))
    path = tmp_path_factory.mktemp("video") / "beer.mp4"
    write_mp4((cv2.resize(cv2.imread(str(f)), (360, 640), interpolation=cv2.INTER_AREA)[..., ::-1] for f in frames),
              path, fps=10)
    return path


def test_a_video_becomes_a_capture_and_its_frames_register(clip, tmp_path):
    result = run_cli("run", clip, "--out", tmp_path / "run", "--until", "scene", "--set", "ingest.video_frames=24",
                     timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "ingest: 24 of the 71 frames of beer.mp4 (7 s at 10 fps), each the sharpest of its 0.30 s -> 360x640" \
        in result.stderr
    run = tmp_path / "run" / "stages"
    index = json.loads(next((run / "ingest").glob("*/images.json")).read_text())
    assert index["layout"] == "video" and len(index["images"]) == 24
    frames = [r["video_frame"] for r in index["images"]]
    assert frames == sorted(frames) and frames[0] <= 2 and frames[-1] >= 68  # spread over the whole video
    assert [r["time_s"] for r in index["images"]] == pytest.approx([f / 10 for f in frames])
    sfm = json.loads(next((run / "sfm").glob("*/manifest.json")).read_text())["summary"]
    assert sfm["registered"] >= 22 and sfm["total"] == 24, sfm
    assert next((run / "scene").glob("*/scene.json")).is_file()


def test_a_folder_holding_one_video_is_that_video_and_a_cut_video_is_one_line(clip, tmp_path):
    folder = tmp_path / "capture"
    folder.mkdir()
    data = clip.read_bytes()
    (folder / "beer.mp4").write_bytes(data[: len(data) // 3])
    result = run_cli("run", folder, "--out", tmp_path / "run", "--until", "ingest")
    assert_one_clear_error(result, "beer.mp4: is truncated or damaged:", "frames its header states decode",
                           "copy it again from the phone or camera")
    shutil.copy(clip, folder / "beer.mp4")
    shutil.copy(clip, folder / "again.mp4")
    assert_one_clear_error(run_cli("run", folder, "--out", tmp_path / "run", "--until", "ingest"),
                           "holds 2 videos (again.mp4, beer.mp4)", "pass one of them")
    (folder / "again.mp4").unlink()
    result = run_cli("run", folder, "--out", tmp_path / "run", "--until", "ingest", "--set", "ingest.video_frames=5")
    assert result.returncode == 0 and "ingest: 5 of the 71 frames of beer.mp4" in result.stderr, result.stderr


@pytest.mark.parametrize("frames, size, problem", [
    (1, (64, 48), "holds only 1 frame; a reconstruction needs at least 3 views"),
    (30, (16, 16), "has frames of only 16x16 pixels, below ingest.min_size=32"),
])
def test_a_video_too_short_or_too_small_is_refused_at_ingest_naming_it(tmp_path, frames, size, problem):
    """Not later, in SfM, as 'only 1 photo' or 'no features', without the video's name."""
    still = cv2.resize(cv2.imread(str(sorted(shared("colmap_beer_yhuoyuh", "images").glob("*.jpg"))[0])), size)
    write_mp4([still[..., ::-1]] * frames, tmp_path / "short.mp4", fps=10)
    result = run_cli("run", tmp_path / "short.mp4", "--out", tmp_path / "run", "--until", "sfm")
    assert_one_clear_error(result, f"short.mp4: {problem}")
    assert "sfm: running" not in result.stderr
