"""The CLI end to end on the bundled capture: run, status, stages, clean, python -m, the console script."""

from __future__ import annotations

import importlib.metadata
import shutil
import subprocess

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
    assert "photos changed: 2 added, 1 modified" in status.stdout

    rerun = run_cli("run", capture, "--out", run_dir, "--set", "ingest.max_size=320", "--until", "ingest")
    assert rerun.returncode == 0
    assert "ingest: running again: photos changed: 2 added, 1 modified" in rerun.stderr


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
