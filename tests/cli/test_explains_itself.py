"""A CLI that explains itself: examples in every --help, the values --until/--only/--force/--preset take
listed and completed, --set keys completed, status --json, run --quiet, short stage paths, one-line errors."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest

from nerfpipe.cli.options import complete_preset, complete_set, complete_stage, examples
from tests.helpers import run_cli

COMMANDS = ("run", "status", "view", "report", "bench", "batch", "stages", "export", "clean")
STAGES = ("ingest", "sfm", "undistort", "bounds", "scene", "train", "export_depth", "export_points", "export_mesh",
          "render")


@pytest.mark.parametrize("command", COMMANDS)
def test_every_help_has_examples_that_fit_80_columns(command):
    env = {**os.environ, "COLUMNS": "80"}
    result = subprocess.run([sys.executable, "-m", "nerfpipe", command, "--help"], capture_output=True, text=True,
                            env=env, timeout=60)
    assert result.returncode == 0
    tail = result.stdout[result.stdout.index("Examples"):]
    commands = [line.strip() for line in tail.splitlines() if line.strip().startswith("nerfpipe ")]
    assert commands and all(f"{c} ".startswith(f"nerfpipe {command} ") for c in commands)
    # each example on a line of its own, not wrapped: the next line is a comment, another example or the end
    lines = [line.strip() for line in tail.splitlines()[1:] if line.strip()]
    assert all(line.startswith(("# ", "nerfpipe ")) for line in lines), lines


def test_examples_put_the_comment_above_the_command():
    assert examples("every stage: nerfpipe run photos/", "nerfpipe clean runs/x").endswith(
        "\b\n  # every stage\n  nerfpipe run photos/\n  nerfpipe clean runs/x")


def test_choices_are_listed_in_help():
    text = " ".join(run_cli("run", "--help").stdout.split()).replace("│ ", "")
    for option in ("--until", "--only", "--force"):
        assert re.search(rf"{option} STAGE .*?One of: " + ", ".join(STAGES), text), option
    assert "One of: balanced, dense, draft" in text and "hash" in text and "planes" in text


def test_completion_offers_stages_presets_and_set_keys():
    assert complete_stage("export_") == ["export_depth", "export_points", "export_mesh"]
    assert complete_stage("") == list(STAGES)
    assert complete_preset("pl") == ["planes"]
    assert complete_set("tr") == ["train."]
    assert "train.field.max_resolution=" in complete_set("train.field.m")
    assert all(k.startswith("render.fr") for k in complete_set("render.fr")) and complete_set("render.fr")
    assert complete_set("ingest.max_size=8") == []  # a value is the user's


def test_shell_completion_end_to_end():
    env = {**os.environ, "_NERFPIPE_COMPLETE": "complete_bash", "COMP_WORDS": "nerfpipe run photos --until export_m",
           "COMP_CWORD": "4"}
    result = subprocess.run([sys.executable, "-m", "nerfpipe"], capture_output=True, text=True, env=env, timeout=60)
    assert result.stdout.split() == ["export_mesh"]


def test_status_json_quiet_run_and_short_paths(capture, tmp_path):
    run_dir = tmp_path / "run"
    quiet = run_cli("run", capture, "--out", run_dir, "--set", "ingest.max_size=64", "--until", "ingest", "--quiet")
    assert quiet.returncode == 0, quiet.stderr
    assert quiet.stdout == "" and quiet.stderr == ""

    loud = run_cli("run", capture, "--out", run_dir, "--set", "ingest.max_size=80", "--until", "ingest")
    assert loud.returncode == 0
    assert not re.search(r"[0-9a-f]{64}", loud.stdout)  # the key cut to 12 characters
    row = next(line for line in loud.stdout.splitlines() if line.lstrip("│ ").startswith("ingest"))
    assert re.search(r"stages/ingest/[0-9a-f]{12}…", row)

    result = run_cli("status", run_dir, "--json")
    assert result.returncode == 0
    doc = json.loads(result.stdout)
    assert doc["run_dir"] == str(run_dir) and [s["name"] for s in doc["stages"]] == list(STAGES)
    ingest, sfm = doc["stages"][0], doc["stages"][1]
    assert ingest["state"] == "fresh" and len(ingest["key"]) == 64 and ingest["path"].endswith(ingest["key"])
    assert any("4 photos" in line for line in ingest["summary"]), ingest["summary"]
    assert sfm["state"] == "missing" and sfm["path"] is None and sfm["reasons"]
