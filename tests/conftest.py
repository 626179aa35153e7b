"""Fixtures shared by every test module."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.helpers import TEMPLE


@pytest.fixture
def capture(tmp_path: Path) -> Path:
    """A writable plain folder: four bundled temple photos and a side-car text file (no pose file)."""
    folder = tmp_path / "capture"
    folder.mkdir()
    for name in ("templeSR0001.png", "templeSR0002.png", "templeSR0003.png", "templeSR0004.png"):
        shutil.copy2(TEMPLE / name, folder / name)
    shutil.copy2(TEMPLE / "README.txt", folder / "README.txt")
    return folder
