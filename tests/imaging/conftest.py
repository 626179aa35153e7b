"""Fixtures shared by the imaging tests: the test-only EXIF/TIFF writer and the folder of real RAW samples."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers import shared


@pytest.fixture(scope="session")
def raw_samples() -> Path:
    """``shared/data/raw_samples`` (blackmagic.dng, kodak_dc50.kdc); skipped if absent, failed under ``CI=true``."""
    return shared("raw_samples")
