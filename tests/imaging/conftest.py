"""Fixtures shared by the imaging tests: the test-only EXIF/TIFF writer and the folder of real RAW samples."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers import SHARED_DATA

RAW_SAMPLES = SHARED_DATA / "raw_samples"


@pytest.fixture(scope="session")
def raw_samples() -> Path:
    """``shared/data/raw_samples`` (blackmagic.dng, kodak_dc50.kdc); the test is skipped if it is absent."""
    if not RAW_SAMPLES.is_dir():
        pytest.skip(f"real RAW samples not found: {RAW_SAMPLES} is absent (see shared/data/raw_samples/SOURCE.md)")
    return RAW_SAMPLES
