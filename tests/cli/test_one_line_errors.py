"""The outside pass's tracebacks and silent choices, each now one line naming the value or file, and a
non-zero exit."""

from __future__ import annotations

import json
import shutil

import pytest

from tests.cli.test_bad_input import assert_one_clear_error
from tests.helpers import TEMPLE, run_cli


@pytest.fixture
def photos(tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    for i in (1, 2, 3):
        shutil.copy(TEMPLE / f"templeSR000{i}.png", folder)
    return folder


def ingest(photos, tmp_path, *extra, out=None):
    return run_cli("run", photos, "--out", out or tmp_path / "run", "--until", "ingest", *extra)


@pytest.mark.parametrize(("capture", "needle"), [
    ("/dev/zero", "/dev/zero: is a device or special file"),
    ("/proc/self", "cannot be read"),
])
def test_a_device_or_proc_as_the_capture(tmp_path, capture, needle) -> None:
    assert_one_clear_error(run_cli("run", capture, "--out", tmp_path / "run", "--until", "ingest"), needle)
    assert not (tmp_path / "run").exists()


def test_an_out_name_or_path_past_the_limits(photos, tmp_path) -> None:
    assert_one_clear_error(ingest(photos, tmp_path, out=tmp_path / ("a" * 300)),
                           "is 300 bytes, more than the 255 a file name may have")
    deep = tmp_path.joinpath(*["b" * 200] * 20)
    assert_one_clear_error(ingest(photos, tmp_path, out=deep), "a run needs 400 more for its stage folders")


def test_config_files_with_a_huge_integer_or_a_key_twice(photos, tmp_path) -> None:
    huge = tmp_path / "huge.yaml"
    huge.write_text(f"ingest:\n  max_size: {'9' * 5000}\n")
    assert_one_clear_error(ingest(photos, tmp_path, "--config", huge), "huge.yaml: not a readable YAML file")
    twice = tmp_path / "twice.yaml"
    twice.write_text("ingest:\n  max_size: 100\n  max_size: 200\n")
    assert_one_clear_error(ingest(photos, tmp_path, "--config", twice), "'max_size' is given twice (line 3)")


def test_conflicting_flags_are_refused_not_resolved_silently(photos, tmp_path) -> None:
    assert_one_clear_error(ingest(photos, tmp_path, "--preset", "draft", "--preset", "fast"),
                           "--preset given 2 times (draft, fast); presets do not combine")
    assert_one_clear_error(ingest(photos, tmp_path, "--skip-bad", "--set", "ingest.skip_bad=false"),
                           "--skip-bad and ingest.skip_bad=false disagree")


@pytest.mark.parametrize(("budget", "needle"), [
    ("99999999999999999999", "at most 10080 min (a week)"),
    ("1e9", "expected a duration such as 10m"),
])
def test_a_budget_out_of_range(photos, tmp_path, budget, needle) -> None:
    assert_one_clear_error(ingest(photos, tmp_path, "--budget", budget), needle)


def test_a_megapixel_limit_below_one_pixel_is_not_taken_as_no_limit(photos, tmp_path) -> None:
    assert_one_clear_error(ingest(photos, tmp_path, "--set", "ingest.max_megapixels=1e-7"),
                           "max_megapixels 1e-07 is below one pixel; use 0 for no limit")


def test_training_steps_beyond_the_budget_are_refused_before_anything_runs(photos, tmp_path) -> None:
    result = run_cli("run", photos, "--out", tmp_path / "run", "--budget", "60s", "--set", "train.steps=10000000")
    assert_one_clear_error(result, "train.steps=10000000 takes at least 166 min 40 s", "--budget off")
    assert result.returncode == 2 and not (tmp_path / "run").exists()


def test_batch_captures_named_like_its_summary_and_an_out_that_is_a_file(photos, tmp_path) -> None:
    root = tmp_path / "captures"
    root.mkdir()
    shutil.copytree(photos, root / "batch.json")
    assert_one_clear_error(run_cli("batch", root, "--out", tmp_path / "runs"), "batch.json: is named like the batch's")
    (tmp_path / "file").write_text("x")
    shutil.move(root / "batch.json", root / "a")
    assert_one_clear_error(run_cli("batch", root, "--out", tmp_path / "file"), "is a file, not a folder")


def test_status_after_a_failed_stage_says_it_failed_and_leaves_no_empty_work_folder(tmp_path) -> None:
    folder = tmp_path / "two"
    folder.mkdir()
    for i in (1, 2):
        shutil.copy(TEMPLE / f"templeSR000{i}.png", folder)
    (folder / "templeSR0002.png").write_bytes((folder / "templeSR0001.png").read_bytes())  # a duplicate
    run = tmp_path / "run"
    assert_one_clear_error(run_cli("run", folder, "--out", run, "--until", "ingest"), "is the same photo as")
    status = run_cli("status", run)
    assert "failed in the last run:" in " ".join(status.stdout.split()), status.stdout
    assert not (run / ".work").exists() or not any(p for p in (run / ".work").iterdir() if not any(p.iterdir()))


def test_a_result_folder_holding_another_keys_result_is_broken(photos, tmp_path) -> None:
    """Case 7: a result folder replaced by a copy of another key's: the manifest's key must be its folder's."""
    run = tmp_path / "run"
    assert ingest(photos, tmp_path, out=run).returncode == 0
    assert ingest(photos, tmp_path, "--set", "ingest.max_size=320", out=run).returncode == 0
    first, second = sorted(p for p in (run / "stages" / "ingest").iterdir() if p.is_dir())
    current = json.loads((run / "stages" / "ingest" / "latest.json").read_text())["key"]
    other = first if current == second.name else second
    shutil.rmtree(run / "stages" / "ingest" / current)
    shutil.copytree(other, run / "stages" / "ingest" / current)
    status = run_cli("status", run, "--verify")
    text = " ".join(status.stdout.split())
    assert "broken" in text and "belongs to another result" in text, text
    rerun = ingest(photos, tmp_path, "--set", "ingest.max_size=320", out=run)
    assert rerun.returncode == 0 and "ingest: done" in rerun.stderr  # computed again, not reused


def test_distortion_beyond_any_lens_is_undistorted_with_a_warning_naming_it(tmp_path) -> None:
    """k1 = 1e6 in a transforms.json was undistorted without a word."""
    import numpy as np

    capture = tmp_path / "cap"
    capture.mkdir()
    frames = []
    for i, angle in zip((1, 2, 3), (0.0, 0.4, 0.8)):
        shutil.copy(TEMPLE / f"templeSR000{i}.png", capture)
        c2w = np.eye(4)
        c2w[:3, 3] = [np.sin(angle) * 4, 0.0, np.cos(angle) * 4]
        frames.append({"file_path": f"templeSR000{i}.png", "transform_matrix": c2w.tolist()})
    (capture / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "k1": 1e6, "frames": frames}))
    result = run_cli("run", capture, "--out", tmp_path / "run", "--until", "undistort", "--set", "sfm.triangulate=false")
    assert "Traceback" not in result.stderr
    assert "undistort: camera 1's distortion coefficients (1e+06) are far beyond any lens's" in result.stderr, \
        result.stderr[-2000:]
