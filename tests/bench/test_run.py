"""``nerfpipe bench`` end to end on a small cut of lego: the figures, the files, resuming, and --set."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.helpers import run_cli, shared


def small_lego(root: Path, train: int = 6, val: int = 4) -> Path:
    """The first ``train`` train and ``val`` val views of lego, with their transforms files cut to match."""
    lego = shared("nerf_synthetic_lego_400")
    folder = root / "lego"
    for split, count in (("train", train), ("val", val)):
        doc = json.loads((lego / f"transforms_{split}.json").read_text())
        doc["frames"] = doc["frames"][:count]
        (folder / split).mkdir(parents=True)
        for frame in doc["frames"]:
            name = Path(frame["file_path"]).name + ".png"
            shutil.copy(lego / split / name, folder / split / name)
        (folder / f"transforms_{split}.json").write_text(json.dumps(doc))
    return folder


@pytest.mark.slow
def test_bench_writes_figures_resumes_and_lets_set_win(tmp_path: Path) -> None:
    capture, run_dir = small_lego(tmp_path), tmp_path / "run"
    args = ["bench", capture, "--out", run_dir, "--size", "24", "--config", "draft", "--config", "no PE",
            "--budget", "60", "--checkpoints", "0.5", "--eval-views", "2", "--set", "train.steps=12",
            "--set", "train.eval_stride=1"]
    first = run_cli(*args, timeout=900)
    assert first.returncode == 0, first.stderr[-3000:]

    folder = run_dir / "bench"
    doc = json.loads((folder / "bench.json").read_text())
    assert [r["name"] for r in doc["results"]] == ["draft", "no PE"]
    draft, no_pe = doc["results"]
    for result in doc["results"]:
        # --set wins over the configuration's own schedule (no PE's is 1500 steps), so both finish at 12
        assert result["steps"] == result["steps_planned"] == 12 and result["finished"]
        assert result["heldout"] == 2 and result["train_images"] == 6
        assert result["samples_per_s"] > 0 and result["render_seconds_per_image"] > 0
        assert result["peak_memory_bytes"] > 0
        psnrs = [p["psnr"] for p in result["points"]]
        assert all(5.0 < p < 60.0 for p in psnrs)
        assert result["points"][-1]["step"] == 12 and result["points"][-1]["seconds"] == result["train_seconds"]
    assert no_pe["spec"]["overrides"]["train"]["field.positional_encoding"] is False
    assert draft["spec"]["overrides"]["train"]["field.levels"] == 1
    table = (folder / "bench.md").read_text()
    assert "| draft |" in table and "| no PE |" in table
    assert (folder / "psnr_time.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    # a rerun with the same settings keeps both results; a changed setting trains again
    again = run_cli(*args, timeout=900)
    assert again.returncode == 0 and again.stderr.count("kept from the last benchmark") == 2
    assert json.loads((folder / "bench.json").read_text())["results"] == doc["results"]
    changed = run_cli(*[a if a != "train.steps=12" else "train.steps=8" for a in args], timeout=900)
    assert changed.returncode == 0 and "kept from the last benchmark" not in changed.stderr
    assert [r["steps"] for r in json.loads((folder / "bench.json").read_text())["results"]] == [8, 8]


def test_bench_refuses_unknown_configurations_and_bad_checkpoints(tmp_path: Path) -> None:
    unknown = run_cli("bench", tmp_path, "--out", tmp_path / "run", "--config", "turbo")
    assert unknown.returncode != 0 and "unknown configuration 'turbo'" in unknown.stderr
    bad = run_cli("bench", tmp_path, "--out", tmp_path / "run", "--checkpoints", "1,soon")
    assert bad.returncode != 0 and "expected seconds separated by commas" in bad.stderr
    assert "Traceback" not in unknown.stderr + bad.stderr
