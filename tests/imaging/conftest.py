"""Fixtures shared by the imaging tests: the test-only EXIF/TIFF writer and the folder of real RAW samples."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

# tests/imaging/conftest.py -> repo root -> its parent, which holds the shared data next to the checkout.
SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
RAW_SAMPLES = SHARED_DATA / "raw_samples"


def _load_exif_writer() -> ModuleType:
    # Loaded by file path: under --import-mode=importlib the test folder is not on sys.path.
    location = Path(__file__).with_name("exif_writer.py")
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


@pytest.fixture(scope="session")
def raw_samples() -> Path:
    """``shared/data/raw_samples`` (blackmagic.dng, kodak_dc50.kdc); the test is skipped if it is absent."""
    if not RAW_SAMPLES.is_dir():
        pytest.skip(f"real RAW samples not found: {RAW_SAMPLES} is absent (see shared/data/raw_samples/SOURCE.md)")
    return RAW_SAMPLES
