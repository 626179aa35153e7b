"""Every bad input gets one clear line naming the file, a non-zero exit, and no traceback."""

from __future__ import annotations

import json
import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from nerfpipe.pipeline.errors import BadPhotoError
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


def test_a_jpeg_with_damaged_image_data_is_refused_not_decoded_green(photos, tmp_path):
    """2000 bytes in the middle of the entropy-coded data overwritten (no 0xFF, so no marker breaks the
    structure): libjpeg decodes it with a warning and grey-green blocks; ingest refuses it, or --skip-bad
    skips it."""
    data = bytearray((shared("llff_cup_kwrous", "images") / "1.jpg").read_bytes())
    middle = len(data) // 2
    data[middle:middle + 2000] = np.random.default_rng(0).integers(0, 255, 2000, dtype=np.uint8).tobytes()
    (photos / "cup.jpg").write_bytes(bytes(data))
    line = assert_one_clear_error(ingest(photos, tmp_path), "cup.jpg", "has damaged image data", "Corrupt JPEG data")
    assert "copy it again from the camera or card" in line
    skipped = run_cli("run", photos, "--out", tmp_path / "skip", "--until", "ingest", "--skip-bad")
    assert skipped.returncode == 0, skipped.stderr
    assert "warning: skipped" in skipped.stderr and "cup.jpg: has damaged image data" in skipped.stderr
    assert "2 photos" in skipped.stderr and "1 skipped" in skipped.stderr


def test_names_with_control_characters_are_printed_escaped(photos, tmp_path):
    """A file name holding a newline and a terminal escape code is shown as \\n and \\x1b, not acted on."""
    (photos / "bad\x1b[2J\nerror: fake.jpg").write_bytes(b"\xff\xd8\xff\xe0" + bytes(range(256)) * 40)
    result = ingest(photos, tmp_path)
    assert_one_clear_error(result, "bad\\x1b[2J\\nerror: fake.jpg")
    assert "\x1b" not in result.stderr and "\nerror: fake" not in result.stderr


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
        (["--set", "ingest.max_size=-5"], ["ingest.max_size: -5 is outside its bounds [0, 65536]"]),
        (["--preset", "ultra"], ["unknown preset 'ultra'"]),
        (["--set", "ingest.max_megapixels=nan"], ["ingest.max_megapixels: expected a finite number, got 'nan'"]),
        (["--set", "train.seconds=inf"], ["train.seconds: expected a finite number, got 'inf'"]),
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


# -- issue 19, cases 8-14 ---------------------------------------------------------------------------


def png_bytes(width: int, height: int, idat: bytes | None, colour_type: int = 2) -> bytes:
    """A PNG with the given header and image data (IDAT) exactly: no encoder would write a bad one."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0))
    return b"\x89PNG\r\n\x1a\n" + header + (chunk(b"IDAT", idat) if idat is not None else b"") + chunk(b"IEND", b"")


def test_8_a_tiny_photo_is_refused_from_its_header(photos, tmp_path):
    (photos / "tiny.png").write_bytes(png_bytes(1, 1, zlib.compress(b"\x00\x00\x00\x00")))
    assert_one_clear_error(ingest(photos, tmp_path), "tiny.png: is only 1x1 pixels, below ingest.min_size=32",
                           "remove it from the photo folder or pass --skip-bad")
    result = ingest(photos, tmp_path, "--skip-bad")
    assert result.returncode == 0 and "warning: skipped" in result.stderr and "tiny.png: is only 1x1" in result.stderr
    result = ingest(photos, tmp_path, "--set", "ingest.min_size=1")  # a real 1x1 photo, if the user says so
    assert result.returncode == 0, result.stderr


def test_9_a_decompression_bomb_is_refused_before_decoding(photos, tmp_path):
    """A 0.4 MB PNG of a 20000x20000 grey image (400 MP, 400 MB decoded): refused from its header."""
    rows = zlib.compressobj(9)
    row = bytes(20001)  # filter byte + 20000 grey samples
    idat = b"".join(rows.compress(row) for _ in range(20000)) + rows.flush()
    (photos / "bomb.png").write_bytes(png_bytes(20000, 20000, idat, colour_type=0))
    assert (photos / "bomb.png").stat().st_size < 1_000_000
    result = ingest(photos, tmp_path)
    assert_one_clear_error(result, "bomb.png: is 20000x20000 pixels (400 megapixels), above ingest.max_megapixels=250",
                           "--set ingest.max_megapixels=400")


def test_10_a_png_header_without_its_data_gets_one_line_and_no_libpng_noise(photos, tmp_path):
    (photos / "empty.png").write_bytes(png_bytes(4000, 3000, zlib.compress(bytes(100))))
    result = ingest(photos, tmp_path)
    assert_one_clear_error(result, "empty.png: is not a valid PNG file",
                           "cannot hold the 4000x3000 image its header states")
    assert "libpng" not in result.stderr


def test_11_skipping_a_duplicate_does_not_advise_the_flag_that_was_passed(photos, tmp_path):
    shutil.copy(photos / "templeSR0001.png", photos / "z_copy.png")
    result = ingest(photos, tmp_path, "--skip-bad")
    assert result.returncode == 0, result.stderr
    warnings = [line for line in result.stderr.splitlines() if line.startswith("warning:")]
    assert warnings == [f"warning: skipped {photos / 'z_copy.png'}: is the same photo as templeSR0001.png (identical content)"]


@pytest.fixture
def in_images(tmp_path) -> Path:
    """A capture with its photos in images/, as LLFF and COLMAP layouts have them."""
    folder = tmp_path / "capture"
    (folder / "images").mkdir(parents=True)
    for name in ("templeSR0001.png", "templeSR0002.png", "templeSR0003.png"):
        shutil.copy(TEMPLE / name, folder / "images")
    return folder


def test_12_a_text_file_named_poses_bounds_npy(in_images, tmp_path):
    (in_images / "poses_bounds.npy").write_text("1 2 3\n")
    result = run_cli("run", in_images, "--out", tmp_path / "run", "--until", "sfm")
    line = assert_one_clear_error(result, "poses_bounds.npy: is not a NumPy .npy file", "regenerate it with LLFF's imgs2poses")
    assert "pickle" not in line


@pytest.mark.parametrize("present", [("cameras.bin",), ("cameras.bin", "points3D.bin"), ("images.txt",)])
def test_13_a_colmap_model_folder_missing_a_file_is_named_not_ignored(in_images, tmp_path, present):
    model = in_images / "sparse" / "0"
    model.mkdir(parents=True)
    for name in present:
        shutil.copy(shared("colmap_beer_yhuoyuh", "sparse", "0", "cameras.bin"), model / name)
    missing = "images.bin" if present[0].endswith(".bin") else "cameras.txt"
    result = run_cli("run", in_images, "--out", tmp_path / "run", "--until", "sfm")
    assert_one_clear_error(result, f"{model / missing}: is missing: the COLMAP model in {model} has {' and '.join(present)}",
                           "--set sfm.poses=sfm")
    assert not (tmp_path / "run" / "stages").exists()  # refused while planning, before any SfM
    result = run_cli("run", in_images, "--out", tmp_path / "run", "--until", "ingest", "--set", "sfm.poses=sfm")
    assert result.returncode == 0, result.stderr  # the way out the message gives works


def test_14_asking_for_colmap_poses_names_the_missing_images_bin(in_images, tmp_path):
    model = in_images / "sparse" / "0"
    model.mkdir(parents=True)
    shutil.copy(shared("colmap_beer_yhuoyuh", "sparse", "0", "cameras.bin"), model)
    result = run_cli("run", in_images, "--out", tmp_path / "run", "--until", "sfm", "--set", "sfm.poses=colmap")
    line = assert_one_clear_error(result, f"{model / 'images.bin'}: is missing", "use --set sfm.poses=sfm")
    assert "has no a" not in line
    (model / "cameras.bin").unlink()
    result = run_cli("run", in_images, "--out", tmp_path / "run", "--until", "sfm", "--set", "sfm.poses=colmap")
    assert_one_clear_error(result, "has no COLMAP model (cameras.bin and images.bin")


@pytest.mark.parametrize("port", ["99999", "-5"])
def test_a_bad_viewer_port_is_one_line_before_anything_runs(tmp_path, port):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "run.json").write_text(json.dumps({"source": str(TEMPLE), "preset": None, "overrides": {}}))
    for args in (["view", run_dir, "--web", "--port", port], ["run", TEMPLE, "--out", tmp_path / "r", "--view", "--port", port]):
        result = run_cli(*args)
        lines = result.stderr.strip().splitlines()
        assert result.returncode != 0 and "Traceback" not in result.stderr, result.stderr
        assert lines == [f"error: --port {port}: a port is a number from 1 to 65535, e.g. --port 8080"], lines
    assert not (tmp_path / "r").exists()  # refused before any stage ran


def test_a_damaged_run_json_is_one_line(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "run.json").write_text("{}")  # valid JSON of the wrong shape
    result = run_cli("status", run_dir)
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert "run.json: is damaged" in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_a_run_directory_inside_the_capture_is_refused_before_anything_is_written(photos, tmp_path):
    for out in (photos, photos / "runs" / "first"):
        line = assert_one_clear_error(run_cli("run", photos, "--out", out, "--until", "ingest"))
        assert line == (f"error: --out {out} lies inside the capture folder {photos}: what a run writes there would be "
                        "read as photos; choose a folder outside it")
    assert not (photos / "runs").exists() and not (photos / "run.json").exists()


def test_force_outside_the_selected_stages_is_refused_not_ignored(photos, tmp_path):
    line = assert_one_clear_error(run_cli("run", photos, "--out", tmp_path / "run", "--until", "ingest", "--force", "render"))
    assert line == ("error: --force render: not among the stages --until ingest runs; drop --force or choose stages "
                    "that include it")
    assert not (tmp_path / "run" / "stages").exists()


def test_batch_runs_inside_the_captures_folder_are_refused(tmp_path):
    root = tmp_path / "captures"
    shutil.copytree(TEMPLE, root / "temple")
    result = run_cli("batch", root, "--out", root / "runs", "--until", "ingest")
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert "lies inside the captures folder" in result.stderr and not (root / "runs").exists()


@pytest.mark.parametrize("start, problem", [(b"", "is not a valid JPEG file; its content is not a JPEG"),
                                            (b"\xff\xd8\xff\xe0", "is not a valid JPEG file (corrupt segment at byte 2)")])
def test_a_3_gb_file_of_zeros_named_jpg_is_refused_from_its_head_before_it_is_hashed(photos, tmp_path, start,
                                                                                     problem):
    """A sparse file: 3 GB to read and hash, 64 KB to refuse."""
    from nerfpipe.stages.ingest import IngestParams, IngestStage

    big = photos / "big.jpg"
    with open(big, "wb") as f:
        f.write(start)
        f.truncate(3 << 30)
    assert_one_clear_error(ingest(photos, tmp_path), f"big.jpg: {problem}")
    with pytest.raises(BadPhotoError, match="big.jpg: is not a valid JPEG file"):  # before the engine hashes it
        IngestStage().input_files(photos, IngestParams())
    assert big in IngestStage().input_files(photos, IngestParams(skip_bad=True))  # skipped later, with a warning


@pytest.mark.parametrize("command", ["status", "batch"])
def test_a_non_finite_value_is_one_line_in_status_and_batch_too(photos, tmp_path, command):
    """Not the 60-line traceback the hashing of the parameters gave."""
    if command == "status":
        assert ingest(photos, tmp_path).returncode == 0
        result = run_cli("status", tmp_path / "run", "--set", "train.seconds=nan")
    else:
        captures = tmp_path / "captures"
        captures.mkdir()
        shutil.move(photos, captures / "photos")
        result = run_cli("batch", captures, "--out", tmp_path / "batch", "--set", "train.seconds=inf")
    assert_one_clear_error(result, "train.seconds: expected a finite number, got '")


@pytest.mark.parametrize("case", ["points3D cut short", "three empty files"])
def test_a_damaged_colmap_model_is_one_line_before_pycolmap_reads_it(in_images, tmp_path, case):
    """A cut points3D.bin made pycolmap reserve 16.9 GB and die; three 0-byte files imported 0 poses."""
    model = in_images / "sparse" / "0"
    model.mkdir(parents=True)
    for name in ("cameras.bin", "images.bin", "points3D.bin"):
        data = shared("colmap_beer_yhuoyuh", "sparse", "0", name).read_bytes()
        if case == "three empty files":
            data = b""
        elif name == "points3D.bin":
            data = data[: len(data) // 2]
        (model / name).write_bytes(data)
    result = run_cli("run", in_images, "--out", tmp_path / "run", "--until", "sfm")
    if case == "three empty files":
        assert_one_clear_error(result, f"{model / 'cameras.bin'}: is empty (0 bytes)", "re-export it from COLMAP")
    else:
        assert_one_clear_error(result, f"{model / 'points3D.bin'}: is cut short: its records run past its end")
    assert "imported" not in result.stderr


def test_a_wrong_compile_switch_is_one_line_before_anything_runs(tmp_path, monkeypatch):
    monkeypatch.setenv("NERFPIPE_COMPILE", "fast")
    result = run_cli("run", TEMPLE, "--out", tmp_path / "r")
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    assert result.stderr.strip().splitlines() == ["error: NERFPIPE_COMPILE=fast: must be one of auto, native, off (or unset, auto)"]
    assert not (tmp_path / "r").exists()
