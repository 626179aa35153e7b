"""RUN_DIR/exports: transforms.json round-trips through nerfpipe's own importer, the COLMAP text model
through pycolmap, and the folder is written anew with copies of the results, only inside a run directory."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from nerfpipe.export.bundle import collect, colmap_text, copy_exports, transforms_json
from nerfpipe.geometry.cameras import Camera, CameraSet, Frame
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


def test_the_colmap_text_model_reads_back_in_pycolmap(tmp_path):
    import pycolmap

    exported = cameras(shared=False)
    colmap_text(exported, tmp_path / "colmap")
    model = pycolmap.Reconstruction(str(tmp_path / "colmap"))
    assert len(model.images) == 3 and len(model.cameras) == 2 and len(model.points3D) == 0
    for image in model.images.values():
        frame = next(f for f in exported.frames if f.name == image.name)
        w2c = np.vstack([np.asarray(image.cam_from_world().matrix()), [0, 0, 0, 1]])
        assert np.abs(np.linalg.inv(w2c) - frame.c2w).max() < 1e-9
        camera = model.cameras[image.camera_id]
        assert camera.model.name == "PINHOLE" and list(camera.params) == list(exported.cameras[frame.camera_id].params)


def test_collect_copies_the_results_and_writes_the_folder_anew(tmp_path):
    ArtifactStore(tmp_path / "run").prepare()  # a run directory nerfpipe made
    results = tmp_path / "stages"
    (results / "depth").mkdir(parents=True)
    (results / "mesh.glb").write_bytes(b"glTF")
    (results / "depth" / "a.depth.npy").write_bytes(b"\0" * 8)
    images = {name: TEMPLE / name for name in NAMES}
    artifacts = {"mesh_glb": results / "mesh.glb", "depth": results / "depth", "points": None}
    (results / "mesh_watertight.ply").write_bytes(b"ply")
    first = collect(tmp_path / "run", artifacts, cameras(), images, (results / "mesh_watertight.ply",))
    folder = tmp_path / "run" / "exports"
    assert first.folder == folder and set(first.names) == {"mesh.glb", "depth", "mesh_watertight.ply",
                                                           "transforms.json", "images", "colmap"}
    assert "points.ply" in first.missing and "render.mp4" in first.missing
    assert (folder / "mesh.glb").read_bytes() == b"glTF" and (folder / "depth" / "a.depth.npy").is_file()
    # a copy: an edit of the export cannot reach the cached result through a hard link
    assert (folder / "mesh.glb").stat().st_ino != (results / "mesh.glb").stat().st_ino
    (folder / "mesh.glb").write_bytes(b"edited")
    assert (results / "mesh.glb").read_bytes() == b"glTF"
    assert sorted(p.name for p in (folder / "images").iterdir()) == list(NAMES)
    (folder / "stale.txt").write_text("from an earlier run")
    again = collect(tmp_path / "run", {"mesh_glb": results / "mesh.glb"}, None, {})
    assert again.names == ("mesh.glb",) and sorted(p.name for p in folder.iterdir()) == ["mesh.glb"]
    copied = copy_exports(folder, tmp_path / "elsewhere", tmp_path / "run")
    assert copied == 4 and (tmp_path / "elsewhere" / "mesh.glb").read_bytes() == b"glTF"
    assert (tmp_path / "elsewhere" / "mesh.glb").stat().st_ino != (results / "mesh.glb").stat().st_ino


def test_collect_writes_no_exports_into_a_folder_nerfpipe_did_not_make(tmp_path):
    (tmp_path / "docs" / "exports").mkdir(parents=True)
    (tmp_path / "docs" / "exports" / "taxes.csv").write_text("1,2")
    with pytest.raises(InputError, match="is not a folder nerfpipe made"):
        collect(tmp_path / "docs", {}, None, {})
    assert (tmp_path / "docs" / "exports" / "taxes.csv").read_text() == "1,2"
