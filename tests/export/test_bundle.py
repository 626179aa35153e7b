"""RUN_DIR/exports: transforms.json round-trips through nerfpipe's own importer and carries nerfstudio's optional
fields, the COLMAP model reads back in pycolmap with its points, the depth maps turn into the SfM frame, and the
folder is written anew with copies of the results, only inside a run directory."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from nerfpipe.export.bundle import CapturedViews, collect, colmap_model, copy_exports, transforms_json
from nerfpipe.export.depth import DepthIndex, DepthView, decode_depth_png, depth_in_frame, write_view
from nerfpipe.geometry.cameras import Camera, CameraSet, Frame, Points
from nerfpipe.pipeline import ArtifactStore, InputError
from nerfpipe.poses.importers import import_poses
from nerfpipe.poses.layout import detect_layout
from tests.helpers import TEMPLE, look_at
from tests.poses.test_importers import fake_records

NAMES = ("templeSR0001.png", "templeSR0002.png", "templeSR0003.png")


def cameras(shared: bool = True) -> CameraSet:
    """Three cameras round the origin in some SfM frame (not normalized: 7 units away), 640x480 photos."""
    table = {1: Camera.pinhole(1520.4, 1525.9, 302.32, 246.87, 640, 480)}
    if not shared:
        table[2] = Camera.pinhole(1400.0, 1400.0, 320.0, 240.0, 640, 480)
    frames = [Frame(name, 1 if shared or i != 2 else 2, look_at(np.array([7 * np.cos(a), 7 * np.sin(a), 1.5]),
                                                               np.array([0.1, 0.0, 0.2])))
              for i, (name, a) in enumerate(zip(NAMES, (0.0, 0.7, 1.9)))]
    return CameraSet(table, frames)


@pytest.mark.parametrize("shared", [True, False])
def test_transforms_json_round_trips_through_the_importer(tmp_path, shared):
    capture = tmp_path / "capture"
    (capture / "images").mkdir(parents=True)
    for name in NAMES:
        shutil.copy(TEMPLE / name, capture / "images" / name)
    exported = cameras(shared)
    doc = transforms_json(exported, {n: f"images/{n}" for n in NAMES})
    (capture / "transforms.json").write_text(json.dumps(doc))
    assert ("fl_x" in doc) == shared and ("fl_x" in doc["frames"][0]) != shared
    layout = detect_layout(capture)
    imported = import_poses(layout, fake_records(layout))
    assert [f.name for f in imported.frames] == list(NAMES)
    for frame, original in zip(imported.frames, exported.frames):
        assert np.abs(frame.c2w - original.c2w).max() < 1e-6
        camera, before = imported.camera_of(frame), exported.camera_of(original)
        assert np.allclose([camera.fx, camera.fy, camera.cx, camera.cy], [before.fx, before.fy, before.cx, before.cy],
                           atol=1e-6)
    # OpenGL axes: the camera's +z (its back) points away from what it looks at
    gl = np.array(doc["frames"][0]["transform_matrix"])
    assert np.allclose(gl[:3, 2], -exported.frames[0].c2w[:3, 2]) and np.allclose(gl[:3, 0], exported.frames[0].c2w[:3, 0])


def test_the_colmap_model_reads_back_in_pycolmap_with_its_points(tmp_path):
    import pycolmap

    exported = cameras(shared=False)
    points = Points(np.array([[0.1, 0.2, 0.3], [-1.0, 0.5, 2.0]]), np.array([[255, 0, 10], [1, 2, 3]], np.uint8),
                    np.zeros(2))
    colmap_model(exported, points, tmp_path / "sparse" / "0")
    assert {p.name for p in (tmp_path / "sparse" / "0").iterdir()} >= {"cameras.bin", "images.bin", "points3D.bin",
                                                                        "cameras.txt", "images.txt", "points3D.txt"}
    for kind in ("bin", "txt"):
        model = pycolmap.Reconstruction()
        (model.read_binary if kind == "bin" else model.read_text)(str(tmp_path / "sparse" / "0"))
        assert len(model.images) == 3 and len(model.cameras) == 2 and len(model.points3D) == 2
        for image in model.images.values():
            frame = next(f for f in exported.frames if f.name == image.name)
            w2c = np.vstack([np.asarray(image.cam_from_world().matrix()), [0, 0, 0, 1]])
            assert np.abs(np.linalg.inv(w2c) - frame.c2w).max() < 1e-9
            camera = model.cameras[image.camera_id]
            assert camera.model.name == "PINHOLE" and list(camera.params) == list(exported.cameras[frame.camera_id].params)
        read = sorted((tuple(p.xyz), tuple(p.color)) for p in model.points3D.values())
        assert read == sorted((tuple(x), tuple(c)) for x, c in zip(points.xyz, points.rgb))


def test_collect_copies_the_results_and_writes_the_folder_anew(tmp_path):
    ArtifactStore(tmp_path / "run").prepare()  # a run directory nerfpipe made
    results = tmp_path / "stages"
    (results / "depth").mkdir(parents=True)
    (results / "mesh.glb").write_bytes(b"glTF")
    (results / "depth" / "a.depth.npy").write_bytes(b"\0" * 8)
    images = {name: TEMPLE / name for name in NAMES}
    artifacts = {"mesh_glb": results / "mesh.glb", "depth": results / "depth", "points": None}
    (results / "mesh_watertight.ply").write_bytes(b"ply")
    first = collect(tmp_path / "run", artifacts, CapturedViews(cameras(), images), (results / "mesh_watertight.ply",))
    folder = tmp_path / "run" / "exports"
    assert first.folder == folder and set(first.names) == {"mesh.glb", "depth", "mesh_watertight.ply",
                                                           "transforms.json", "images", "sparse"}
    assert "points.ply" in first.missing and "render.mp4" in first.missing
    assert (folder / "mesh.glb").read_bytes() == b"glTF" and (folder / "depth" / "a.depth.npy").is_file()
    # a copy: an edit of the export cannot reach the cached result through a hard link
    assert (folder / "mesh.glb").stat().st_ino != (results / "mesh.glb").stat().st_ino
    (folder / "mesh.glb").write_bytes(b"edited")
    assert (results / "mesh.glb").read_bytes() == b"glTF"
    assert sorted(p.name for p in (folder / "images").iterdir()) == list(NAMES)
    (folder / "stale.txt").write_text("from an earlier run")
    again = collect(tmp_path / "run", {"mesh_glb": results / "mesh.glb"}, None)
    assert again.names == ("mesh.glb",) and sorted(p.name for p in folder.iterdir()) == ["mesh.glb"]
    copied = copy_exports(folder, tmp_path / "elsewhere", tmp_path / "run")
    assert copied == 4 and (tmp_path / "elsewhere" / "mesh.glb").read_bytes() == b"glTF"
    assert (tmp_path / "elsewhere" / "mesh.glb").stat().st_ino != (results / "mesh.glb").stat().st_ino


TO_SFM = np.array([[0.0, -2.0, 0.0, 1.0], [2.0, 0.0, 0.0, -3.0], [0.0, 0.0, 2.0, 0.5], [0.0, 0.0, 0.0, 1.0]])  # s = 2


def depth_maps(folder, names) -> DepthIndex:
    """export_depth's files for ``names``: 8x6 views of a plane at depth 1.5 (normalized world)."""
    folder.mkdir(parents=True)
    views = [DepthView(name, f"{i:04d}", "heldout" if i == 2 else "train", 8, 6, (8.0, 8.0, 4.0, 3.0),
                       tuple(map(tuple, np.eye(4).tolist())), 0.5, 3.0) for i, name in enumerate(names)]
    depth = np.full((6, 8), 1.5, np.float32)
    for view in views:
        rendered = {"depth": depth, "acc": np.ones_like(depth), "disparity": 1 / depth, "rgb": np.zeros((6, 8, 3))}
        write_view(folder, view, rendered, 1000.0, 0.5, TO_SFM.tolist())
    return DepthIndex(views, 1000.0, TO_SFM.tolist(), 0.5)


def test_depth_maps_turn_into_the_sfm_frame(tmp_path):
    import cv2

    index = depth_maps(tmp_path / "depth", NAMES)
    factor = depth_in_frame(tmp_path / "depth", index)
    assert factor == pytest.approx(2.0 / 1000.0)
    assert np.allclose(np.load(tmp_path / "depth" / "0000.depth.npy"), 3.0)  # 1.5 x 2
    assert np.allclose(np.load(tmp_path / "depth" / "0000.disparity.npy"), 1 / 3.0)
    sidecar = json.loads((tmp_path / "depth" / "0000.depth.json").read_text())
    counts = cv2.imread(str(tmp_path / "depth" / "0000.depth.png"), cv2.IMREAD_ANYDEPTH)
    assert np.allclose(decode_depth_png(counts, sidecar["scale"]), 3.0) and "SfM" in sidecar["units"]
    assert np.allclose(counts * factor, 3.0)  # nerfstudio's depth_unit_scale_factor
    moved = DepthIndex.load(tmp_path / "depth" / "index.json")
    assert moved.views[0].near == pytest.approx(1.0) and moved.views[0].far == pytest.approx(6.0)
    assert np.allclose(np.asarray(moved.views[0].c2w)[:3, 3], TO_SFM[:3, 3])  # the camera at the origin, moved


def test_transforms_json_carries_nerfstudios_optional_fields(tmp_path):
    import cv2

    from nerfpipe.export.points import read_ply

    ArtifactStore(tmp_path / "run").prepare()
    index = depth_maps(tmp_path / "stages" / "depth", NAMES)
    (tmp_path / "masks").mkdir()
    for name in NAMES:  # as the train stage writes them: one channel, 255 on the subject
        cv2.imwrite(str(tmp_path / "masks" / name), np.pad(np.full((2, 2), 255, np.uint8), 2)[:6, :8])
    masks = {name: tmp_path / "masks" / name for name in NAMES}
    points = Points(np.array([[0.1, 0.2, 0.3], [1.0, 2.0, 3.0]]), np.array([[255, 0, 0], [0, 0, 255]], np.uint8),
                    np.zeros(2))
    views = CapturedViews(cameras(), {n: TEMPLE / n for n in NAMES}, points, masks, (NAMES[2],), index)
    exported = collect(tmp_path / "run", {"depth": tmp_path / "stages" / "depth"}, views)
    folder = exported.folder
    assert {"masks", "sparse_pc.ply", "sparse"} <= set(exported.names)
    doc = json.loads((folder / "transforms.json").read_text())
    assert doc["ply_file_path"] == "sparse_pc.ply" and np.allclose(read_ply(folder / "sparse_pc.ply").xyz, points.xyz)
    assert doc["train_filenames"] == [f"images/{n}" for n in NAMES[:2]]
    assert doc["val_filenames"] == doc["test_filenames"] == [f"images/{NAMES[2]}"]
    assert doc["depth_unit_scale_factor"] == pytest.approx(0.002)
    check_nerfstudio_fields(folder, doc)
    for i, frame in enumerate(doc["frames"]):
        assert frame["depth_file_path"] == f"depth/{i:04d}.depth.png"
        mask = cv2.imread(str(folder / frame["mask_path"]), cv2.IMREAD_UNCHANGED)
        assert set(np.unique(mask)) == {0, 255}
    # the stage's own depth maps stay in the normalized world
    assert np.allclose(np.load(tmp_path / "stages" / "depth" / "0000.depth.npy"), 1.5)
    assert np.allclose(np.load(folder / "depth" / "0000.depth.npy"), 3.0)
    # a mask missing for one frame: none at all (nerfstudio takes them for every frame or none)
    del masks[NAMES[1]]
    doc = json.loads((collect(tmp_path / "run", {}, views).folder / "transforms.json").read_text())
    assert all("mask_path" not in f and "depth_file_path" not in f for f in doc["frames"])
    assert "depth_unit_scale_factor" not in doc
    check_nerfstudio_fields(tmp_path / "run" / "exports", doc)


def test_collect_writes_no_exports_into_a_folder_nerfpipe_did_not_make(tmp_path):
    (tmp_path / "docs" / "exports").mkdir(parents=True)
    (tmp_path / "docs" / "exports" / "taxes.csv").write_text("1,2")
    with pytest.raises(InputError, match="is not a folder nerfpipe made"):
        collect(tmp_path / "docs", {}, None, {})
    assert (tmp_path / "docs" / "exports" / "taxes.csv").read_text() == "1,2"


def check_nerfstudio_fields(folder, doc) -> None:
    """What nerfstudio's own dataparser (nerfstudio/data/dataparsers/nerfstudio_dataparser.py) asks of a
    transforms.json: shared or per-frame intrinsics; mask_path and depth_file_path on every frame or on
    none; split lists naming frames' file_path, for train and for the evaluation split (val or test) alike;
    the files there, masks of one 8-bit channel, depth as 16-bit PNG; ply_file_path a point cloud Open3D
    reads."""
    import cv2
    import open3d as o3d

    keys = ("fl_x", "fl_y", "cx", "cy", "h", "w")
    for frame in doc["frames"]:
        assert all(k in doc or k in frame for k in keys) and (folder / frame["file_path"]).is_file()
        assert np.asarray(frame["transform_matrix"]).shape == (4, 4)
    assert doc.get("camera_model", "OPENCV") in ("OPENCV", "PINHOLE", "OPENCV_FISHEYE", "EQUIRECTANGULAR")
    for key in ("mask_path", "depth_file_path"):
        assert sum(key in f for f in doc["frames"]) in (0, len(doc["frames"]))
    files = {f["file_path"] for f in doc["frames"]}
    if any(f"{s}_filenames" in doc for s in ("train", "val", "test")):
        assert set(doc["train_filenames"]) <= files and set(doc["val_filenames"]) <= files
        assert set(doc["test_filenames"]) == set(doc["val_filenames"])
    for frame in doc["frames"]:
        if "mask_path" in frame:
            mask = cv2.imread(str(folder / frame["mask_path"]), cv2.IMREAD_UNCHANGED)
            assert mask.dtype == np.uint8 and mask.ndim == 2
        if "depth_file_path" in frame:
            assert cv2.imread(str(folder / frame["depth_file_path"]), cv2.IMREAD_ANYDEPTH).dtype == np.uint16
    if "ply_file_path" in doc:
        assert len(o3d.io.read_point_cloud(str(folder / doc["ply_file_path"])).points) > 0
