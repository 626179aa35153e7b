"""Pose files that would give a silently wrong reconstruction, or a crash, are refused in one line naming the
file: zero quaternions, negative focal lengths, a photo repeated with two poses, JSON nested without end, an
.npy header that promises more rows than the file holds."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from numpy.lib import format as npy

from nerfpipe.pipeline import InputError
from nerfpipe.poses.colmap_files import quaternion_problem
from nerfpipe.poses.importers import import_poses
from nerfpipe.poses.layout import detect_layout
from tests.poses.test_importers import _import, fake_records, temple_capture, temple_lines


def colmap_text_capture(tmp_path, qvecs, camera="1 PINHOLE 640 480 1520.4 1525.9 302.32 246.87"):
    """Three temple photos with a COLMAP text model whose images carry ``qvecs`` (w, x, y, z)."""
    capture = tmp_path / "cap"
    temple_capture(capture / "images", 3)
    model = capture / "sparse" / "0"
    model.mkdir(parents=True)
    (model / "cameras.txt").write_text(camera + "\n")
    lines = []
    for image_id, (line, q) in enumerate(zip(temple_lines()[:3], qvecs), start=1):
        fields = line.split()
        lines += [f"{image_id} {' '.join(map(str, q))} {' '.join(fields[19:22])} 1 {fields[0]}", ""]
    (model / "images.txt").write_text("\n".join(lines) + "\n")
    return capture


def test_quaternion_problems_by_hand() -> None:
    assert quaternion_problem([1.0, 0.0, 0.0, 0.0]) is None
    assert quaternion_problem([0.5, 0.5, 0.5, 0.5]) is None  # |q| = 1
    assert quaternion_problem([0.0, 0.0, 0.0, 0.0]) == "its quaternion is zero, which is no rotation"
    assert quaternion_problem([float("nan"), 0.0, 0.0, 1.0]) == "its quaternion holds a non-finite value"


def test_a_zero_quaternion_in_a_text_model_is_refused_not_read_as_the_identity(tmp_path) -> None:
    capture = colmap_text_capture(tmp_path, [(1, 0, 0, 0), (0, 0, 0, 0), (1, 0, 0, 0)])
    layout = detect_layout(capture)
    with pytest.raises(InputError, match="image 2: its quaternion is zero, which is no rotation") as err:
        import_poses(layout, fake_records(layout))
    assert err.value.path == capture / "sparse" / "0" / "images.txt"


def test_a_zero_quaternion_in_a_binary_model_is_refused(tmp_path) -> None:
    import pycolmap

    capture = colmap_text_capture(tmp_path, [(1, 0, 0, 0)] * 3)
    model = capture / "sparse" / "0"
    (model / "points3D.txt").write_text("")
    pycolmap.Reconstruction(str(model)).write_binary(str(model))
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        (model / name).unlink(missing_ok=True)
    data = bytearray((model / "images.bin").read_bytes())
    # the first image's record starts after the count (8 bytes) and its id (4): zero its four doubles
    data[12:12 + 32] = struct.pack("<4d", 0.0, 0.0, 0.0, 0.0)
    (model / "images.bin").write_bytes(bytes(data))
    layout = detect_layout(capture)
    with pytest.raises(InputError, match="its quaternion is zero") as err:
        import_poses(layout, fake_records(layout))
    assert err.value.path == model / "images.bin"


@pytest.mark.parametrize("camera", ["1 PINHOLE 640 480 -1520.4 1525.9 302.32 246.87",
                                    "1 SIMPLE_RADIAL 640 480 -800 320 240 0.01",
                                    "1 PINHOLE 640 480 1520.4 0 302.32 246.87"])
def test_a_negative_or_zero_focal_length_is_refused_at_import(tmp_path, camera) -> None:
    """It used to pass sfm and crash undistort."""
    capture = colmap_text_capture(tmp_path, [(1, 0, 0, 0)] * 3, camera)
    layout = detect_layout(capture)
    with pytest.raises(InputError, match="camera 1 has focal length .*a focal length is a positive number") as err:
        import_poses(layout, fake_records(layout))
    assert err.value.path == capture / "sparse" / "0" / "cameras.txt"


def test_a_photo_repeated_with_two_poses_is_refused_and_with_one_pose_kept_once(tmp_path) -> None:
    capture = temple_capture(tmp_path / "cap", 2)
    moved = np.eye(4)
    moved[0, 3] = 1.0
    frames = [{"file_path": "templeSR0001.png", "transform_matrix": np.eye(4).tolist()},
              {"file_path": "templeSR0002.png", "transform_matrix": np.eye(4).tolist()},
              {"file_path": "templeSR0001.png", "transform_matrix": np.eye(4).tolist()}]
    (capture / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": frames}))
    assert [f.name for f in _import(capture).frames] == ["templeSR0001.png", "templeSR0002.png"]
    frames[2]["transform_matrix"] = moved.tolist()
    (capture / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": frames}))
    with pytest.raises(InputError, match=r"frame 2 \(templeSR0001.png\) repeats templeSR0001.png with another pose"):
        _import(capture)


def test_a_transforms_json_nested_without_end_is_one_line(tmp_path) -> None:
    capture = temple_capture(tmp_path / "cap", 1)
    (capture / "transforms.json").write_text('{"frames": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(InputError, match="nests its JSON too deeply") as err:
        detect_layout(capture)
    assert err.value.path == capture / "transforms.json"


def test_an_npy_header_claiming_a_billion_rows_is_refused_before_any_allocation(tmp_path) -> None:
    """np.load would allocate the 127 GiB the header promises before it reads a byte of data."""
    capture = tmp_path / "cap"
    temple_capture(capture / "images", 2)
    with open(capture / "poses_bounds.npy", "wb") as f:
        npy.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": (10**9, 17)})
        f.write(np.zeros((2, 17)).tobytes())
    layout = detect_layout(capture)
    with pytest.raises(InputError, match="claims 1000000000 rows, more than its .* bytes hold") as err:
        import_poses(layout, fake_records(layout))
    assert err.value.path == capture / "poses_bounds.npy"
