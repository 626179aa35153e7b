"""Batches of captures on the local executor, and two writers racing on one stage (the engine's part).

The same batches on a Ray instance, with the real stages, are in tests/pipeline/test_ray.py.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from nerfpipe.pipeline import InputError, ParamError, Pipeline
from nerfpipe.pipeline.batch import SUMMARY, Batch, BatchSettings, StageJob, find_captures, run_stage_task
from nerfpipe.pipeline.executors import LocalExecutor
from tests.helpers import TEMPLE, contents, run_cli, slow_stages, two_stages

STAGES = "tests.helpers:two_stages"


def make_captures(root: Path, sizes=(2, 3, 4)) -> list[Path]:
    """Captures of 2, 3 and 4 bundled temple photos."""
    folders = []
    for i, n in enumerate(sizes):
        folder = root / f"cap{i}"
        folder.mkdir(parents=True)
        for k in range(1, n + 1):
            shutil.copy2(TEMPLE / f"templeSR{k:04d}.png", folder)
        folders.append(folder)
    return folders


def run_batch(sources, out, workers=1, **settings):
    with LocalExecutor(workers) as ex:
        return Batch(sources, out, ex, BatchSettings(stages=STAGES, **settings)).run()


def test_a_batch_runs_each_capture_into_its_own_run_directory_and_a_rerun_does_nothing(tmp_path):
    sources = make_captures(tmp_path / "captures")
    states = run_batch(sources, tmp_path / "runs")
    assert [(c.name, c.state, c.count("ran")) for c in states] == [("cap0", "done", 2), ("cap1", "done", 2), ("cap2", "done", 2)]
    for source, n in zip(sources, (2, 3, 4)):
        result = Pipeline.from_run_dir(two_stages(), tmp_path / "runs" / source.name).result("count")
        assert json.loads((result.path / "count.json").read_text()) == {"count": n}
    summary = json.loads((tmp_path / "runs" / SUMMARY).read_text())
    assert [c["state"] for c in summary["captures"]] == ["done"] * 3 and summary["executor"] == "local"

    logs_before = sorted(p.name for p in (tmp_path / "runs" / "cap0" / "logs").iterdir())
    again = run_batch(sources, tmp_path / "runs")
    assert all(c.state == "done" and c.count("ran") == 0 and c.count("cached") == 2 for c in again)
    assert sorted(p.name for p in (tmp_path / "runs" / "cap0" / "logs").iterdir()) == logs_before  # no task ran

    changed = run_batch(sources, tmp_path / "runs", overrides={"count": {"label": "n"}})  # reruns count only
    assert all(c.finished["ingest"]["action"] == "cached" and c.finished["count"]["action"] == "ran" for c in changed)


def test_a_broken_capture_fails_alone_with_its_reason(tmp_path):
    make_captures(tmp_path / "captures", sizes=(2, 2))
    broken = tmp_path / "captures" / "broken"
    broken.mkdir()
    (broken / "notes.txt").write_text("no photos here")
    states = {c.name: c for c in run_batch(find_captures(tmp_path / "captures"), tmp_path / "runs")}
    assert states["cap0"].state == states["cap1"].state == "done"
    # found while planning (listing the capture's photos), before any task was submitted for it
    assert states["broken"].state == "failed" and states["broken"].stage is None and not states["broken"].finished
    assert "broken: no photos found" in states["broken"].error
    assert not (tmp_path / "runs" / "broken" / "stages" / "count").exists()


def test_two_local_workers_give_the_same_outputs_as_one(tmp_path):
    sources = make_captures(tmp_path / "captures")
    one = run_batch(sources, tmp_path / "one")
    two = run_batch(sources, tmp_path / "two", workers=2, max_parallel=2)
    for a, b in zip(one, two):
        assert b.state == "done"
        for stage in ("ingest", "count"):
            out_a = contents(Pipeline.from_run_dir(two_stages(), a.run_dir).result(stage).manifest["outputs"])
            out_b = contents(Pipeline.from_run_dir(two_stages(), b.run_dir).result(stage).manifest["outputs"])
            assert out_a == out_b
    assert {two[0].finished["ingest"]["pid"], two[1].finished["ingest"]["pid"]} - {one[0].finished["ingest"]["pid"]}


def test_bad_batch_settings_fail_once_before_any_capture(tmp_path):
    sources = make_captures(tmp_path / "captures", sizes=(2,))
    with LocalExecutor() as ex:
        with pytest.raises(ParamError, match="unknown stage 'trian'"):
            Batch(sources, tmp_path / "runs", ex, BatchSettings(stages=STAGES, until="trian"))
        with pytest.raises(ParamError, match="ingest.max_size"):
            Batch(sources, tmp_path / "runs", ex, BatchSettings(stages=STAGES, overrides={"ingest": {"max_size": "big"}}))
    with pytest.raises(InputError, match="has no capture folders inside"):
        find_captures(sources[0])
    assert not (tmp_path / "runs").exists()


def test_the_stage_task_reports_errors_instead_of_raising(tmp_path):
    source = make_captures(tmp_path / "captures", sizes=(2,))[0]
    job = StageJob("cap0", "count", str(source), str(tmp_path / "run"), STAGES)
    result = run_stage_task(job)  # ingest has not run
    assert not result["ok"] and "upstream stage ingest is missing" in result["error"]
    skipped = run_stage_task(job, {"ok": False, "stage": "ingest"})
    assert skipped["skipped"] and skipped["error"] == "upstream stage ingest failed"


RACE = """
import json, sys
from pathlib import Path
from nerfpipe.pipeline import Pipeline
from tests.helpers import slow_stages
pipe = Pipeline(slow_stages(), Path(sys.argv[1]), Path(sys.argv[2]))
pipe.run_stage("ingest") if sys.argv[3] == "ingest" else None
print(json.dumps({"action": pipe.run_stage("slow_count").action}), flush=True)
"""


def test_two_workers_racing_on_one_stage_leave_one_complete_result(tmp_path):
    source = make_captures(tmp_path / "captures", sizes=(3,))[0]
    run_dir = tmp_path / "shared-run"
    Pipeline(slow_stages(), source, run_dir).run_stage("ingest")
    env_path = str(Path(__file__).resolve().parents[2])
    racers = [
        subprocess.Popen([sys.executable, "-c", RACE, str(source), str(run_dir), "-"], stdout=subprocess.PIPE, text=True,
                         env={**os.environ, "PYTHONPATH": env_path})
        for _ in range(2)
    ]
    actions = sorted(json.loads(p.communicate(timeout=120)[0])["action"] for p in racers)
    assert actions == ["cached", "ran"]  # the second waited for the first and found its result
    results = list((run_dir / "stages" / "slow_count").iterdir())
    results = [p for p in results if p.is_dir()]
    assert len(results) == 1 and json.loads((results[0] / "count.json").read_text()) == {"images": 3}
    manifest = json.loads((results[0] / "manifest.json").read_text())
    assert set(manifest["outputs"]) == {"count.json", "started"}
    assert not any((run_dir / ".work").iterdir())


def test_nerfpipe_batch_cli_prints_a_summary_and_exits_non_zero_when_a_capture_fails(tmp_path):
    make_captures(tmp_path / "captures", sizes=(2,))
    (tmp_path / "captures" / "empty").mkdir()
    result = run_cli("batch", tmp_path / "captures", "--out", tmp_path / "runs", "--until", "ingest")
    assert result.returncode == 1, result.stderr
    assert "1 of 2 captures done, 1 failed" in result.stdout
    assert "│ empty   │ failed │" in result.stdout and "plan: " in result.stdout and "Traceback" not in result.stderr
    reasons = {c["capture"]: c["error"] for c in json.loads((tmp_path / "runs" / SUMMARY).read_text())["captures"]}
    assert reasons["cap0"] is None and "empty: the capture folder is empty; put the photos" in reasons["empty"]
    assert "batch: cap0: done" in result.stderr  # progress lines when not on a terminal
    bad = run_cli("batch", tmp_path / "captures", "--out", tmp_path / "runs", "--executor", "spark")
    assert bad.returncode == 2 and "expected local or ray, got 'spark'" in bad.stderr
