"""Pose importers on real captures: COLMAP, transforms.json, LLFF and Middlebury agree with their own numbers,
with each other, and with nerfpipe's conventions (OpenCV c2w, COLMAP intrinsics scaled to the ingested size)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from nerfpipe import Pipeline
from nerfpipe.artifacts import ImageIndex, PhotoRecord, output_names
from nerfpipe.geometry.cameras import CameraSet, invert_pose
from nerfpipe.pipeline import InputError
from nerfpipe.poses.importers import import_poses
from nerfpipe.poses.layout import CaptureLayout, detect_layout
from nerfpipe.stages import IngestStage
from tests.helpers import TEMPLE, shared

LEGO_FOCAL_400 = 0.5 * 400 / np.tan(0.5 * 0.6911112070083618)  # 555.5555 px


def fake_records(layout: CaptureLayout, skip: tuple[str, ...] = ()) -> list[PhotoRecord]:
    """images.json records as ingest writes them at full size (max_size=0), without decoding into a run."""
    relpaths = [p.relative_to(layout.capture).as_posix() for p in layout.photos]
    names = output_names(relpaths)
    records = []
    for path, rel in zip(layout.photos, relpaths):
        if rel in skip:
            continue
        width, height = image_size(path)
        records.append(PhotoRecord(names[rel], source=rel, width=width, height=height, source_width=width,
                                   source_height=height, split=layout.splits.get(rel)))
    return records


def image_size(path: Path) -> tuple[int, int]:
    """(width, height); PNGs from their IHDR chunk, which keeps the 200 lego frames cheap."""
    with path.open("rb") as f:
        head = f.read(24)
    if head[:8] == b"\x89PNG\r\n\x1a\n":
        return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    height, width = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).shape[:2]
    return width, height


def ingest_records(capture: Path, run: Path, max_size: int) -> list[PhotoRecord]:
    outcome = Pipeline([IngestStage()], capture, run, overrides={"ingest": {"max_size": str(max_size)}}).run()[0]
    return ImageIndex.load(outcome.path / "images.json").records


def temple_lines() -> list[str]:
    return (TEMPLE / "templeSR_par.txt").read_text().splitlines()[1:]


def temple_capture(folder: Path, n: int, par_lines: list[str] | None = None, count: int | None = None) -> Path:
    """``n`` temple photos, and a par file of ``par_lines`` (the real first n lines unless given)."""
    folder.mkdir(parents=True, exist_ok=True)
    for line in temple_lines()[:n]:
        shutil.copy(TEMPLE / line.split()[0], folder)
    if par_lines is not None or count is not None:
        par_lines = temple_lines()[:n] if par_lines is None else par_lines
        count = len(par_lines) if count is None else count
        (folder / "x_par.txt").write_text("\n".join([str(count), *par_lines]) + "\n")
    return folder


# ---------------------------------------------------------------------------------------------------
# COLMAP and LLFF on the Beer capture


@pytest.fixture(scope="module")
def beer() -> tuple[CaptureLayout, list[dict], CameraSet]:
    layout = detect_layout(shared("colmap_beer_yhuoyuh"))
    records = fake_records(layout)
    return layout, records, import_poses(layout, records)


def test_beer_colmap_model(beer):
    layout, _, cameras = beer
    assert layout.kind == "colmap" and cameras.source == "colmap_model" and cameras.unregistered == []
    assert len(cameras.frames) == 71 and len(cameras.cameras) == 71  # one SIMPLE_RADIAL camera per image
    assert [f.name for f in cameras.frames] == [f"{i:04d}.png" for i in range(71)]
    first = cameras.camera_of(cameras.frames[0])
    assert first.model == "SIMPLE_RADIAL" and (first.width, first.height) == (720, 1280)
    assert first.params == pytest.approx((1105.13, 360, 640, 0.0578), abs=1e-2)
    points = cameras.points
    assert points.xyz.shape == (4414, 3) and points.rgb.dtype == np.uint8 and points.error.shape == (4414,)
    assert points.error.mean() == pytest.approx(0.754, abs=1e-3)  # pycolmap: mean_reprojection_error 0.753951
    assert len(points.visible) == 71 and min(len(v) for v in points.visible) > 0
    # 30839 observations; 540 of them see a point a second time in the same image
    assert sum(len(v) for v in points.visible) == 30299


def test_beer_points_reproject_onto_their_observations(beer):
    """The imported c2w and camera send frame 0000's points onto the pixels COLMAP observed them at."""
    import pycolmap

    layout, _, cameras = beer
    rec = pycolmap.Reconstruction(str(layout.pose_files[0].parent))
    image = next(im for im in rec.images.values() if im.name == "0000.jpg")
    observed = {p.point3D_id: np.asarray(p.xy) for p in image.points2D if p.has_point3D()}
    ids = sorted(rec.points3D)
    frame, camera = cameras.frames[0], cameras.camera_of(cameras.frames[0])
    assert sorted(ids[i] for i in cameras.points.visible[0]) == sorted(observed)
    xyz = cameras.points.xyz[cameras.points.visible[0]]
    cam = (invert_pose(frame.c2w) @ np.c_[xyz, np.ones(len(xyz))].T)[:3].T
    assert np.all(cam[:, 2] > 0)  # OpenCV: in front of the camera is +z
    f, cx, cy, k = camera.params
    uv = cam[:, :2] / cam[:, 2:]
    uv = uv * (1 + k * (uv**2).sum(1, keepdims=True)) * f + [cx, cy]
    errors = np.linalg.norm(uv - np.array([observed[ids[i]] for i in cameras.points.visible[0]]), axis=1)
    assert np.median(errors) < 1.5  # pixels; the model's mean error is 0.75


def test_imported_set_saves_and_loads(beer, tmp_path):
    _, _, cameras = beer
    cameras.save(tmp_path)
    loaded = CameraSet.load(tmp_path)
    assert loaded.cameras == cameras.cameras and loaded.source == "colmap_model"
    assert all(np.array_equal(a.c2w, b.c2w) and a.name == b.name for a, b in zip(loaded.frames, cameras.frames))
    assert all(np.array_equal(a, b) for a, b in zip(loaded.points.visible, cameras.points.visible))


def test_beer_colmap_and_llff_poses_agree(beer):
    """The issue's acceptance test: the model and its poses_bounds.npy import to the same cameras."""
    layout, records, colmap = beer
    llff_layout = CaptureLayout("llff", layout.capture, layout.photos, [layout.capture / "poses_bounds.npy"])
    llff = import_poses(llff_layout, records)
    assert llff.source == "llff" and [f.name for f in llff.frames] == [f.name for f in colmap.frames]
    c2w_diff = max(np.abs(a.c2w - b.c2w).max() for a, b in zip(colmap.frames, llff.frames))
    assert c2w_diff < 1e-4  # measured: 3.6e-15
    # LLFF's imgs2poses writes the first camera's focal into every row; the model has one camera per image
    assert list(llff.cameras) == [1] and llff.cameras[1].fx == pytest.approx(colmap.cameras[1].fx, abs=1e-9)
    for a, b in zip(colmap.frames, llff.frames):
        ca, cb = colmap.camera_of(a), llff.camera_of(b)
        assert (ca.width, ca.height) == (cb.width, cb.height) == (720, 1280) and (ca.cx, ca.cy) == (cb.cx, cb.cy)
        assert ca.fx == pytest.approx(cb.fx, rel=0.05)  # per-image focals span 1101.6 to 1155.3
    bounds = llff.hints.llff_bounds
    assert len(bounds) == 71 and min(b[0] for b in bounds.values()) == pytest.approx(3.124, abs=1e-3)
    assert max(b[1] for b in bounds.values()) == pytest.approx(31.508, abs=1e-3)


# ---------------------------------------------------------------------------------------------------
# transforms.json


def test_lego_transforms_train_and_val():
    layout = detect_layout(shared("nerf_synthetic_lego_400"))
    cameras = import_poses(layout, fake_records(layout))
    assert cameras.source == "transforms_json" and len(cameras.frames) == 200
    splits = [f.split for f in cameras.frames]
    assert splits.count("train") == 100 and splits.count("val") == 100
    assert cameras.frames[0].name == "train/r_0.png" and cameras.frames[100].name == "val/r_0.png"
    assert list(cameras.cameras) == [1]  # all 200 frames share one camera
    camera = cameras.cameras[1]
    assert camera.model == "PINHOLE" and (camera.width, camera.height) == (400, 400)
    assert camera.fx == camera.fy == pytest.approx(555.5555, abs=1e-3) == LEGO_FOCAL_400
    assert (camera.cx, camera.cy) == (200, 200)
    centers = cameras.centers()
    assert np.allclose(np.linalg.norm(centers, axis=1), 4.0311, atol=1e-3)
    for frame in cameras.frames:  # OpenCV: +z of c2w looks at the object at the origin
        to_origin = -frame.center / np.linalg.norm(frame.center)
        assert frame.c2w[:3, 2] @ to_origin > 0.9
        assert np.linalg.det(frame.c2w[:3, :3]) == pytest.approx(1.0, abs=1e-9)
    # r_0 by hand: its OpenGL matrix times diag(1, -1, -1, 1) flips the y and z columns
    gl = np.array(json.loads((layout.capture / "transforms_train.json").read_text())["frames"][0]["transform_matrix"])
    assert np.allclose(cameras.frames[0].c2w[:3, 1], -gl[:3, 1], atol=2e-6)
    assert np.allclose(cameras.frames[0].c2w[:3, 3], gl[:3, 3])


def test_transforms_intrinsics_distortion_and_scaling(tmp_path):
    capture = temple_capture(tmp_path / "cap", 3)  # 640x480 photos
    frames = [{"file_path": f"templeSR000{i}", "transform_matrix": np.eye(4).tolist()} for i in (1, 2, 3)]
    frames[1]["k3"] = 0.01
    (capture / "transforms.json").write_text(json.dumps({
        "fl_x": 1000, "fl_y": 1010, "cx": 330, "cy": 250, "w": 1280, "h": 960,  # 2x the photos
        "k1": 0.1, "k2": -0.05, "p1": 0.001, "p2": 0.0, "frames": frames}))
    (capture / "transforms_test.json").write_text(json.dumps({
        "camera_model": "OPENCV_FISHEYE", "camera_angle_x": 1.0, "k1": 0.02,
        "frames": [{"file_path": "templeSR0001.png", "transform_matrix": np.eye(4).tolist()}]}))
    layout = detect_layout(capture)
    cameras = import_poses(layout, fake_records(layout))
    assert [f.name for f in cameras.frames] == ["templeSR0001.png", "templeSR0002.png", "templeSR0003.png"]
    assert [f.split for f in cameras.frames] == ["train"] * 3  # templeSR0001 again in the test file: first wins
    a, b, c = (cameras.camera_of(f) for f in cameras.frames)
    assert a == c and cameras.frames[0].camera_id == cameras.frames[2].camera_id  # identical intrinsics share
    assert a.model == "OPENCV" and (a.width, a.height) == (640, 480)
    assert a.params == pytest.approx((500, 505, 165, 125, 0.1, -0.05, 0.001, 0.0))  # scaled by 0.5
    assert b.model == "FULL_OPENCV" and b.param("k3") == 0.01 and b.fx == 500
    assert np.allclose(cameras.frames[0].c2w, np.diag([1.0, -1.0, -1.0, 1.0]))  # OpenGL identity

    (capture / "transforms.json").unlink()
    layout = detect_layout(capture)
    fisheye = import_poses(layout, fake_records(layout))
    camera = fisheye.camera_of(fisheye.frames[0])
    assert fisheye.frames[0].split == "test" and camera.model == "OPENCV_FISHEYE"
    assert camera.fx == camera.fy == pytest.approx(0.5 * 640 / np.tan(0.5)) and (camera.cx, camera.cy) == (320, 240)
    assert camera.param("k1") == 0.02


# ---------------------------------------------------------------------------------------------------
# LLFF


def test_cup_llff_with_real_ingest_and_downscale(tmp_path):
    capture = shared("llff_cup_kwrous")
    records = ingest_records(capture, tmp_path / "run", max_size=200)  # 800x600 -> 200x150
    cameras = import_poses(detect_layout(capture), records)
    assert cameras.source == "llff" and len(cameras.frames) == 77 and list(cameras.cameras) == [1]
    camera = cameras.cameras[1]
    assert camera.model == "PINHOLE" and (camera.width, camera.height) == (200, 150)
    assert camera.fx == pytest.approx(589.0271 / 4, abs=1e-3) and camera.fy == camera.fx
    assert (camera.cx, camera.cy) == (100, 75)
    # rows follow lexicographic names: 1.jpg is row 0, 10.jpg row 1
    assert [f.name for f in cameras.frames[:3]] == ["1.png", "10.png", "11.png"]
    rows = np.load(capture / "poses_bounds.npy")
    pose = rows[1, :15].reshape(3, 5)
    down, right, back = pose[:, 0], pose[:, 1], pose[:, 2]
    assert np.allclose(cameras.frames[1].c2w[:3], np.c_[right, down, -back, pose[:, 3]], atol=1e-12)
    bounds = cameras.hints.llff_bounds
    assert bounds["1.png"] == pytest.approx(rows[0, 15:].tolist()) and bounds["10.png"] == pytest.approx(rows[1, 15:].tolist())
    assert len(bounds) == 77 and all(1.9 < near < far < 21.4 for near, far in bounds.values())


# ---------------------------------------------------------------------------------------------------
# Middlebury


def test_temple_middlebury():
    layout = detect_layout(TEMPLE)
    cameras = import_poses(layout, fake_records(layout))
    assert layout.kind == "middlebury" and cameras.source == "middlebury" and len(cameras.frames) == 16
    assert list(cameras.cameras) == [1]  # all 16 lines share one K
    camera = cameras.cameras[1]
    assert camera.params == (1520.4, 1525.9, 302.32, 246.87) and (camera.width, camera.height) == (640, 480)
    # templeSR0001, centre = -R^T t worked out from the numbers on its line
    assert cameras.frames[0].name == "templeSR0001.png"
    assert np.allclose(cameras.frames[0].center, [-0.050731, 0.183326, 0.589352], atol=1e-6)
    # the centre of the README's bounding box lands inside every image
    box_centre = (np.array([-0.073568, 0.021728, -0.012445]) + np.array([0.028855, 0.181892, 0.062736])) / 2
    for frame in cameras.frames:
        x = invert_pose(frame.c2w) @ np.r_[box_centre, 1.0]
        u, v, _ = camera.K() @ (x[:3] / x[2])
        assert x[2] > 0 and 0 < u < 640 and 0 < v < 480


def test_photos_ingest_skipped_are_unregistered():
    layout = detect_layout(TEMPLE)
    cameras = import_poses(layout, fake_records(layout, skip=("templeSR0003.png",)))
    assert len(cameras.frames) == 15 and cameras.unregistered == ["templeSR0003.png"]


def test_colmap_text_model_without_points_matches_middlebury(tmp_path):
    """A hand-written COLMAP text model (cameras + images, no points3D) of three temple views imports to the
    Middlebury poses; the fourth photo in images/ is unregistered."""
    import pycolmap

    capture = tmp_path / "cap"
    temple_capture(capture / "images", 4)
    model = capture / "sparse" / "0"
    model.mkdir(parents=True)
    (model / "cameras.txt").write_text("1 PINHOLE 640 480 1520.4 1525.9 302.32 246.87\n")
    lines = []
    for image_id, line in enumerate(temple_lines()[:3], start=1):
        fields = line.split()
        R, t = np.array(fields[10:19], float).reshape(3, 3), fields[19:22]
        qx, qy, qz, qw = pycolmap.Rotation3d(R).quat
        lines += [f"{image_id} {qw} {qx} {qy} {qz} {' '.join(t)} 1 {fields[0]}", ""]
    (model / "images.txt").write_text("\n".join(lines) + "\n")
    layout = detect_layout(capture)
    colmap = import_poses(layout, fake_records(layout))
    assert layout.kind == "colmap" and colmap.points is None
    assert [f.name for f in colmap.frames] == ["templeSR0001.png", "templeSR0002.png", "templeSR0003.png"]
    assert colmap.unregistered == ["templeSR0004.png"]
    middlebury = import_poses(detect_layout(TEMPLE), fake_records(detect_layout(TEMPLE)))
    for a, b in zip(colmap.frames, middlebury.frames):
        assert np.abs(a.c2w - b.c2w).max() < 1e-9
    assert colmap.cameras[1] == middlebury.cameras[1]


def test_a_cut_colmap_model_names_its_file(tmp_path):
    beer = shared("colmap_beer_yhuoyuh")
    model = tmp_path / "cap" / "sparse" / "0"
    model.mkdir(parents=True)
    (tmp_path / "cap" / "images").mkdir()
    shutil.copy(beer / "images" / "0000.jpg", tmp_path / "cap" / "images")
    for name in ("cameras.bin", "points3D.bin"):
        shutil.copy(beer / "sparse" / "0" / name, model)
    (model / "images.bin").write_bytes((beer / "sparse" / "0" / "images.bin").read_bytes()[:1000])
    layout = detect_layout(tmp_path / "cap")
    with pytest.raises(InputError, match="is cut short: its records run past its end") as err:
        import_poses(layout, fake_records(layout))
    assert err.value.path == model / "images.bin"  # found by the walk, before pycolmap reads the counts


def test_folder_layout_has_nothing_to_import(capture):
    with pytest.raises(ValueError, match="SfM"):
        import_poses(detect_layout(capture), [])


# ---------------------------------------------------------------------------------------------------
# Path escapes


def _transforms_naming(capture: Path, file_path: str) -> None:
    frame = {"file_path": file_path, "transform_matrix": np.eye(4).tolist()}
    (capture / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": [frame]}))


def test_pose_files_cannot_name_images_outside_the_capture(tmp_path):
    capture = temple_capture(tmp_path / "cap", 1)
    shutil.copy(TEMPLE / "templeSR0002.png", tmp_path / "outside.png")
    _transforms_naming(capture, "../outside.png")
    with pytest.raises(InputError, match="outside the capture folder") as err:
        import_poses(detect_layout(capture), [])
    assert err.value.path == capture / "transforms.json"

    _transforms_naming(capture, str(tmp_path / "outside.png"))
    with pytest.raises(InputError, match="absolute path"):
        import_poses(detect_layout(capture), [])

    (capture / "link.png").symlink_to(tmp_path / "outside.png")
    _transforms_naming(capture, "link.png")
    with pytest.raises(InputError, match="outside the capture folder"):
        import_poses(detect_layout(capture), [])

    (capture / "transforms.json").unlink()
    par = temple_capture(tmp_path / "par", 1, ["../x.png" + temple_lines()[0][len("templeSR0001.png"):]])
    (tmp_path / "x.png").write_bytes((TEMPLE / "templeSR0001.png").read_bytes())
    with pytest.raises(InputError, match="outside the capture folder") as err:
        import_poses(detect_layout(par), [])
    assert err.value.path == par / "x_par.txt"


# ---------------------------------------------------------------------------------------------------
# Malformed pose files: one InputError naming the file and the place


def _import(capture: Path) -> CameraSet:
    layout = detect_layout(capture)
    return import_poses(layout, fake_records(layout))


def _replace_field(line: str, index: int, value: str) -> str:
    fields = line.split()
    fields[index] = value
    return " ".join(fields)


@pytest.mark.parametrize(
    ("lines", "message"),
    [
        (lambda l: [l[0], _replace_field(l[1], 5, "abc")], "malformed number 'abc' on line 3"),
        (lambda l: [l[0], " ".join(l[1].split()[:-1])], "line 3 has 21 fields, not 22"),
        (lambda l: [l[0], _replace_field(l[1], 3, "nan")], "non-finite number 'nan' on line 3"),
        # R scaled by 2: det 8
        (lambda l: [l[0], " ".join(l[1].split()[:10] + [str(2 * float(v)) for v in l[1].split()[10:19]]
                                   + l[1].split()[19:])], "line 3: the rotation is not a rotation"),
    ],
    ids=["not-a-number", "too-few-fields", "nan", "not-a-rotation"],
)
def test_malformed_par_file(tmp_path, lines, message):
    capture = temple_capture(tmp_path / "cap", 2, lines(temple_lines()))
    with pytest.raises(InputError, match=message) as err:
        _import(capture)
    assert err.value.path == capture / "x_par.txt" and str(capture / "x_par.txt") in str(err.value)


def test_par_file_count_mismatch(tmp_path):
    capture = temple_capture(tmp_path / "cap", 2, count=3)
    with pytest.raises(InputError, match="says 3 images on line 1 but lists 2"):
        _import(capture)


def _llff_capture(folder: Path, n_photos: int, rows: np.ndarray) -> Path:
    temple_capture(folder / "images", n_photos)
    np.save(folder / "poses_bounds.npy", rows)
    return folder


def _llff_rows(n: int) -> np.ndarray:
    pose = np.c_[np.eye(3), [0.0, 0.0, 1.0], [480.0, 640.0, 1000.0]]
    return np.tile(np.r_[pose.ravel(), 1.0, 10.0], (n, 1))


def test_poses_bounds_of_the_wrong_shape(tmp_path):
    capture = _llff_capture(tmp_path / "cap", 5, np.zeros((5, 16)))
    with pytest.raises(InputError, match=r"has shape \(5, 16\).*must be \(N, 17\)") as err:
        _import(capture)
    assert err.value.path == capture / "poses_bounds.npy"


def test_poses_bounds_of_complex_numbers(tmp_path):
    capture = _llff_capture(tmp_path / "cap", 2, _llff_rows(2).astype(complex))
    with pytest.raises(InputError, match="holds complex128 values, not real numbers"):
        _import(capture)


def test_poses_bounds_rows_must_match_the_photos(tmp_path):
    capture = _llff_capture(tmp_path / "cap", 3, _llff_rows(2))
    with pytest.raises(InputError, match="has 2 rows but images/ holds 3 photos") as err:
        _import(capture)
    assert err.value.path == capture / "poses_bounds.npy"
    np.save(capture / "poses_bounds.npy", _llff_rows(3))
    assert len(_import(capture).frames) == 3  # the same capture with a row per photo imports


def test_poses_bounds_row_that_is_not_a_rotation(tmp_path):
    rows = _llff_rows(2)
    rows[1, 0] = 3.0
    with pytest.raises(InputError, match=r"row 1 \(templeSR0002.png\): the rotation is not a rotation"):
        _import(_llff_capture(tmp_path / "cap", 2, rows))


def test_poses_bounds_camera_of_another_aspect_ratio(tmp_path):
    rows = _llff_rows(2)
    rows[:, [4, 9]] = 640.0, 480.0  # hwf says portrait, the photos are landscape
    with pytest.raises(InputError, match="the camera is 480x640 but the photo images/templeSR0001.png is 640x480"):
        _import(_llff_capture(tmp_path / "cap", 2, rows))


@pytest.mark.parametrize(
    ("frame", "message"),
    [
        ({}, r"frame 0 \(templeSR0001.png\) has no transform_matrix"),
        ({"transform_matrix": np.eye(3).tolist()}, "transform_matrix is 3x3, not 4x4"),
        ({"transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, "x"], [0, 0, 0, 1]]}, "not a matrix of numbers"),
        ({"transform_matrix": (np.eye(4) * [2, 1, 1, 1]).tolist()}, "the rotation is not a rotation"),
        ({"transform_matrix": np.eye(4).tolist(), "fl_x": "big"}, "fl_x is 'big', not a finite number"),
        ({"transform_matrix": [[1, 0, 0, 1e300], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]},
         r"the translation 1e\+300 lies beyond any real scene \(\|t\| <= 1e\+09\)"),
    ],
    ids=["no-matrix", "3x3", "string", "not-a-rotation", "bad-focal", "1e300"],
)
def test_malformed_transforms_frame(tmp_path, frame, message):
    capture = temple_capture(tmp_path / "cap", 1)
    doc = {"camera_angle_x": 0.7, "frames": [{"file_path": "templeSR0001.png", **frame}]}
    (capture / "transforms.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=message) as err:
        _import(capture)
    assert err.value.path == capture / "transforms.json"


def test_instant_ngp_aabb_scale_is_recorded_as_a_hint(tmp_path):
    """instant-ngp's aabb_scale (the scene's extent in units of the cameras' unit cube) lands in
    ``hints.aabb_scale``; across split files the largest wins; a file without it records nothing."""
    capture = temple_capture(tmp_path / "cap", 2)
    frame = {"file_path": "templeSR0001.png", "transform_matrix": np.eye(4).tolist()}
    (capture / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.7, "aabb_scale": 4, "frames": [frame]}))
    (capture / "transforms_test.json").write_text(json.dumps(
        {"camera_angle_x": 0.7, "aabb_scale": 16, "frames": [{**frame, "file_path": "templeSR0002.png"}]}))
    cameras = _import(capture)
    assert cameras.hints.aabb_scale == 16.0
    cameras.save(tmp_path)
    assert CameraSet.load(tmp_path).hints.aabb_scale == 16.0
    (capture / "transforms_test.json").unlink()
    (capture / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": [frame]}))
    assert _import(capture).hints.aabb_scale is None


@pytest.mark.parametrize("value", [0, -2, "16", True, None])
def test_a_bad_aabb_scale_is_refused(tmp_path, value):
    capture = temple_capture(tmp_path / "cap", 1)
    (capture / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "aabb_scale": value, "frames": [
        {"file_path": "templeSR0001.png", "transform_matrix": np.eye(4).tolist()}]}))
    with pytest.raises(InputError, match="aabb_scale is .*, not a positive number") as err:
        _import(capture)
    assert err.value.path == capture / "transforms.json"


def test_transforms_without_focal_length(tmp_path):
    capture = temple_capture(tmp_path / "cap", 1)
    (capture / "transforms.json").write_text(json.dumps(
        {"frames": [{"file_path": "templeSR0001.png", "transform_matrix": np.eye(4).tolist()}]}))
    with pytest.raises(InputError, match="has no focal length"):
        _import(capture)


def test_unparsable_transforms_json(tmp_path):
    capture = temple_capture(tmp_path / "cap", 1)
    (capture / "transforms.json").write_text('{"frames": [')
    with pytest.raises(InputError, match="is not valid JSON") as err:
        _import(capture)
    assert err.value.path == capture / "transforms.json"


def test_a_transforms_json_with_no_frames_is_one_line_naming_it(tmp_path):
    capture = temple_capture(tmp_path / "cap", 2)
    (capture / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": []}))
    with pytest.raises(InputError, match="has an empty frames list: no photo to reconstruct") as err:
        detect_layout(capture)
    assert err.value.path == capture / "transforms.json"
