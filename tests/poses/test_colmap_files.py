"""A COLMAP binary model walked record by record before pycolmap reads it: the shared beer model and one
pycolmap writes pass; a file cut short, empty, with bytes left over or with an unknown camera model is one
line naming it (a cut points3D.bin made pycolmap reserve 16.9 GB)."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import pytest

from nerfpipe.pipeline import InputError
from nerfpipe.poses.colmap_files import check_binary_model
from tests.helpers import shared

BEER = shared("colmap_beer_yhuoyuh", "sparse", "0")


@pytest.fixture
def model(tmp_path) -> Path:
    shutil.copytree(BEER, tmp_path / "model")
    for path in (tmp_path / "model").iterdir():
        path.chmod(0o644)
    return tmp_path / "model"


def test_the_shared_model_and_one_pycolmap_writes_pass(tmp_path):
    import pycolmap

    check_binary_model(BEER)
    pycolmap.Reconstruction(str(BEER)).write_binary(str(tmp_path))
    check_binary_model(tmp_path)


def test_the_walk_counts_what_pycolmap_reads():
    """The record layouts, checked against the reader: a file with one byte more or less fails."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(BEER))
    data = (BEER / "points3D.bin").read_bytes()
    assert struct.unpack_from("<Q", data)[0] == len(rec.points3D)
    data = (BEER / "images.bin").read_bytes()
    assert struct.unpack_from("<Q", data)[0] == len(rec.images)


@pytest.mark.parametrize("name", ["cameras.bin", "images.bin", "points3D.bin"])
def test_a_file_cut_short_is_one_line(model, name):
    data = (model / name).read_bytes()
    (model / name).write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(InputError) as err:
        check_binary_model(model)
    assert err.value.path == model / name
    assert err.value.problem == f"is cut short: its records run past its end ({len(data) * 2 // 3} bytes)"


@pytest.mark.parametrize("name", ["cameras.bin", "images.bin", "points3D.bin"])
def test_an_empty_file_or_bytes_after_the_last_record_are_one_line(model, name):
    with open(model / name, "ab") as f:
        f.write(b"\0" * 5)
    with pytest.raises(InputError, match=f"{name}: has 5 bytes after its last record"):
        check_binary_model(model)
    (model / name).write_bytes(b"")
    with pytest.raises(InputError, match=f"{name}: is empty \\(0 bytes\\)"):
        check_binary_model(model)


def test_a_huge_track_length_is_caught_without_reading_it(model):
    data = bytearray((model / "points3D.bin").read_bytes())
    struct.pack_into("<Q", data, 8 + 51 - 8, 2**40)  # the first point's track length
    (model / "points3D.bin").write_bytes(bytes(data))
    with pytest.raises(InputError, match="points3D.bin: is cut short"):
        check_binary_model(model)


def test_an_unknown_camera_model_and_no_images_are_named(model):
    data = bytearray((model / "cameras.bin").read_bytes())
    struct.pack_into("<i", data, 8 + 4, 99)
    (model / "cameras.bin").write_bytes(bytes(data))
    with pytest.raises(InputError, match="cameras.bin: names camera model id 99, which COLMAP does not define"):
        check_binary_model(model)
    (model / "cameras.bin").write_bytes((BEER / "cameras.bin").read_bytes())
    (model / "images.bin").write_bytes(struct.pack("<Q", 0))
    with pytest.raises(InputError, match="images.bin: holds no images"):
        check_binary_model(model)
