"""The run directory: a file, a read-only disk, a folder that cannot be made, a full disk (cases 1-4 of
issue 19). Each is one line naming the path and what to do, a non-zero exit, no traceback, nothing lost."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import shutil
import subprocess
from pathlib import Path
from typing import Iterator

import pytest

from nerfpipe.pipeline import DiskFullError, Pipeline
from nerfpipe.pipeline.errors import format_bytes
from tests.cli.test_bad_input import assert_one_clear_error
from tests.helpers import TEMPLE, run_cli, two_stages


@contextlib.contextmanager
def tmpfs(where: Path, size: str, read_only: bool = False) -> Iterator[Path]:
    """A real filesystem of ``size`` (``3m``) mounted at ``where``; skips the test where mounting is not
    allowed (not root, or a container without the capability)."""
    where.mkdir(parents=True, exist_ok=True)
    options = f"size={size}" + (",ro" if read_only else "")
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)], capture_output=True, text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({mounted.stderr.strip()})")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=True)


def photo_digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def test_1_out_names_an_existing_file(tmp_path):
    (tmp_path / "notes.txt").write_text("keep me")
    result = run_cli("run", TEMPLE, "--out", tmp_path / "notes.txt", "--until", "ingest")
    assert_one_clear_error(result, "notes.txt: is a file, not a folder", "pass --out a new folder")
    assert (tmp_path / "notes.txt").read_text() == "keep me"
    result = run_cli("run", TEMPLE, "--out", tmp_path / "notes.txt" / "run", "--until", "ingest")
    assert_one_clear_error(result, "notes.txt: is a file, not a folder", "does not run through a file")


def test_2_out_on_a_read_only_filesystem(tmp_path):
    with tmpfs(tmp_path / "ro", "1m", read_only=True) as ro:
        result = run_cli("run", TEMPLE, "--out", ro / "run", "--until", "ingest")
    assert_one_clear_error(result, f"{ro / 'run'}: cannot be made in {ro} (it is on a read-only filesystem)",
                           "pass --out a folder on a writable disk")


def test_2_an_existing_run_folder_on_a_read_only_filesystem(tmp_path):
    with tmpfs(tmp_path / "disk", "1m") as disk:
        (disk / "run").mkdir()
        subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
        result = run_cli("run", TEMPLE, "--out", disk / "run", "--until", "ingest")
    assert_one_clear_error(result, f"{disk / 'run'}: is on a read-only filesystem", "pass --out a folder on a writable disk")


def test_3_out_where_no_folder_can_be_made():
    result = run_cli("run", TEMPLE, "--out", "/proc/nerfpipe-run/run", "--until", "ingest")
    assert_one_clear_error(result, "/proc/nerfpipe-run/run: cannot be made in /proc", "pass --out a folder on a writable disk")


def test_4_disk_full_during_ingest_is_one_line_and_leaves_no_result(tmp_path):
    before = photo_digests(TEMPLE)
    with tmpfs(tmp_path / "small", "3m") as disk:
        # the 16 temple PNGs come to about 2.9 MB by the estimate: the check lets them start, the disk fills up
        result = run_cli("run", TEMPLE, "--out", disk / "run", "--until", "ingest")
        assert_one_clear_error(result, f"{disk / 'run'}: the disk is full (it filled up while ingest was writing)",
                               "free some space, or pass --out a folder on a disk with more room")
        assert not (disk / "run" / "stages" / "ingest").exists()
        assert list((disk / "run" / ".work").iterdir()) == []  # the half-written stage is gone
    assert "--- Logging error ---" not in result.stderr
    assert photo_digests(TEMPLE) == before


def test_4_free_space_is_checked_before_ingest_writes(tmp_path):
    with tmpfs(tmp_path / "tiny", "1m") as disk:
        result = run_cli("run", TEMPLE, "--out", disk / "run", "--until", "ingest")
        line = assert_one_clear_error(result, f"{disk / 'run'}: not enough free space for ingest (needs about",
                                      "MB free); free some space")
        assert not any((disk / "run" / ".work").glob("*"))  # refused before a byte was written
    assert "1.0 MB free" in line


def test_enospc_anywhere_in_a_stage_is_the_disk_full_error(tmp_path, monkeypatch):
    """Wherever a stage's write fails with ENOSPC (here the first PNG), in process, without a real full disk."""
    import nerfpipe.stages.ingest as ingest_module

    def no_space(path, pixels):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(ingest_module, "write_png", no_space)
    capture = tmp_path / "photos"
    capture.mkdir()
    shutil.copy(TEMPLE / "templeSR0001.png", capture)
    pipe = Pipeline(two_stages(), capture, tmp_path / "run")
    with pytest.raises(DiskFullError, match="the disk is full \\(it filled up while ingest was writing\\)"):
        pipe.run()
    assert list((tmp_path / "run" / ".work").iterdir()) == [] and pipe.result("ingest") is None


def test_a_failure_on_a_disk_with_no_space_left_is_the_disk_full_error(tmp_path, monkeypatch):
    import nerfpipe.pipeline.runner as runner
    import nerfpipe.stages.ingest as ingest_module

    def native_failure(path, pixels):
        raise RuntimeError("[enforce fail at inline_container.cc:626] . unexpected pos 64 vs 0: file write failed")

    monkeypatch.setattr(ingest_module, "write_png", native_failure)
    monkeypatch.setattr(ingest_module.IngestStage, "expected_bytes", lambda self, inputs, params: 0)
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(runner.shutil, "disk_usage", lambda path: usage._replace(free=4096))
    capture = tmp_path / "photos"
    capture.mkdir()
    shutil.copy(TEMPLE / "templeSR0001.png", capture)
    with pytest.raises(DiskFullError, match="the disk is full"):
        Pipeline(two_stages(), capture, tmp_path / "run").run()
    # with space left, the same failure is a bug and keeps its own type and traceback
    monkeypatch.setattr(runner.shutil, "disk_usage", lambda path: usage._replace(free=10**12))
    with pytest.raises(RuntimeError, match="file write failed"):
        Pipeline(two_stages(), capture, tmp_path / "run").run()


@pytest.mark.parametrize("n, text", [(512, "512 bytes"), (1536, "1.5 KB"), (2_900_000, "2.9 MB"), (12 * 10**12, "12000.0 GB")])
def test_format_bytes(n, text):
    assert format_bytes(n) == text


@pytest.mark.parametrize("failure", [MemoryError(), RuntimeError(
    "[enforce fail at alloc_cpu.cpp:117] data. DefaultCPUAllocator: can't allocate memory: you tried to allocate "
    "5554176 bytes. Error code 12 (Cannot allocate memory)")])
def test_a_stage_out_of_memory_is_one_line_naming_it_and_leaves_no_result(tmp_path, monkeypatch, failure):
    """Python's MemoryError, or the allocation failure torch raises as its own error (a process at its memory
    limit, as the parameter sweep's runs are), is one line naming the stage and what to do."""
    from nerfpipe.pipeline import StageError
    import nerfpipe.stages.ingest as ingest_module

    def exhausted(path, pixels):
        raise failure

    monkeypatch.setattr(ingest_module, "write_png", exhausted)
    capture = tmp_path / "photos"
    capture.mkdir()
    shutil.copy(TEMPLE / "templeSR0001.png", capture)
    pipe = Pipeline(two_stages(), capture, tmp_path / "run")
    with pytest.raises(StageError, match=r"^ingest: ran out of memory \(.*\); lower the sizes it works at "
                                         r"\(`nerfpipe stages ingest` lists them\), or run it where more memory is free$"):
        pipe.run()
    assert pipe.result("ingest") is None
