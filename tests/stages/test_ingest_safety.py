"""Ingest stores only pixels it can vouch for: the bytes it decoded are the bytes it hashed, a photo no camera
makes is refused, long names stay names, an unreadable photo is one line (skipped with --skip-bad)."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest

from nerfpipe.artifacts import MAX_NAME_BYTES, output_names
from nerfpipe.pipeline import InputError, Pipeline
from nerfpipe.pipeline.errors import BadPhotoError
from nerfpipe.stages import IngestStage
from tests.cli.test_bad_input import assert_one_clear_error
from tests.helpers import TEMPLE, run_cli


def test_a_photo_changed_after_it_was_hashed_is_an_error_not_stored_under_the_old_hash(capture, tmp_path) -> None:
    pipe = Pipeline([IngestStage()], capture, tmp_path / "run", None, {})
    pipe.plan()  # hashed as the run begins
    original = (capture / "templeSR0002.png").read_bytes()
    shutil.copy(TEMPLE / "templeSR0009.png", capture / "templeSR0002.png")  # replaced while ingest runs
    with pytest.raises(InputError, match="templeSR0002.png: changed while nerfpipe was reading it"):
        pipe.run()
    assert pipe.result("ingest") is None
    (capture / "templeSR0002.png").write_bytes(original)  # put back: the next run hashes it again
    fresh = Pipeline([IngestStage()], capture, tmp_path / "run", None, {})
    assert fresh.run()[0].action == "ran"


def test_a_photo_no_camera_makes_is_refused_not_squashed(capture, tmp_path) -> None:
    """3000x40 used to be written as 64x1."""
    cv2.imwrite(str(capture / "strip.png"), np.full((40, 3000, 3), 128, np.uint8))
    result = run_cli("run", capture, "--out", tmp_path / "run", "--until", "ingest")
    assert_one_clear_error(result, "strip.png: is 3000x40 pixels, 75 times as long as it is wide", "--skip-bad")
    skipped = run_cli("run", capture, "--out", tmp_path / "run", "--until", "ingest", "--skip-bad")
    assert skipped.returncode == 0 and "skipped" in skipped.stderr and "strip.png" in skipped.stderr


def test_two_photos_whose_names_reach_the_limit_keep_two_names_within_it() -> None:
    stem = "x" * 251
    names = output_names([f"{stem}.jpg", f"{stem}.png"])
    assert len(set(names.values())) == 2
    assert all(len(n.encode()) <= MAX_NAME_BYTES and n.endswith(".png") for n in names.values())
    assert output_names(["a.jpg"]) == {"a.jpg": "a.png"}  # short names as before


def test_two_photos_with_255_byte_names_ingest(tmp_path) -> None:
    folder = tmp_path / "long"
    folder.mkdir()
    stem = "x" * 251
    for i, suffix in enumerate((".jpg", ".png")):
        cv2.imwrite(str(folder / f"{stem}{suffix}"), cv2.imread(str(TEMPLE / f"templeSR000{i + 1}.png")))
    result = run_cli("run", folder, "--out", tmp_path / "run", "--until", "ingest")
    assert result.returncode == 0, result.stderr


def test_an_unreadable_photo_is_one_line_and_skipped_with_skip_bad(capture, tmp_path, monkeypatch) -> None:
    """As root every file reads; a photo that cannot be opened is simulated where ingest and the hashing open it."""
    import builtins

    real_open = builtins.open
    locked = capture / "templeSR0003.png"

    def guarded_open(file, *args, **kwargs):
        if str(file) == str(locked):
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", guarded_open)
    with pytest.raises(InputError, match="templeSR0003.png: cannot be read \\(Permission denied\\)"):
        Pipeline([IngestStage()], capture, tmp_path / "run", None, {}).run()
    pipe = Pipeline([IngestStage()], capture, tmp_path / "skip", None, {"ingest": {"skip_bad": "true"}})
    assert pipe.run()[0].summary["images"] == 3


def test_a_photo_decoded_with_the_wrong_hash_is_not_a_bad_photo_that_skip_bad_hides(capture, tmp_path) -> None:
    pipe = Pipeline([IngestStage()], capture, tmp_path / "run", None, {"ingest": {"skip_bad": "true"}})
    pipe.plan()
    shutil.copy(TEMPLE / "templeSR0009.png", capture / "templeSR0001.png")
    with pytest.raises(InputError) as err:
        pipe.run()
    assert not isinstance(err.value, BadPhotoError) and "changed while nerfpipe was reading it" in str(err.value)
