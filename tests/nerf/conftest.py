"""Fixtures of the NeRF library's tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.nerf.scenes import write_image_folders


@pytest.fixture
def image_folders(tmp_path: Path) -> dict[str, Path]:
    """``images``, ``undistorted_images`` and ``pinhole`` folders of three tiny images (``tests.nerf.scenes``)."""
    return write_image_folders(tmp_path / "inputs")
