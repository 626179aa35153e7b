"""The CLI end to end on the bundled capture: run, status, stages, clean, python -m, the console script."""

from __future__ import annotations

import importlib.metadata
import os
import shutil
import subprocess
import sys

import pytest

from tests.helpers import REPO, TEMPLE, run_cli


def test_run_status_and_rerun(capture, tmp_path):
    run_dir = tmp_path / "run"
    first = run_cli("run", capture, "--out", run_dir, "--set", "ingest.max_size=320", "--until", "ingest")
    assert first.returncode == 0, first.stderr
    assert "ingest: running for the first time" in first.stderr and "ran" in first.stdout

    second = run_cli("run", capture, "--out", run_dir, "--set", "ingest.max_size=320", "--until", "ingest")
    assert second.returncode == 0 and "ingest: up to date, reusing its result" in second.stderr and "cached" in second.stdout

    status = run_cli("status", run_dir)
    assert status.returncode == 0 and "fresh" in status.stdout
    what_if = run_cli("status", run_dir, "--set", "ingest.max_size=800")
    assert "stale" in what_if.stdout and "params changed: ingest.max_size 320 -> 800" in what_if.stdout

    shutil.copy(TEMPLE / "templeSR0007.png", capture)
    shutil.copy(TEMPLE / "templeSR0008.png", capture)
    shutil.copy(TEMPLE / "templeSR0011.png", capture / "templeSR0001.png")
    status = run_cli("status", run_dir)
    assert "photos changed: 2 added (templeSR0007.png, templeSR0008.png), 1 modified (templeSR0001.png)" \
        in status.stdout.replace("\n", "")

    rerun = run_cli("run", capture, "--out", run_dir, "--set", "ingest.max_size=320", "--until", "ingest")
    assert rerun.returncode == 0
    assert ("ingest: running again: photos changed: 2 added (templeSR0007.png, templeSR0008.png), 1 modified "
            "(templeSR0001.png)") in rerun.stderr


def test_status_of_a_folder_that_is_no_run(tmp_path):
    result = run_cli("status", tmp_path)
    assert result.returncode != 0 and "is not a nerfpipe run directory" in result.stderr
    assert "Traceback" not in result.stderr


def test_stages_lists_params_defaults_and_presets():
    result = run_cli("stages")
    assert result.returncode == 0
    out = result.stdout
    assert "ingest" in out and "ingest.max_size" in out and "1600" in out
    assert "preset draft: max_size=400" in out and "auto|8|16" in out
    # train as it is: a grid field by default, the paper's MLPs only when asked
    assert "Train the radiance field the scene calls for (by default a grid field" in " ".join(out.split())


def test_clean_prunes_old_keys(capture, tmp_path):
    run_dir = tmp_path / "run"
    assert run_cli("run", capture, "--out", run_dir, "--set", "ingest.max_size=100", "--until", "ingest").returncode == 0
    assert run_cli("run", capture, "--out", run_dir, "--set", "ingest.max_size=120", "--until", "ingest").returncode == 0
    assert len(list((run_dir / "stages" / "ingest").glob("*/manifest.json"))) == 2
    result = run_cli("clean", run_dir)
    assert result.returncode == 0 and "removed 1 folders" in result.stdout
    assert len(list((run_dir / "stages" / "ingest").glob("*/manifest.json"))) == 1
    assert "fresh" in run_cli("status", run_dir).stdout


def test_default_out_is_runs_slash_folder_name(capture, tmp_path):
    result = run_cli("run", capture, "--until", "ingest", "--set", "ingest.max_size=64", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "runs" / "capture" / "run.json").is_file()


def test_console_script():
    # `nerfpipe` is installed as a console script pointing at the CLI
    scripts = {ep.name: ep.value for ep in importlib.metadata.entry_points(group="console_scripts")}
    assert scripts["nerfpipe"] == "nerfpipe.cli.main:main"
    exe = shutil.which("nerfpipe")
    assert exe is not None
    assert subprocess.run([exe, "--help"], capture_output=True, text=True).returncode == 0


def test_ci_script_runs_the_readme_test_command():
    readme = (REPO / "README.md").read_text()
    ci = (REPO / ".ci" / "run").read_text()
    commands = [line.strip() for line in readme.splitlines() if line.strip().startswith("apt-get update")]
    assert len(commands) == 2, "the README gives exactly two set-up commands"
    test_command = next(c for c in commands if "pytest" in c)
    assert test_command in ci


def test_version_completion_and_defaults_in_help():
    version = run_cli("--version")
    assert version.returncode == 0 and version.stdout.strip() == f"nerfpipe {importlib.metadata.version('nerfpipe')}"
    # typer takes the shell as a value only with detection off; detection walks the process tree, which has no
    # shell under a detached job
    env = {**os.environ, "_TYPER_COMPLETE_TEST_DISABLE_SHELL_DETECTION": "1"}
    completion = subprocess.run([sys.executable, "-m", "nerfpipe", "--show-completion", "bash"], capture_output=True,
                                text=True, env=env, timeout=60)
    assert completion.returncode == 0 and "complete" in completion.stdout and "nerfpipe" in completion.stdout
    help_text = " ".join(run_cli("run", "--help").stdout.split())
    assert "[default: runs/<photos folder name>]" in help_text  # not swallowed as markup
    assert "[default: 127.0.0.1]" in help_text and "[default: 8080]" in help_text


def test_stages_filters_by_name_and_speaks_json():
    import json

    one = run_cli("stages", "train")
    assert one.returncode == 0 and "train.field.max_resolution" in one.stdout and "ingest.max_size" not in one.stdout
    doc = json.loads(run_cli("stages", "train", "sfm", "--json").stdout)
    assert list(doc) == ["sfm", "train"]  # in the graph's order
    field = next(p for p in doc["train"]["parameters"] if p["name"] == "field.max_resolution")
    assert field == {"name": "field.max_resolution", "type": "int", "default": 128,
                     "help": "(grid, hash, planes) cells a side of the finest level", "bounds": [1, 8192],
                     "kinds": ["grid", "hash", "planes"]}
    chunk = next(p for p in doc["train"]["parameters"] if p["name"] == "chunk")
    assert chunk["keyed"] is False and chunk["help"].endswith("changing it reruns nothing")
    assert doc["train"]["presets"]["draft"]["steps"] == 500 and doc["train"]["upstream"]
    bad = run_cli("stages", "trian")
    assert bad.returncode != 0 and bad.stderr.strip().startswith("error: unknown stage 'trian'; stages are: ingest")


def test_a_config_file_sets_parameters_set_wins_and_the_run_writes_its_own(capture, tmp_path):
    import json

    import yaml

    settings = tmp_path / "run.yaml"
    settings.write_text("ingest:\n  max_size: 320\n  skip_bad: false\ntrain:\n  field:\n    levels: 2\n  optim.lr: 0.01\n")
    run_dir = tmp_path / "run"
    first = run_cli("run", capture, "--out", run_dir, "--config", settings, "--set", "ingest.max_size=300",
                    "--until", "ingest")
    assert first.returncode == 0, first.stderr
    written = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert written["ingest"]["max_size"] == 300  # --set won
    assert written["train"]["field.levels"] == 2 and written["train"]["optim.lr"] == 0.01
    assert written["render"]["frames"] == 45 and len(written) == 11  # the budget, every parameter of every stage
    # the budget as asked (auto), and not the train.seconds it sets, so the file repeats the run as it was asked
    assert written["budget"] == "auto" and "seconds" not in written["train"] and "steps" not in written["train"]
    again = run_cli("run", capture, "--out", run_dir, "--config", run_dir / "config.yaml", "--until", "ingest")
    assert again.returncode == 0 and "ingest: up to date, reusing its result" in again.stderr
    settings.write_text("budget: off\ntrain:\n  seconds: 30\n")
    run_cli("run", capture, "--out", run_dir, "--config", settings, "--until", "ingest")
    written = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert written["budget"] == "off" and written["train"]["seconds"] == 30
    assert json.loads((run_dir / "run.json").read_text())["budget"] is None
    settings.write_text("budget: soon\n")
    late = run_cli("run", capture, "--out", run_dir, "--config", settings, "--until", "ingest")
    assert late.returncode != 0 and "Traceback" not in late.stderr
    assert late.stderr.strip() == "error: --budget 'soon': expected a duration such as 10m, 90s or 600, or auto or off"
    settings.write_text("ingest: [1, 2]\n")
    bad = run_cli("run", capture, "--out", run_dir, "--config", settings)
    assert bad.returncode != 0 and "Traceback" not in bad.stderr
    assert bad.stderr.strip() == f"error: --config {settings}: ingest must map parameter names to values, got [1, 2]"
    settings.write_text("ingest: {max_size: 320\n")
    broken = run_cli("run", capture, "--out", run_dir, "--config", settings)
    assert broken.returncode != 0 and "not a readable YAML file" in broken.stderr and "Traceback" not in broken.stderr


@pytest.mark.slow
def test_a_short_run_of_the_demo_finishes_with_a_video_and_a_mesh(tmp_path):
    """The quick run a new user tries first: a few hundred steps, a fixed amount of work (not a time, which a
    busy machine would turn into fewer steps), that ends with exit 0, a render.mp4 and a mesh."""
    # 12 frames rather than 45: the video at its floor size, a quarter of the suite's time for it
    result = run_cli("run", TEMPLE, "--out", tmp_path / "run", "--set", "train.steps=400", "--set",
                     "ingest.max_size=320", "--set", "render.frames=12", timeout=900)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr and "error:" not in result.stderr
    assert "warnings" not in " ".join(result.stdout.split())  # no stage failed or was skipped
    assert len(list((tmp_path / "run" / "stages" / "render").glob("*/render.mp4"))) == 1
    assert len(list((tmp_path / "run" / "stages" / "export_mesh").glob("*/mesh.ply"))) == 1
