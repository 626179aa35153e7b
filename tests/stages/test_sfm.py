"""The sfm stage: real COLMAP SfM on real photos, matcher choice, priors, and the failures users hit."""

from __future__ import annotations

import itertools
import json
import shutil
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
import pytest

from nerfpipe.artifacts import ImageIndex, PhotoRecord
from nerfpipe import Pipeline
from nerfpipe.geometry.align import rotation_angle_deg, umeyama
from nerfpipe.geometry.cameras import CameraSet, invert_pose
from nerfpipe.poses.colmap.matching import choose_matcher
from nerfpipe.stages import IngestStage, SfmStage
from nerfpipe.stages.sfm import SfmParams
from tests.helpers import TEMPLE, count_progress, run_cli, shared
from tests.imaging import photos


def read_par(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Middlebury ``*_par.txt``: name -> (K, c2w in OpenCV convention), from P = K [R | t]."""
    cameras = {}
    for line in path.read_text().splitlines()[1:]:
        fields = line.split()
        values = np.array(fields[1:], dtype=np.float64)
        K, R, t = values[:9].reshape(3, 3), values[9:18].reshape(3, 3), values[18:21]
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = R, t
        cameras[fields[0]] = (K, invert_pose(w2c))
    return cameras


def sfm_pipeline(capture: Path, run_dir: Path, progress=None, **sfm) -> Pipeline:
    overrides = {"sfm": {"poses": "sfm", **sfm}}
    return Pipeline([IngestStage(), SfmStage()], capture, run_dir, overrides=overrides,
                    **({"progress": progress} if progress else {}))


@pytest.mark.slow
@pytest.mark.parametrize("mapper", ["incremental", "global"])
def test_temple_registers_all_16_and_matches_the_calibration(tmp_path, mapper):
    """Acceptance: images only (poses ignored); after a similarity alignment to templeSR_par.txt the median
    rotation error is <= 1 degree and the median position error <= 2 % of the ring's diameter."""
    calls: list = []
    outcome = sfm_pipeline(TEMPLE, tmp_path / "run", count_progress(calls), mapper=mapper).run(until="sfm")[-1]
    assert outcome.summary["method"] == f"colmap {mapper}"
    # progress: features, matches, and (incremental mapping) each photo as it is registered
    # (a relaxed retry, when the first mapping left a photo out, gets a bar of its own)
    bar = calls.index((18, "sfm"))
    steps = list(itertools.takewhile(lambda c: isinstance(c, int), calls[bar + 1:]))
    if mapper == "incremental":
        assert 2 + 10 <= sum(steps) <= 18, calls
    else:
        assert sum(steps) == 2, calls
    assert outcome.summary["registered"] == 16 and outcome.summary["total"] == 16
    cameras = CameraSet.load(outcome.path / "model")
    truth = read_par(TEMPLE / "templeSR_par.txt")
    names = [f.name for f in cameras.frames]
    est = np.array([f.center for f in cameras.frames])
    gt = np.array([truth[n][1][:3, 3] for n in names])
    s, R, t = umeyama(est, gt)
    position_error = np.linalg.norm(est @ (s * R).T + t - gt, axis=1)
    diameter = max(np.linalg.norm(a - b) for a in gt for b in gt)
    rotation_error = [rotation_angle_deg(truth[f.name][1][:3, :3].T @ R @ f.c2w[:3, :3]) for f in cameras.frames]
    print(f"temple ({mapper}): median rotation error {np.median(rotation_error):.3f} deg, median position error "
          f"{100 * np.median(position_error) / diameter:.3f} % of the ring diameter")
    assert np.median(rotation_error) <= 1.0
    assert np.median(position_error) <= 0.02 * diameter
    # the estimated focal length agrees with the calibration (1520.4 / 1525.9 px)
    assert abs(cameras.cameras[cameras.frames[0].camera_id].fx - 1523) < 0.03 * 1523
    # COLMAP's log went to the stage folder, the kept model was written for other tools
    assert (outcome.path / "colmap.log").stat().st_size > 1000
    assert (outcome.path / "colmap" / "images.bin").is_file()
    assert cameras.points is not None and len(cameras.points.visible) == 16
    assert all(len(v) > 20 for v in cameras.points.visible)


def records(n: int, gps: bool = False, names: str = "IMG_{:04d}.jpg") -> list[PhotoRecord]:
    return [PhotoRecord(names.format(3 * i + 7), width=640, height=480,
                        exif={"gps": [48.0, 2.0, 30.0] if gps else None}) for i in range(n)]


def test_matcher_choice():
    params = SfmParams()
    assert choose_matcher(records(40), params)[0] == "exhaustive"
    assert choose_matcher(records(300, gps=True), params) == ("spatial", "300 of 300 photos carry GPS")
    assert choose_matcher(records(300, names="frame_{:05d}.png"), params)[0] == "exhaustive"  # step 3: not frames
    video = [PhotoRecord(f"{i:04d}.jpg") for i in range(300)]
    assert choose_matcher(video, params) == ("sequential", "300 photos named as numbered frames")
    assert choose_matcher(records(40), SfmParams(matcher="sequential")) == ("sequential", "set by sfm.matcher")
    assert choose_matcher(records(300), SfmParams(exhaustive_max=500))[0] == "exhaustive"


def test_exif_focal_prior_and_gps_reach_colmap(tmp_path):
    """JPEGs with a 35 mm focal length and GPS: COLMAP's camera starts from the prior, and spatial
    matching pairs the photos by their positions."""
    import pycolmap

    from nerfpipe.poses.colmap.mapping import single_camera, write_priors
    from nerfpipe.poses.colmap.matching import match_features

    folder = tmp_path / "photos"
    folder.mkdir()
    for i in (1, 2, 3, 4):
        image = cv2.imread(str(TEMPLE / f"templeSR000{i}.png"))
        exif = photos.exif({0x010F: "Acme", 0x0110: "Z1"}, {0xA405: 83},
                           {0x0001: "N", 0x0002: (Fraction(48), Fraction(51), Fraction(i)),
                            0x0003: "E", 0x0004: (Fraction(2), Fraction(17), Fraction(40))})
        (folder / f"t{i}.jpg").write_bytes(photos.jpeg(image[:, :, ::-1], exif, quality=95))
    ingest = Pipeline([IngestStage()], folder, tmp_path / "run").run()[0]
    recs = ImageIndex.load(ingest.path / "images.json").records
    assert single_camera(recs)

    database = tmp_path / "database.db"
    pycolmap.Database.open(database).close()
    reader = pycolmap.ImageReaderOptions()
    pycolmap.extract_features(database, ingest.path / "images", [r.name for r in recs],
                              pycolmap.CameraMode.SINGLE, reader, device=pycolmap.Device.cpu)
    assert write_priors(database, recs, single=True) == 4
    match_features(database, "spatial", SfmParams())
    with pycolmap.Database.open(database) as db:
        camera = db.read_all_cameras()[0]
        assert camera.has_prior_focal_length
        assert camera.params[0] == pytest.approx(83 / 35 * 640)  # COLMAP's 35 mm rule at 640 px
        # COLMAP numbers the images in the order its threads finish them: find each photo's prior by its id.
        names = {image.image_id: image.name for image in db.read_all_images()}
        priors = {names[p.corr_data_id.id]: p.position[:2] for p in db.read_all_pose_priors()}
        assert sorted(priors) == ["t1.png", "t2.png", "t3.png", "t4.png"]
        for i in (1, 2, 3, 4):
            assert np.allclose(priors[f"t{i}.png"], [48 + 51 / 60 + i / 3600, 2 + 17 / 60 + 40 / 3600])
        assert db.num_matched_image_pairs() > 0


def test_two_photos_are_refused_with_advice(tmp_path):
    folder = tmp_path / "two"
    folder.mkdir()
    for i in (1, 2):
        shutil.copy(TEMPLE / f"templeSR000{i}.png", folder)
    result = run_cli("run", folder, "--out", tmp_path / "run", "--until", "sfm")
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert "only 2 photos to reconstruct; SfM needs at least 3" in result.stderr


def test_textureless_photos_fail_clearly(tmp_path):
    folder = tmp_path / "flat"
    folder.mkdir()
    for i in range(5):
        gradient = np.tile(np.linspace(40 + 10 * i, 200, 320, dtype=np.float32), (240, 1))
        cv2.imwrite(str(folder / f"wall{i}.png"), np.dstack([gradient] * 3).astype(np.uint8))
    result = run_cli("run", folder, "--out", tmp_path / "run", "--until", "sfm")
    assert result.returncode == 1 and "Traceback" not in result.stderr
    line = [l for l in result.stderr.splitlines() if l.startswith("error:")]
    assert len(line) == 1 and "SfM registered only 0 of 5 photos" in line[0] and "Try:" in line[0]
    assert "I20" not in result.stderr  # COLMAP's own log lines stay out of the terminal
    assert not list((tmp_path / "run" / "stages" / "sfm").glob("*/manifest.json"))


# -- imported poses: points triangulated with the poses fixed --------------------------------------------

# templeSparseRing/README.txt: "The (tight) bounding box for the templeSparseRing model"
TEMPLE_BOX = np.array([[-0.073568, 0.021728, -0.012445], [0.028855, 0.181892, 0.062736]])


def to_bounds(capture: Path, run_dir: Path, **overrides) -> list:
    from nerfpipe.stages import BoundsStage, UndistortStage

    return Pipeline([IngestStage(), SfmStage(), UndistortStage(), BoundsStage()], capture, run_dir,
                    overrides=overrides).run()


def box_in_sfm_frame(bounds) -> np.ndarray:
    """(2, 3) axis-aligned box, in the SfM (pose file) frame, around the bounds stage's scene box."""
    lo, hi = map(np.array, bounds.scene_box)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    to_sfm = np.array(bounds.to_sfm)
    corners = corners @ to_sfm[:3, :3].T + to_sfm[:3, 3]
    return np.array([corners.min(axis=0), corners.max(axis=0)])


@pytest.mark.slow
def test_temple_par_file_gets_triangulated_points_and_its_tight_box(tmp_path):
    """The Middlebury temple comes with poses and no points: triangulated with the poses fixed, the points give
    the bounds stage a scene box that holds the published tight box with at most 2.5 cm to spare (16 % of the
    temple's 16 cm height), where the rig guess made a 57 cm cube."""
    from nerfpipe.artifacts import Bounds

    outcomes = to_bounds(TEMPLE, tmp_path / "run")
    sfm = outcomes[1].summary
    assert sfm["method"] == "imported middlebury" and sfm["points_from"] == "triangulated"
    assert sfm["triangulation"]["status"] == "ok" and sfm["triangulation"]["matcher"] == "exhaustive"
    assert sfm["points"] == sfm["triangulation"]["points"] > 1000
    # the lab's calibration reprojects within SIFT's noise: bundle adjustment's is not kept
    assert sfm["triangulation"]["bundle_adjustment"]["kept"] is False
    (camera,) = CameraSet.load(outcomes[1].path / "model").cameras.values()
    assert camera.model == "PINHOLE" and np.allclose(camera.params, (1520.4, 1525.9, 302.32, 246.87))
    assert sfm["triangulation"]["max_pose_change"] < 1e-9  # the poses were held fixed
    assert sfm["triangulation_fallback"] is None
    # COLMAP's database and log stay in a scratch folder: the result is the same on every run
    assert sorted(p.name for p in outcomes[1].path.iterdir()) == ["manifest.json", "model"]
    cameras = CameraSet.load(outcomes[1].path / "model")
    truth = read_par(TEMPLE / "templeSR_par.txt")
    assert all(np.allclose(f.c2w, truth[f.name][1], atol=1e-9) for f in cameras.frames)  # the imported poses
    assert len(cameras.points.visible) == 16 and all(len(v) > 50 for v in cameras.points.visible)
    assert SfmStage().describe(outcomes[1].path, {"summary": sfm})[0].startswith(
        f"imported middlebury: 16/16 photos registered, {sfm['points']} points triangulated with the poses fixed")

    bounds = Bounds.load(outcomes[-1].path / "bounds.json")
    assert bounds.method == "points" and all(f.method == "points" for f in bounds.frames)
    box = box_in_sfm_frame(bounds)
    print(f"temple: triangulated scene box {box.round(4).tolist()} vs the tight box {TEMPLE_BOX.tolist()}")
    # the points' box grown by 10 % of its extent a side (bounds.box_margin) holds the whole temple, with at most
    # 2.5 cm to spare on any side; the points' own box is within 1.5 cm of the tight box, but cuts 1 cm off its top
    assert np.all(box[0] <= TEMPLE_BOX[0]) and np.all(box[1] >= TEMPLE_BOX[1])
    assert np.abs(box - TEMPLE_BOX).max() < 0.025

    # the same parameters again: nothing reruns; sfm.triangulate=false is a new key and today's rig guess
    assert [o.action for o in to_bounds(TEMPLE, tmp_path / "run")] == ["cached"] * 4
    rig = to_bounds(TEMPLE, tmp_path / "run", sfm={"triangulate": "false"})
    assert rig[1].action == "ran" and any("sfm.triangulate auto -> false" in r for r in rig[1].reasons)
    assert rig[1].summary["points_from"] == "none" and rig[1].summary["triangulation"] is None
    assert Bounds.load(rig[-1].path / "bounds.json").method == "rig"


def test_llff_poses_get_triangulated_points_and_a_box_the_size_of_the_object(tmp_path):
    """The LLFF cup: its poses_bounds.npy has near/far and no points. By default its points are triangulated
    with the poses fixed, and the scene box they give is the object's, about the cameras' distance from the
    centre a side; the box of the file's near/far frusta is 3-5 times that (320 px photos, 4 s)."""
    from nerfpipe.artifacts import Bounds

    cup = shared("llff_cup_kwrous")
    ingest = {"max_size": "320"}
    auto = to_bounds(cup, tmp_path / "run", ingest=ingest)
    s = auto[1].summary
    assert s["points_from"] == "triangulated" and s["triangulation"]["max_pose_change"] < 1e-9
    assert s["points"] > 1000 and s["triangulation"]["mean_reprojection_error_px"] < 2.0
    # the file's pinhole left out the lens: adjusted, the points reproject well over a fifth closer, through a
    # radial camera whose k1 bends the photos' corners inwards (barrel distortion)
    adjusted = s["triangulation"]["bundle_adjustment"]
    assert adjusted["kept"] and adjusted["after_px"] < 0.7 * adjusted["before_px"]
    (camera,) = CameraSet.load(auto[1].path / "model").cameras.values()
    assert camera.model == "SIMPLE_RADIAL" and -0.05 < camera.params[3] < -0.005
    near_far = to_bounds(cup, tmp_path / "run", ingest=ingest, sfm={"triangulate": "false"})
    sizes = {}
    for name, outcomes in (("points", auto), ("pose_file", near_far)):
        bounds = Bounds.load(outcomes[-1].path / "bounds.json")
        assert bounds.method == name
        world = CameraSet.load(outcomes[-1].path / "world")
        radius = float(np.median(np.linalg.norm(np.asarray(world.centers()), axis=1)))
        lo, hi = np.asarray(bounds.scene_box)
        sizes[name] = (hi - lo) / radius  # the box a side, in the cameras' distances from the centre
    print("cup scene box in camera distances:", {k: v.round(2).tolist() for k, v in sizes.items()})
    assert np.all(sizes["points"] < 2.0) and np.all(sizes["pose_file"] > 2.0 * sizes["points"])


def flat_capture(folder: Path, n: int = 4) -> Path:
    """``n`` textureless photos around the origin with a transforms.json carrying instant-ngp's aabb_scale."""
    from tests.helpers import look_at

    folder.mkdir()
    frames = []
    for i in range(n):
        gradient = np.tile(np.linspace(40 + 10 * i, 200, 320, dtype=np.float32), (240, 1))
        cv2.imwrite(str(folder / f"wall{i}.png"), np.dstack([gradient] * 3).astype(np.uint8))
        eye = np.array([4.0 * np.cos(i), 4.0 * np.sin(i), 1.0])
        c2w_gl = look_at(eye, np.zeros(3)) @ np.diag([1.0, -1.0, -1.0, 1.0])
        frames.append({"file_path": f"wall{i}.png", "transform_matrix": c2w_gl.tolist()})
    (folder / "transforms.json").write_text(json.dumps({"camera_angle_x": 0.8, "aabb_scale": 16, "frames": frames}))
    return folder


def test_a_failed_triangulation_falls_back_to_the_rig_and_says_so(tmp_path, caplog, monkeypatch):
    import logging

    import pycolmap

    def fail(*args, **kwargs):
        raise RuntimeError("Check failed: database_cache_->NumImages() > 0 No images with matches found")

    monkeypatch.setattr(pycolmap, "triangulate_points", fail)
    capture = flat_capture(tmp_path / "flat")
    with caplog.at_level(logging.INFO, logger="nerfpipe"):
        outcome = Pipeline([IngestStage(), SfmStage()], capture, tmp_path / "run").run()[-1]
    s = outcome.summary
    assert s["triangulation"]["status"] == "failed" and s["points_from"] == "none" and s["points"] == 0
    assert s["triangulation_fallback"].startswith("triangulation failed (RuntimeError: Check failed: ")
    assert s["triangulation_fallback"].endswith("; bounds fall back to the rig guess")
    assert f"sfm: {s['triangulation_fallback']}" in [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert CameraSet.load(outcome.path / "model").points is None
    assert not (outcome.path / "colmap.log").exists()  # COLMAP's log has timestamps: equal runs, equal results
    # instant-ngp's aabb_scale: kept for later stages, and a hint in the summary
    assert CameraSet.load(outcome.path / "model").hints.aabb_scale == 16.0 and s["aabb_scale"] == 16.0
    lines = SfmStage().describe(outcome.path, {"summary": s})
    assert lines[0] == "imported transforms: 4/4 photos registered, no sparse points"
    assert lines[1] == f"warning: {s['triangulation_fallback']}"
    assert lines[2].startswith("hint: instant-ngp aabb_scale 16: the scene extends 16x the cameras' unit cube")


def test_textureless_photos_triangulate_nothing_and_fall_back(tmp_path):
    outcome = Pipeline([IngestStage(), SfmStage()], flat_capture(tmp_path / "flat"), tmp_path / "run").run()[-1]
    s = outcome.summary
    # COLMAP either refuses a database without matches or triangulates nothing: both fall back
    assert s["triangulation"]["status"] in ("failed", "too_few") and s["points"] == 0
    assert s["triangulation_fallback"].endswith("; bounds fall back to the rig guess")
    assert CameraSet.load(outcome.path / "model").points is None


def test_too_few_triangulated_points_fall_back_and_spatial_matching_uses_the_known_positions(tmp_path):
    """Four neighbouring temple photos (7-10, 22° apart on the ring) matched by their known camera positions
    (no GPS anywhere): points come out, but fewer than asked for, so none are kept and the bounds come from
    the rig."""
    from nerfpipe.artifacts import Bounds

    capture = tmp_path / "temple4"
    capture.mkdir()
    lines = (TEMPLE / "templeSR_par.txt").read_text().splitlines()[7:11]
    for line in lines:
        shutil.copy(TEMPLE / line.split()[0], capture)
    (capture / "t_par.txt").write_text("\n".join(["4", *lines]) + "\n")
    outcomes = to_bounds(capture, tmp_path / "run", sfm={"matcher": "spatial", "min_triangulated_points": 100000})
    t = outcomes[1].summary["triangulation"]
    assert t["matcher"] == "spatial" and t["matcher_reason"] == "set by sfm.matcher: each photo with its 10 nearest cameras"
    assert t["status"] == "too_few" and 0 < t["points"] < 100000
    assert outcomes[1].summary["triangulation_fallback"] == (
        f"triangulation kept only {t['points']} points (< sfm.min_triangulated_points 100000); "
        "bounds fall back to the rig guess")
    assert CameraSet.load(outcomes[1].path / "model").points is None
    assert Bounds.load(outcomes[-1].path / "bounds.json").method == "rig"


def test_triangulation_matcher_choice():
    from nerfpipe.poses.colmap.triangulate import choose_triangulation_matcher

    params = SfmParams()  # 10 nearest cameras
    assert choose_triangulation_matcher(records(20), params) == (
        "exhaustive", "20 photos <= 2 x sfm.spatial_neighbors 10")
    assert choose_triangulation_matcher(records(77), params) == (  # bundle adjustment to follow: all pairs
        "exhaustive", "77 photos <= sfm.exhaustive_max 100: all pairs, which tie the poses together for bundle adjustment")
    assert choose_triangulation_matcher(records(77), SfmParams(bundle_adjust="off")) == (
        "spatial", "77 known poses: each photo with its 10 nearest cameras")
    assert choose_triangulation_matcher(records(101), params) == (
        "spatial", "101 known poses: each photo with its 10 nearest cameras")
    video = [PhotoRecord(f"{i:04d}.jpg") for i in range(300)]
    assert choose_triangulation_matcher(video, params)[0] == "spatial"  # the poses say more than the frame order
    assert choose_triangulation_matcher(records(40), SfmParams(matcher="spatial", spatial_neighbors=5)) == (
        "spatial", "set by sfm.matcher: each photo with its 5 nearest cameras")
    assert choose_triangulation_matcher(video, SfmParams(matcher="exhaustive")) == ("exhaustive", "set by sfm.matcher")
    assert choose_triangulation_matcher(video, SfmParams(matcher="sequential"))[0] == "sequential"
    with pytest.raises(ValueError, match="spatial_neighbors"):
        SfmParams(spatial_neighbors=0)
    with pytest.raises(ValueError, match="min_triangulated_points"):
        SfmParams(min_triangulated_points=0)


def bounds_figures(outcome) -> dict[str, np.ndarray]:
    """Median near and far over the images and the scene box's extent per axis, in SfM units."""
    from nerfpipe.artifacts import Bounds

    bounds = Bounds.load(outcome.path / "bounds.json")
    lo, hi = map(np.array, bounds.scene_box)
    return {"near": np.median([f.near for f in bounds.frames]) / bounds.scale,
            "far": np.median([f.far for f in bounds.frames]) / bounds.scale,
            "extent": (hi - lo) / bounds.scale}


@pytest.mark.slow
def test_beer_triangulated_with_its_own_poses_gives_the_bounds_of_its_own_points(tmp_path):
    """The Beer capture's COLMAP model (71 phone frames, 4414 points), its points ignored and triangulated
    again with its poses fixed: near/far (medians over the images) and the scene box's extent per axis
    agree with those of the model's own points (640 px frames, sequential matching of the video frames: under
    a minute on 2 cores): near/far and the vertical extent within 10 %, the horizontal extents within 15 %.

    Near/far and the vertical extent agree within 4 % at every size and matcher tried. The horizontal
    extents are fragile: the bounds stage's robust box ends in the sparse tail of this capture's background
    points, where it moves by up to 13 % when a random 10 % of the model's own points is left out, and
    triangulations at 960 px or full size, or with exhaustive matching, land 12-58 % off on x or y. COLMAP's
    threaded matching does not repeat itself run to run either (2611-2656 points, y off by 6-10 % in five
    runs), so x and y are held to the box estimator's own spread, 15 %, and a failure of that assertion
    after a COLMAP upgrade says more about the box estimator than about the triangulation."""
    beer = shared("colmap_beer_yhuoyuh")
    run_dir = tmp_path / "run"
    ingest, sfm = {"max_size": "640"}, {"matcher": "sequential"}
    own = to_bounds(beer, run_dir, ingest=ingest, sfm={**sfm, "triangulate": "false"})
    assert own[1].summary["points_from"] == "pose file" and own[1].summary["points"] == 4414
    ours = to_bounds(beer, run_dir, ingest=ingest, sfm={**sfm, "triangulate": "true"})
    s = ours[1].summary
    assert s["points_from"] == "triangulated" and s["triangulation"]["max_pose_change"] < 1e-9
    assert s["points"] > 2000 and s["triangulation"]["matcher"] == "sequential"
    reference, triangulated = bounds_figures(own[-1]), bounds_figures(ours[-1])
    error = {k: np.abs(triangulated[k] / reference[k] - 1) for k in reference}
    print(f"beer at 640 px: {s['points']} points in {s['triangulation']['seconds']} s; relative differences "
          + ", ".join(f"{k} {np.round(v, 3)}" for k, v in error.items()))
    assert error["near"] < 0.1 and error["far"] < 0.1
    assert error["extent"][2] < 0.1  # z: up
    assert np.all(error["extent"][:2] < 0.15)  # x, y: the box estimator's own spread (see above)
