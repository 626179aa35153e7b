"""A run never deletes or overwrites a file nerfpipe did not make: every data-loss case an outside pass found,
run against folders of sentinel files that must come out byte-identical."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest

from nerfpipe.export.bundle import EXPORT_LIST, copy_exports
from nerfpipe.pipeline import ArtifactStore, InputError
from tests.cli.test_bad_input import assert_one_clear_error
from tests.helpers import TEMPLE, run_cli

PHOTOS = ("templeSR0001.png", "templeSR0002.png", "templeSR0003.png")


def snapshot(root: Path) -> dict[str, str]:
    """Every file under ``root`` with its sha256: what must not change."""
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def photos_in(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name in PHOTOS:
        shutil.copy(TEMPLE / name, folder)
    return folder


@pytest.fixture
def finished_run(tmp_path) -> Path:
    """A run directory nerfpipe made (ingest only: enough for its folders and marker)."""
    run = tmp_path / "RUN"
    result = run_cli("run", photos_in(tmp_path / "capture"), "--out", run, "--until", "ingest")
    assert result.returncode == 0, result.stderr
    assert (run / ".nerfpipe-run").is_file()
    return run


def test_out_a_folder_of_the_users_is_refused_and_left_as_it_was(tmp_path) -> None:
    """Case 1: `run photos/ --out docs` deleted docs/report/q3.docx and docs/exports/taxes.csv."""
    docs = tmp_path / "docs"
    (docs / "report").mkdir(parents=True)
    (docs / "exports").mkdir()
    (docs / "report" / "q3.docx").write_bytes(b"quarterly figures")
    (docs / "exports" / "taxes.csv").write_text("year,amount\n2026,1\n")
    before = snapshot(docs)
    result = run_cli("run", photos_in(tmp_path / "photos"), "--out", docs, "--until", "ingest")
    assert_one_clear_error(result, str(docs), "is a folder nerfpipe did not make", "exports, report")
    assert snapshot(docs) == before and not (docs / ".nerfpipe-run").exists()


@pytest.mark.parametrize("managed", ["exports", "report", "logs", "stages"])
def test_a_capture_inside_a_folder_the_run_replaces_is_refused(tmp_path, managed) -> None:
    """Cases 2-3: `run proj/exports --out proj` deleted all 8 photos; photos in proj/logs/ or proj/stages/ got
    run files written among them. Here proj is a run directory nerfpipe made, so only the capture check can
    refuse it."""
    proj = tmp_path / "proj"
    ArtifactStore(proj).prepare()
    capture = photos_in(proj / managed)
    before = snapshot(proj)
    result = run_cli("run", capture, "--out", proj, "--until", "ingest")
    assert_one_clear_error(result, f"the capture {capture} lies inside {proj / managed}", "copy the photos elsewhere")
    assert snapshot(proj) == before


def test_the_documented_run_of_a_runs_exports_into_the_run_is_refused(finished_run) -> None:
    """Case 4: `nerfpipe run RUN/exports --out RUN` deleted the capture it was reading."""
    photos_in(finished_run / "exports")
    before = snapshot(finished_run / "exports")
    result = run_cli("run", finished_run / "exports", "--out", finished_run, "--until", "ingest")
    assert_one_clear_error(result, "lies inside", "exports")
    assert snapshot(finished_run / "exports") == before


def test_export_to_a_capture_a_file_or_inside_the_run_is_refused(finished_run, tmp_path) -> None:
    capture = photos_in(tmp_path / "photos")
    a_file = tmp_path / "notes.txt"
    a_file.write_text("mine")
    before = snapshot(tmp_path / "photos"), a_file.read_bytes()
    for target, needle in ((capture, "holds photos or pose files"), (a_file, "is a file, not a folder"),
                           (finished_run / "exports", "lies inside the run directory"),
                           (finished_run / "exports" / "copy", "lies inside the run directory"),
                           (finished_run, "lies inside the run directory")):
        assert_one_clear_error(run_cli("export", finished_run, "--to", target), str(target), needle)
    assert (snapshot(tmp_path / "photos"), a_file.read_bytes()) == before
    assert not (finished_run / "exports" / "copy").exists()


def test_export_never_overwrites_a_file_it_did_not_write(tmp_path) -> None:
    run = tmp_path / "RUN"
    ArtifactStore(run).prepare()
    exports = run / "exports"
    exports.mkdir()
    (exports / "mesh.glb").write_bytes(b"glTF new")
    (exports / "points.ply").write_bytes(b"ply")
    out = tmp_path / "out"
    out.mkdir()
    (out / "mesh.glb").write_bytes(b"the user's own model")
    with pytest.raises(InputError, match="mesh.glb: exists and was not written by an earlier `nerfpipe export`"):
        copy_exports(exports, out, run)
    assert snapshot(out) == {"mesh.glb": hashlib.sha256(b"the user's own model").hexdigest()}
    # into a new folder, then again over its own earlier copy: allowed
    assert copy_exports(exports, tmp_path / "fresh", run) == 11
    (exports / "mesh.glb").write_bytes(b"glTF newer")
    copy_exports(exports, tmp_path / "fresh", run)
    assert (tmp_path / "fresh" / "mesh.glb").read_bytes() == b"glTF newer"
    assert (tmp_path / "fresh" / EXPORT_LIST).is_file()
    # but not over an earlier copy the user has edited since
    (tmp_path / "fresh" / "points.ply").write_bytes(b"ply, edited by hand")
    with pytest.raises(InputError, match="points.ply: exists and was not written"):
        copy_exports(exports, tmp_path / "fresh", run)
    assert (tmp_path / "fresh" / "points.ply").read_bytes() == b"ply, edited by hand"


def test_export_of_a_run_without_exports_is_one_line(finished_run, tmp_path) -> None:
    result = run_cli("export", finished_run, "--to", tmp_path / "out")
    assert_one_clear_error(result, "holds no exports yet", "nerfpipe run")


def test_out_empty_is_refused_not_the_current_folder(tmp_path) -> None:
    mine = tmp_path / "cwd"
    mine.mkdir()
    (mine / "thesis.tex").write_text("\\documentclass{article}")
    result = run_cli("run", photos_in(tmp_path / "photos"), "--out", "", "--until", "ingest", cwd=mine)
    assert_one_clear_error(result, "--out is empty")
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.tex"]


def test_a_missing_capture_makes_no_run_directory(tmp_path) -> None:
    result = run_cli("run", tmp_path / "nonexistent", "--until", "ingest", cwd=tmp_path)
    assert_one_clear_error(result, "capture folder does not exist")
    assert not (tmp_path / "runs").exists()


def test_a_run_directory_from_before_the_marker_is_still_a_run(tmp_path) -> None:
    """Runs made before the marker (run.json and stages/) are adopted, not refused."""
    old = tmp_path / "old"
    (old / "stages").mkdir(parents=True)
    (old / "run.json").write_text("{}")
    ArtifactStore(old).prepare()
    assert (old / ".nerfpipe-run").is_file()


def test_export_to_a_folder_that_cannot_be_written_is_one_line_before_any_copy(tmp_path, monkeypatch) -> None:
    """As root every folder is writable; one that is not (another user's, a read-only mount) is simulated where
    the check asks."""
    import os

    import nerfpipe.export.bundle as bundle

    run = tmp_path / "RUN"
    ArtifactStore(run).prepare()
    (run / "exports").mkdir()
    (run / "exports" / "points.ply").write_bytes(b"ply")
    locked = tmp_path / "locked"
    locked.mkdir()
    monkeypatch.setattr(bundle.os, "access", lambda path, mode: Path(path) != locked and os.access(path, mode))
    with pytest.raises(InputError, match="locked: cannot be written to \\(permission denied\\)"):
        copy_exports(run / "exports", locked, run)
    assert not any(locked.iterdir())
