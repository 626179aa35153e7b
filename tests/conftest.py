"""Fixtures shared by every test module."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from helpers import TEMPLE


@pytest.fixture
def capture(tmp_path: Path) -> Path:
    """A writable copy of four bundled temple photos plus its calibration text file."""
    folder = tmp_path / "capture"
    folder.mkdir()
    for name in ("templeSR0001.png", "templeSR0002.png", "templeSR0003.png", "templeSR0004.png", "templeSR_par.txt"):
        shutil.copy2(TEMPLE / name, folder / name)
    return folder
