"""Every bad input gets one clear line naming the file, a non-zero exit, and no traceback."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.helpers import TEMPLE, run_cli, shared


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("error:")]


def assert_one_clear_error(result, *needles: str) -> str:
    assert result.returncode != 0, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    lines = error_lines(result.stderr)
    assert len(lines) == 1, result.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def ingest(folder: Path, tmp_path: Path, *extra: str):
    return run_cli("run", folder, "--out", tmp_path / "run", "--until", "ingest", *extra)


def test_missing_folder(tmp_path):
    assert_one_clear_error(ingest(tmp_path / "nope", tmp_path), "nope", "capture folder does not exist")


def test_empty_folder(tmp_path):
    (tmp_path / "empty").mkdir()
    assert_one_clear_error(ingest(tmp_path / "empty", tmp_path), "empty", "the capture folder is empty", "put the photos")


def test_folder_with_no_images(tmp_path):
    folder = tmp_path / "notes"
    folder.mkdir()
    (folder / "readme.txt").write_text("x")
    (folder / "poses.json").write_text("{}")
    assert_one_clear_error(ingest(folder, tmp_path), "no photos found among its 2 files", "JPEG, PNG, TIFF and camera RAW")


@pytest.fixture
def photos(tmp_path) -> Path:
    folder = tmp_path / "photos"
    folder.mkdir()
    for name in ("templeSR0001.png", "templeSR0002.png"):
        shutil.copy(TEMPLE / name, folder)
    return folder


def test_corrupt_jpeg(photos, tmp_path):
    (photos / "broken.jpg").write_bytes(b"\xff\xd8\xff\xe0" + bytes(range(256)) * 40)
    assert_one_clear_error(ingest(photos, tmp_path), "broken.jpg")


def test_truncated_jpeg(photos, tmp_path):
    data = (shared("llff_cup_kwrous", "images") / "1.jpg").read_bytes()
    (photos / "cup.jpg").write_bytes(data[: len(data) // 2])
    assert_one_clear_error(ingest(photos, tmp_path), "cup.jpg", "truncated")


def test_truncated_png(photos, tmp_path):
    data = (TEMPLE / "templeSR0003.png").read_bytes()
    (photos / "cut.png").write_bytes(data[: len(data) * 2 // 3])
    assert_one_clear_error(ingest(photos, tmp_path), "cut.png", "truncated")


def test_truncated_raw(photos, tmp_path):
    data = shared("raw_samples", "blackmagic.dng").read_bytes()
    (photos / "cut.dng").write_bytes(data[: len(data) * 6 // 10])
    assert_one_clear_error(ingest(photos, tmp_path), "cut.dng")


def test_zero_byte_file(photos, tmp_path):
    (photos / "zero.jpg").write_bytes(b"")
    assert_one_clear_error(ingest(photos, tmp_path), "zero.jpg", "0 bytes")


def test_unsupported_extension(photos, tmp_path):
    (photos / "IMG_0001.heic").write_bytes(b"\x00\x00\x00\x18ftypheic")
    assert_one_clear_error(ingest(photos, tmp_path), "IMG_0001.heic", "HEIC")


def test_duplicate_images(photos, tmp_path):
    shutil.copy(photos / "templeSR0001.png", photos / "copy of 0001.png")
    line = assert_one_clear_error(ingest(photos, tmp_path), "identical content")
    assert "copy of 0001.png" in line and "templeSR0001.png" in line


def test_skip_bad_skips_with_a_warning_and_records_why(photos, tmp_path):
    (photos / "zero.jpg").write_bytes(b"")
    shutil.copy(photos / "templeSR0001.png", photos / "z_dup.png")
    result = ingest(photos, tmp_path, "--skip-bad")
    assert result.returncode == 0, result.stderr
    assert result.stderr.count("warning: skipped") == 2
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run["overrides"] == {"ingest": {"skip_bad": "true"}}
    latest = json.loads((tmp_path / "run" / "stages" / "ingest" / "latest.json").read_text())["key"]
    images = json.loads((tmp_path / "run" / "stages" / "ingest" / latest / "images.json").read_text())
    assert [i["source"] for i in images["images"]] == ["templeSR0001.png", "templeSR0002.png"]
    assert sorted(s["source"] for s in images["skipped"]) == ["z_dup.png", "zero.jpg"]


def test_all_photos_bad_with_skip_bad(tmp_path):
    folder = tmp_path / "bad"
    folder.mkdir()
    (folder / "a.jpg").write_bytes(b"")
    assert_one_clear_error(ingest(folder, tmp_path, "--skip-bad"), "none of the photos could be used")


def test_spaces_and_non_ascii_paths_work(tmp_path):
    folder = tmp_path / "mes photos d'été" / "tëmple 1"
    folder.mkdir(parents=True)
    shutil.copy(TEMPLE / "templeSR0001.png", folder / "vue n°1.png")
    shutil.copy(TEMPLE / "templeSR0002.png", folder / "写真 2.png")
    result = run_cli("run", folder, "--out", tmp_path / "sortie é", "--until", "ingest")
    assert result.returncode == 0, result.stderr
    images = list((tmp_path / "sortie é" / "stages" / "ingest").glob("*/images/*.png"))
    assert sorted(p.name for p in images) == ["vue n°1.png", "写真 2.png"]


@pytest.mark.parametrize(
    "flags, needles",
    [
        (["--set", "ingest.max_size=abc"], ["ingest.max_size: expected an integer, got 'abc'"]),
        (["--set", "ingest.max_sise=800"], ["unknown parameter ingest.max_sise; did you mean ingest.max_size?"]),
        (["--set", "ingst.max_size=800"], ["unknown stage 'ingst'; did you mean ingest?"]),
        (["--set", "max_size=800"], ["expected STAGE.PARAM=VALUE"]),
        (["--set", "ingest.bit_depth=12"], ["ingest.bit_depth: '12' is not one of auto, 8, 16"]),
        (["--set", "ingest.max_size=-5"], ["max_size must be 0"]),
        (["--preset", "ultra"], ["unknown preset 'ultra'"]),
    ],
)
def test_bad_flags(photos, tmp_path, flags, needles):
    result = run_cli("run", photos, "--out", tmp_path / "run", *flags)
    assert_one_clear_error(result, *needles)
    assert result.returncode == 2


def test_debug_shows_the_traceback(tmp_path):
    (tmp_path / "empty").mkdir()
    result = run_cli("run", tmp_path / "empty", "--out", tmp_path / "run", "--debug")
    assert result.returncode != 0 and "Traceback" in result.stderr and "InputError" in result.stderr
