"""A cached result is reused only while its files are what its manifest recorded (cases 5-7 and 15 of
issue 19, and `status --verify`). Each rerun computes exactly the damaged stage and what depends on it."""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import pytest

from tests.cli.test_bad_input import error_lines
from tests.helpers import run_cli, temple_subset

STAGES = ("ingest", "sfm", "undistort")


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    """Every other photo of the bundled temple, with its calibration: SfM triangulates its points in ~2 s."""
    return temple_subset(tmp_path_factory.mktemp("capture"), "temple", [1, 3, 5, 7, 9, 11, 13, 15])


@pytest.fixture(scope="module")
def finished(capture, tmp_path_factory) -> Path:
    """The capture run to undistort once; each test damages its own copy of it."""
    run_dir = tmp_path_factory.mktemp("cache") / "run"
    result = run_cli("run", capture, "--out", run_dir, "--until", "undistort")
    assert result.returncode == 0, result.stderr
    return run_dir


@pytest.fixture
def run_dir(finished, tmp_path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(finished, copy)  # copy2 keeps each file's modification time, as the manifests recorded it
    assert states(copy) == dict.fromkeys(STAGES, "fresh")
    return copy


def states(run_dir: Path) -> dict[str, str]:
    result = run_cli("status", run_dir)
    assert result.returncode == 0, result.stderr
    return {name: row[1] for name, row in table(result.stdout).items() if name in STAGES}


def table(stdout: str) -> dict[str, tuple[str, ...]]:
    """The rows of a rich table printed by `run` or `status`: first cell -> all cells."""
    rows = {}
    for line in stdout.splitlines():
        cells = [c.strip() for c in line.strip("│┃ ").split("│")]
        if len(cells) >= 3 and re.fullmatch(r"[a-z_]+", cells[0]):
            rows[cells[0]] = tuple(cells)
    return rows


def result_dir(run_dir: Path, stage: str) -> Path:
    key = json.loads((run_dir / "stages" / stage / "latest.json").read_text())["key"]
    return run_dir / "stages" / stage / key


def rerun(run_dir: Path) -> tuple[dict[str, str], str]:
    """Run again to undistort: each stage's action (ran / cached), and the log on stderr."""
    result = run_cli("run", "--out", run_dir, json.loads((run_dir / "run.json").read_text())["source"], "--until", "undistort")
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr and not error_lines(result.stderr)
    return {name: row[1] for name, row in table(result.stdout).items() if name in STAGES}, result.stderr


def assert_moved_aside(run_dir: Path, stage: str, file: str, stderr: str) -> Path:
    (aside,) = (run_dir / "broken").glob(f"{stage}-*")
    assert f"{stage}: its cached result is damaged ({file}" in stderr and f"moved it aside to {aside}" in stderr
    assert file in (aside / "REASON.txt").read_text()
    return aside


def test_5_a_corrupt_manifest_is_recomputed_not_a_crash(run_dir):
    manifest = result_dir(run_dir, "undistort") / "manifest.json"
    manifest.write_text('{"broken": ')
    status = table(run_cli("status", run_dir).stdout)
    assert status["undistort"][1] == "broken" and "manifest.json is not readable JSON" in status["undistort"][2]
    actions, stderr = rerun(run_dir)
    assert actions == {"ingest": "cached", "sfm": "cached", "undistort": "ran"}
    aside = assert_moved_aside(run_dir, "undistort", "manifest.json", stderr)
    assert (aside / "manifest.json").read_text() == '{"broken": '  # nothing lost
    assert json.loads(manifest.read_text())["key"] == manifest.parent.name
    assert rerun(run_dir)[0] == dict.fromkeys(STAGES, "cached")  # and stays fixed


def test_6_a_deleted_output_is_reported_and_recomputed_and_what_depends_on_it_kept_when_it_comes_out_the_same(run_dir):
    cameras = result_dir(run_dir, "sfm") / "model" / "cameras.json"
    cameras.unlink()
    result = run_cli("status", run_dir)
    status = table(result.stdout)
    assert status["ingest"][1] == "fresh"
    assert status["sfm"][1] == "broken" and "model/cameras.json is missing" in status["sfm"][2]
    assert status["undistort"][1] == "stale" and "upstream sfm is broken" in status["undistort"][2]
    actions, stderr = rerun(run_dir)
    # SfM on the same photos writes the same bytes: undistort, built on them, stands (early cutoff)
    assert actions == {"ingest": "cached", "sfm": "ran", "undistort": "cached"}
    assert_moved_aside(run_dir, "sfm", "model/cameras.json is missing", stderr)
    assert "undistort: sfm computed again to the same outputs; its result stands" in stderr
    assert cameras.is_file()
    status = table(run_cli("status", run_dir).stdout)
    assert status["undistort"][1] == "fresh" and "upstream sfm was computed again to the same outputs" in status["undistort"][2]


def test_7_an_overwritten_output_is_caught_by_its_time_and_hash(run_dir):
    photo = result_dir(run_dir, "ingest") / "images" / "templeSR0005.png"
    other = (result_dir(run_dir, "ingest") / "images" / "templeSR0007.png").read_bytes()
    original, size = photo.read_bytes(), photo.stat().st_size
    photo.write_bytes(other[:size].ljust(size, b"\0"))  # same size, new content, new time
    status = table(run_cli("status", run_dir).stdout)
    assert status["ingest"][1] == "broken" and "images/templeSR0005.png changed content" in status["ingest"][2]
    assert status["sfm"][1] == "stale" and status["undistort"][1] == "stale"
    actions, stderr = rerun(run_dir)
    # ingest made the photo again, byte for byte: what was built on it stands (early cutoff)
    assert actions == {"ingest": "ran", "sfm": "cached", "undistort": "cached"}
    assert_moved_aside(run_dir, "ingest", "images/templeSR0005.png changed content", stderr)
    assert photo.read_bytes() == original


def test_a_touched_output_with_its_content_intact_is_still_fresh(run_dir):
    photo = result_dir(run_dir, "ingest") / "images" / "templeSR0005.png"
    os.utime(photo, ns=(photo.stat().st_atime_ns, photo.stat().st_mtime_ns + 10**9))  # a copy without -p, a touch
    assert states(run_dir) == dict.fromkeys(STAGES, "fresh")


def test_15_a_stage_built_on_a_broken_upstream_is_never_fresh(run_dir):
    (result_dir(run_dir, "ingest") / "manifest.json").write_text("not json")
    status = table(run_cli("status", run_dir).stdout)
    assert status["ingest"][1] == "broken"
    assert status["sfm"][1] == "stale" and "upstream ingest is broken" in status["sfm"][2]
    assert status["undistort"][1] == "stale" and "upstream ingest is broken" in status["undistort"][2]
    actions, stderr = rerun(run_dir)
    assert actions == {"ingest": "ran", "sfm": "cached", "undistort": "cached"}  # ingest came out the same
    assert_moved_aside(run_dir, "ingest", "manifest.json", stderr)
    assert states(run_dir) == dict.fromkeys(STAGES, "fresh")


def test_verify_finds_what_the_cheap_check_cannot_and_the_next_run_recomputes_it(run_dir):
    """A flipped byte with the size and time kept (bit rot, a tool that restores times): only sha256 sees it."""
    cameras = result_dir(run_dir, "sfm") / "model" / "cameras.json"
    stat = cameras.stat()
    data = bytearray(cameras.read_bytes())
    data[20] ^= 0x01
    cameras.write_bytes(bytes(data))
    os.utime(cameras, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert table(run_cli("status", run_dir).stdout)["sfm"][1] == "fresh"

    result = run_cli("status", run_dir, "--verify")
    assert result.returncode == 0, result.stderr
    (aside,) = (run_dir / "broken").glob("sfm-*")
    assert "1 damaged result" in result.stdout
    assert f"sfm: model/cameras.json changed content (its sha256 is not the manifest's); moved aside to {aside}" \
        in result.stdout.replace("\n", "")
    status = table(result.stdout)
    assert status["ingest"][1] == "fresh" and status["sfm"][1] == "missing" and status["undistort"][1] == "stale"
    actions, _ = rerun(run_dir)
    assert actions == {"ingest": "cached", "sfm": "ran", "undistort": "cached"}  # sfm came out as before the flip
    assert "0 damaged results" in run_cli("status", run_dir, "--verify").stdout


def test_a_manifest_of_another_shape_is_damage_the_next_run_recomputes(run_dir):
    """Valid JSON of the wrong shape (an output without its size), not only unreadable JSON."""
    manifest = result_dir(run_dir, "undistort") / "manifest.json"
    doc = json.loads(manifest.read_text())
    for meta in doc["outputs"].values():
        del meta["size"]
    manifest.write_text(json.dumps(doc))
    status = table(run_cli("status", run_dir).stdout)
    assert status["undistort"][1] == "broken" and "manifest.json has no key or outputs" in status["undistort"][2]
    actions, stderr = rerun(run_dir)
    assert actions == {"ingest": "cached", "sfm": "cached", "undistort": "ran"}
    assert_moved_aside(run_dir, "undistort", "manifest.json", stderr)
    assert states(run_dir) == dict.fromkeys(STAGES, "fresh")


@pytest.mark.parametrize("path", ["stages/sfm/latest.json", ".cache/fingerprints.json"])
def test_a_pointer_or_cache_of_another_shape_costs_nothing_but_a_lookup(run_dir, path):
    """latest.json and the fingerprint cache hold no results: a list where an object belongs is dropped."""
    (run_dir / path).write_text("[]")
    assert states(run_dir) == dict.fromkeys(STAGES, "fresh")
    assert set(rerun(run_dir)[0].values()) <= {"cached", "restored"}  # nothing computed again
    assert isinstance(json.loads((run_dir / path).read_text()), dict)  # and the run rewrote it


def test_a_run_json_of_another_shape_is_one_line_and_the_next_run_rewrites_it(run_dir):
    source = json.loads((run_dir / "run.json").read_text())["source"]
    (run_dir / "run.json").write_text("{}")
    result = run_cli("status", run_dir)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert error_lines(result.stderr) == [f"error: {run_dir / 'run.json'}: is damaged; rerun `nerfpipe run "
                                          "PHOTOS_DIR --out` on this folder"]
    result = run_cli("run", source, "--out", run_dir, "--until", "undistort")
    assert result.returncode == 0 and {row[1] for row in table(result.stdout).values()} == {"cached"}
    assert states(run_dir) == dict.fromkeys(STAGES, "fresh")


def test_verify_hashes_the_photos_too(run_dir, tmp_path):
    """A photo replaced in place with its size and time kept passes the cheap check; --verify hashes it."""
    capture = tmp_path / "capture"
    shutil.copytree(json.loads((run_dir / "run.json").read_text())["source"], capture)
    config = json.loads((run_dir / "run.json").read_text())
    (run_dir / "run.json").write_text(json.dumps({**config, "source": str(capture)}))
    assert states(run_dir) == dict.fromkeys(STAGES, "fresh")
    photo, other = capture / "templeSR0005.png", (capture / "templeSR0007.png").read_bytes()
    stat, size = photo.stat(), photo.stat().st_size
    photo.write_bytes(other[:size].ljust(size, b"\0"))
    os.utime(photo, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert states(run_dir) == dict.fromkeys(STAGES, "fresh")  # size and time say nothing
    result = run_cli("status", run_dir, "--verify")
    assert result.returncode == 0, result.stderr
    status = table(result.stdout)
    assert status["ingest"][1] == "stale" and status["ingest"][2] == "photos changed: 1 modified (templeSR0005.png)"
    assert status["sfm"][1] == "stale" and status["undistort"][1] == "stale"
    assert states(run_dir)["ingest"] == "stale"  # the new hash is remembered
