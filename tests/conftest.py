"""Fixtures shared by every test module."""

from __future__ import annotations

import importlib.util
import shutil
import sys
from pathlib import Path
from types import ModuleType

import pytest

from helpers import TEMPLE


@pytest.fixture
def capture(tmp_path: Path) -> Path:
    """A writable plain folder: four bundled temple photos and a side-car text file (no pose file)."""
    folder = tmp_path / "capture"
    folder.mkdir()
    for name in ("templeSR0001.png", "templeSR0002.png", "templeSR0003.png", "templeSR0004.png"):
        shutil.copy2(TEMPLE / name, folder / name)
    shutil.copy2(TEMPLE / "README.txt", folder / "README.txt")
    return folder


def _load_exif_writer() -> ModuleType:
    # Loaded by file path: under --import-mode=importlib the test folder is not on sys.path.
    location = Path(__file__).parent / "imaging" / "exif_writer.py"
    spec = importlib.util.spec_from_file_location("imaging_tests_exif_writer", location)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    # dataclasses look their module up in sys.modules while the class is being created.
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def exif_writer() -> ModuleType:
    """The helpers of ``tests/imaging/exif_writer.py`` (tiff_blob, jpeg_with_exif, ...)."""
    return _load_exif_writer()
