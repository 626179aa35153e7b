"""The typed artifacts: each reads what its stage wrote and writes it back byte for byte."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from nerfpipe.artifacts import (
    Bounds,
    Decision,
    FrameBounds,
    ImageIndex,
    PhotoRecord,
    SceneDecisions,
    ViewSplit,
    frame_image_path,
    output_names,
    view_file_stem,
)
from nerfpipe.pipeline.errors import StageError


def test_output_names_keep_stems_unless_they_collide():
    assert output_names(["a.jpg", "b.PNG", "a.tif", "c.dng"]) == {
        "a.jpg": "a_jpg.png", "b.PNG": "b.png", "a.tif": "a_tif.png", "c.dng": "c.png"
    }
    assert output_names(["images/1.jpg", "images/10.jpg"]) == {"images/1.jpg": "1.png", "images/10.jpg": "10.png"}
    assert output_names(["train/r_0.png", "val/r_0.png", "images/x.jpg"]) == {
        "train/r_0.png": "train/r_0.png", "val/r_0.png": "val/r_0.png", "images/x.jpg": "images/x.png"
    }


def test_file_names_of_frames():
    assert view_file_stem("val/r_0.png") == "val__r_0"
    assert view_file_stem("a.png") == "a"
    assert frame_image_path("x/a.png", "undistort", Path("/i"), Path("/u")) == Path("/u/x/a.png")
    assert frame_image_path("a.png", "ingest", Path("/i"), Path("/u")) == Path("/i/a.png")
    with pytest.raises(ValueError, match="expected one of undistort, ingest"):
        frame_image_path("a.png", "sfm", Path("/i"), Path("/u"))


def bounds_example() -> Bounds:
    eye = [[2.0, 0.0, 0.0, 1.0], [0.0, 2.0, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    frames = (FrameBounds("a.png", 0.5, 3.0, "points"), FrameBounds("b.png", 0.25, 2.0, "rig"))
    return Bounds(eye, eye, 2.0, [0.0, 0.0, 1.0], "inward", "points", ([-1.0, -1.0, -0.5], [1.0, 1.0, 0.5]),
                  0.25, 3.0, frames)


def test_bounds_round_trip_and_accessors(tmp_path):
    bounds = bounds_example()
    bounds.save(tmp_path / "bounds.json")
    assert Bounds.load(tmp_path / "bounds.json") == bounds
    doc = json.loads((tmp_path / "bounds.json").read_text())
    assert list(doc) == ["convention", "to_world", "to_sfm", "scale", "up", "rig", "method", "scene_box", "near", "far",
                         "frames"]
    assert doc["frames"][1] == {"name": "b.png", "near": 0.25, "far": 2.0, "method": "rig"}
    lo, hi = bounds.box()
    assert lo.tolist() == [-1.0, -1.0, -0.5] and hi.tolist() == [1.0, 1.0, 0.5]
    assert bounds.near_far() == {"a.png": (0.5, 3.0), "b.png": (0.25, 2.0)}


def test_a_damaged_artifact_is_a_stage_error_naming_the_file(tmp_path):
    (tmp_path / "bounds.json").write_text('{"broken": ')
    with pytest.raises(StageError, match="bounds.json: cannot read this stage result"):
        Bounds.load(tmp_path / "bounds.json")


def test_a_user_override_replaces_the_value_and_keeps_the_evidence():
    auto = Decision.made("inward360", "cameras look at a common centre", {"ring": 4.0})
    assert auto == Decision("inward360", "cameras look at a common centre", False, {"ring": 4.0})
    forced = Decision.made("inward360", "cameras look at a common centre", {"ring": 4.0}, "forward")
    assert forced.value == "forward" and forced.overridden and forced.measured == {"ring": 4.0}
    assert forced.evidence == "cameras look at a common centre; set by the user (the data suggested inward360)"
    colour = Decision.made([0.0, 0.0, 0.0], "border", {}, [0.5, 0.5, 0.5])
    assert colour.evidence == "border; set by the user (the data suggested (0, 0, 0))"


def scene_example() -> SceneDecisions:
    return SceneDecisions(
        layout=Decision.made("inward360", "ring", {"ring": 4.0}, "forward"),
        background=Decision.made("color", "border", {"border_color": [0, 0, 0]}),
        background_color=Decision.made([0.0, 0.0, 0.0], "measured", {}),
        lens=Decision.made("pinhole", "no distortion", {}),
        photometric=Decision.made("srgb", "8-bit photos", {}),
        exposure_varies=Decision.made(False, "one exposure", {}),
        near=0.25, far=3.0, scene_box=([-1.0, -1.0, -0.5], [1.0, 1.0, 0.5]),
    )


def test_the_backdrop_is_the_colour_and_tolerance_of_a_color_background():
    scene = scene_example()
    assert scene.backdrop() is None  # a scene.json written before the tolerance was recorded: no masks
    measured = {"border_color": [0, 0, 0], "tolerance": 0.1}
    color = replace(scene, background=Decision.made("color", "border", measured))
    assert color.backdrop() == ((0.0, 0.0, 0.0), 0.1)
    # the user's colour is the backdrop's, matched with the tolerance the analysis used
    assert replace(color, background_color=Decision.made([0.0] * 3, "", {}, [0.5, 0.5, 0.5])).backdrop() == ((0.5,) * 3, 0.1)
    for other in ("alpha", "none"):
        assert replace(color, background=Decision.made(other, "border", measured)).backdrop() is None
    assert replace(color, background_color=Decision.made(None, "", {})).backdrop() is None


def test_scene_decisions_round_trip_ndc_and_describe(tmp_path):
    scene = scene_example()
    scene.save(tmp_path / "scene.json")
    assert SceneDecisions.load(tmp_path / "scene.json") == scene
    doc = json.loads((tmp_path / "scene.json").read_text())
    assert list(doc) == [*SceneDecisions.NAMES, "ndc", "near", "far", "scene_box"]
    assert doc["ndc"] is True  # the user's forward layout, not the data's inward360
    assert doc["layout"] == {"value": "forward", "evidence": scene.layout.evidence, "overridden": True,
                             "measured": {"ring": 4.0}}
    assert scene.values()["exposure_varies"] is False
    assert scene.describe() == [
        "layout is forward: ring; set by the user (the data suggested inward360)",
        "background is color: border",
        "background_color is (0, 0, 0): measured",
        "lens is pinhole: no distortion",
        "photometric is srgb: 8-bit photos",
        "exposure_varies is false: one exposure",
    ]


def test_image_index_and_view_split_round_trip(tmp_path):
    index = ImageIndex("llff", [PhotoRecord("a.png", width=4), PhotoRecord("b.png", width=8)], [{"source": "c.jpg"}])
    index.save(tmp_path / "images.json")
    assert ImageIndex.load(tmp_path / "images.json") == index
    assert index.by_name()["b.png"].width == 8
    split = ViewSplit(["a.png"], ["b.png"], "every 8th image")
    split.save(tmp_path / "views.json")
    assert ViewSplit.load(tmp_path / "views.json") == split
    assert json.loads((tmp_path / "views.json").read_text()) == {"train": ["a.png"], "heldout": ["b.png"],
                                                                 "rule": "every 8th image"}


def test_a_photo_record_round_trips_through_images_json_key_for_key(tmp_path) -> None:
    from nerfpipe.artifacts import IMAGES_JSON, ImageIndex, PhotoRecord
    from nerfpipe.pipeline.stage import StageInputs

    photo = {"name": "a.png", "source": "a.jpg", "source_sha256": "ab", "source_bytes": 10, "format": "jpeg",
             "width": 40, "height": 30, "source_width": 400, "source_height": 300, "scale": 0.1, "bit_depth": 8,
             "has_alpha": False, "mask": None, "raw": False, "linear": False, "exif": {"make": "X", "gps": None},
             "focal_prior": {"focal_px": 35.0, "source": "exif"}, "split": "train"}
    frame = {**photo, "name": "frame_0000.png", "format": "video", "focal_prior": None, "split": None,
             "video_frame": 12, "time_s": 0.4}
    index = ImageIndex("folder", [PhotoRecord.from_json(photo), PhotoRecord.from_json(frame)])
    index.save(tmp_path / "images.json")
    doc = json.loads((tmp_path / "images.json").read_text())
    assert doc["images"] == [photo, frame]  # a photo's record has no video fields: the file is as before
    loaded = StageInputs({"images_json": tmp_path / "images.json"}, tmp_path).load(IMAGES_JSON)
    assert loaded == index and loaded.by_name()["a.png"].focal_px == 35.0 and loaded.records[1].video_frame == 12
