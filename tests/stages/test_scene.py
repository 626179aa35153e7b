"""The scene stage on real captures (temple ring, handheld cup, lego) and user overrides of its decisions."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from nerfpipe import Pipeline
from nerfpipe.analysis.exposure import decide_exposure, decide_photometric, measure_exposure
from nerfpipe.analysis.layout import decide_layout
from nerfpipe.artifacts import Bounds, FrameBounds, PhotoRecord, SceneDecisions
from nerfpipe.geometry.cameras import OPENGL_TO_OPENCV, Camera, CameraSet, Frame, Points, PoseHints, invert_pose
from nerfpipe.geometry.normalize import in_view
from nerfpipe.pipeline import ParamError, parse_assignments
from nerfpipe.stages import IngestStage
from nerfpipe.stages.bounds import BoundsStage
from nerfpipe.stages.scene import SceneParams, SceneStage
from tests.helpers import TEMPLE, SavedCameras, look_at, shared

# README.txt of templeSparseRing: "The (tight) bounding box for the templeSparseRing model"
TEMPLE_BOX = (np.array([-0.073568, 0.021728, -0.012445]), np.array([0.028855, 0.181892, 0.062736]))


def run_scene(capture: Path, cameras: CameraSet, run_dir: Path, undistorted=None, **overrides) -> dict:
    stages = [IngestStage(), SavedCameras(cameras, requires=("images_json",), check_frames=True, images=undistorted, images_artifact="undistorted_images"), BoundsStage(), SceneStage()]
    outcome = Pipeline(stages, capture, run_dir, overrides={"scene": overrides} if overrides else None).run()[-1]
    return json.loads((outcome.path / "scene.json").read_text())


def with_hints(cameras: CameraSet, undistorted: bool = False, displacement: float = 0.0, root: str = "ingest") -> CameraSet:
    cameras.hints.undistortion = {
        str(k): {"max_displacement_px": displacement, "undistorted": undistorted} for k in cameras.cameras
    }
    cameras.hints.image_roots = {f.name: root for f in cameras.frames}
    return cameras


# -- captures --------------------------------------------------------------------------------------------
def temple_cameras(names: list[str] | None = None, n_points: int = 3000) -> CameraSet:
    """Middlebury templeSR_par.txt (P = K [R | t], so c2w = inv([R | t])) plus synthetic points sampled
    inside the README's bounding box of the model."""
    cameras, frames = {}, []
    for line in (TEMPLE / "templeSR_par.txt").read_text().splitlines()[1:]:
        if not line.strip():
            continue
        name, *values = line.split()
        if names is not None and name not in names:
            continue
        v = np.array(values, float)
        K, R, t = v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:]
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = R, t
        cameras[1] = Camera.pinhole(K[0, 0], K[1, 1], K[0, 2], K[1, 2], 640, 480)
        frames.append(Frame(name, 1, invert_pose(w2c)))
    rng = np.random.default_rng(0)
    xyz = rng.uniform(*TEMPLE_BOX, (n_points, 3))
    visible = [np.flatnonzero(in_view(f.c2w, cameras[1].K(), 640, 480, xyz)) for f in frames]
    points = Points(xyz, np.full((n_points, 3), 200, np.uint8), np.full(n_points, 0.5), visible)
    return with_hints(CameraSet(cameras, frames, points, "middlebury"))


def cup_capture(tmp_path: Path) -> tuple[Path, CameraSet]:
    """The LLFF cup at 200x150 (images_4) as a plain folder, and its poses_bounds.npy as a CameraSet.

    LLFF rotation columns are [down, right, backwards]; OpenCV's [right, down, forward] = [c1, c0, -c2].
    Rows follow the lexicographically sorted image names.
    """
    source = shared("llff_cup_kwrous")
    capture = tmp_path / "cup"
    (capture / "images").mkdir(parents=True)
    names = sorted(p.name for p in (source / "images_4").iterdir())
    for name in names:
        shutil.copy(source / "images_4" / name, capture / "images" / name)
    poses = np.load(source / "poses_bounds.npy")[:, :15].reshape(-1, 3, 5)
    assert len(poses) == len(names)
    h, w, focal = poses[0, :, 4]
    frames = []
    for name, pose in zip(names, poses):
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = pose[:, 1], pose[:, 0], -pose[:, 2], pose[:, 3]
        frames.append(Frame(Path(name).stem + ".png", 1, c2w))
    camera = Camera.pinhole(focal / 4, focal / 4, w / 8, h / 8, int(w) // 4, int(h) // 4)
    return capture, with_hints(CameraSet({1: camera}, frames, None, "llff"))


def lego_capture(tmp_path: Path, every: int = 8) -> tuple[Path, CameraSet]:
    """Every ``every``-th lego train image (RGBA) with a transforms_train.json naming only those."""
    source = shared("nerf_synthetic_lego_400")
    doc = json.loads((source / "transforms_train.json").read_text())
    capture = tmp_path / "lego"
    (capture / "train").mkdir(parents=True)
    kept = doc["frames"][::every]
    for f in kept:
        shutil.copy(source / (f["file_path"][2:] + ".png"), capture / "train")
    (capture / "transforms_train.json").write_text(json.dumps({**doc, "frames": kept}))
    focal = 0.5 * 400 / np.tan(0.5 * doc["camera_angle_x"])
    frames = [
        Frame(f["file_path"][2:] + ".png", 1, np.array(f["transform_matrix"]) @ OPENGL_TO_OPENCV, "train") for f in kept
    ]
    camera = Camera.pinhole(focal, focal, 200.0, 200.0, 400, 400)
    return capture, with_hints(CameraSet({1: camera}, frames, None, "transforms_json"))


# -- real captures ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def temple_run(tmp_path_factory) -> tuple[Path, dict]:
    run_dir = tmp_path_factory.mktemp("temple") / "run"
    return run_dir, run_scene(TEMPLE, temple_cameras(), run_dir)


def test_temple_ring_is_inward360_on_a_black_background(temple_run):
    _, scene = temple_run
    layout = scene["layout"]
    assert layout["value"] == "inward360" and layout["overridden"] is False
    # 16 views on a ring at latitude ±82° of the gantry, all aimed at the temple
    assert layout["measured"]["median_axis_to_center_deg"] < 2.0
    assert layout["measured"]["azimuth_coverage_deg"] > 300
    assert layout["measured"]["points_outside_ring"] == 0.0
    # the photos are shot against black cloth: the borders are black up to its folds
    background = scene["background"]
    assert background["value"] == "color"
    assert background["measured"]["border_color"] == [0.0, 0.0, 0.0]
    assert 0.9 <= background["measured"]["border_within_tolerance"] < 0.97
    assert background["measured"]["tolerance"] == 0.1  # training masks the backdrop with the same tolerance
    assert scene["background_color"]["value"] == [0.0, 0.0, 0.0]
    assert scene["lens"]["value"] == "pinhole" and scene["photometric"]["value"] == "srgb"
    # no EXIF: measured from the brightness of the points in each photo (these synthetic points are not on the
    # temple's surface, so their value says nothing; the real triangulated points are checked in test_train.py)
    exposure = scene["exposure_varies"]
    assert exposure["measured"]["source"] == "brightness" and len(exposure["measured"]["stops"]) == 16
    assert scene["ndc"] is False


def test_override_keeps_the_evidence_and_marks_it(temple_run):
    run_dir, auto = temple_run
    stages = [IngestStage(), SavedCameras(temple_cameras(), requires=("images_json",), check_frames=True, images_artifact="undistorted_images"), BoundsStage(), SceneStage()]
    overrides = parse_assignments(["scene.layout=forward", "scene.background_color=0.5,0.5,0.5"])
    outcomes = Pipeline(stages, TEMPLE, run_dir, overrides=overrides).run()
    assert [o.action for o in outcomes] == ["cached", "cached", "cached", "ran"]
    scene = json.loads((outcomes[-1].path / "scene.json").read_text())
    layout = scene["layout"]
    assert layout["value"] == "forward" and layout["overridden"] is True and scene["ndc"] is True
    assert layout["evidence"].startswith(auto["layout"]["evidence"])
    assert "the data suggested inward360" in layout["evidence"]
    assert layout["measured"] == auto["layout"]["measured"]
    color = scene["background_color"]
    assert color["value"] == [0.5, 0.5, 0.5] and color["overridden"] is True
    assert color["measured"] == auto["background_color"]["measured"] == {"border_color": [0.0, 0.0, 0.0]}
    assert "the data suggested (0, 0, 0)" in color["evidence"]
    assert scene["background"] == auto["background"]  # untouched decisions are as measured
    lines = SceneDecisions.load(outcomes[-1].path / "scene.json").describe()
    assert SceneStage().describe(outcomes[-1].path, {}) == lines
    assert lines[0].startswith("layout is forward: cameras look at a common centre")
    assert lines[0].endswith("; set by the user (the data suggested inward360)")
    assert any(line.startswith("background is color: median border colour (0.00, 0.00, 0.00)") for line in lines)


def test_bad_overrides_are_refused(tmp_path):
    stages = [IngestStage(), SavedCameras(temple_cameras(), requires=("images_json",), check_frames=True, images_artifact="undistorted_images"), BoundsStage(), SceneStage()]
    with pytest.raises(ParamError, match="scene.layout: 'sideways' is not one of"):
        Pipeline(stages, TEMPLE, tmp_path / "run", overrides={"scene": {"layout": "sideways"}}).plan()
    with pytest.raises(ParamError, match="background_color must be auto, white, black or r,g,b"):
        Pipeline(stages, TEMPLE, tmp_path / "run", overrides={"scene": {"background_color": "1,2"}}).plan()


def test_cup_is_a_partial_orbit_not_forward_facing(tmp_path):
    # The cup capture is handheld around a cup on a desk, the phone turned a quarter: the cameras all aim at
    # the cup (median ~5° off the least-squares look-at point) from up to 74° apart, over ~220° of azimuth
    # about the standing cup (a 138° gap behind it; a few shots from overhead left out). Not forward-facing (NDC
    # would need every view within 45° of the mean); with no sparse points, nothing says the scene extends
    # beyond the cameras, so it is a bounded inward capture.
    capture, cameras = cup_capture(tmp_path)
    scene = run_scene(capture, cameras, tmp_path / "run")
    layout = scene["layout"]
    assert layout["value"] == "inward360"
    assert 70 < layout["measured"]["max_angle_to_mean_deg"] < 78
    assert layout["measured"]["median_axis_to_center_deg"] < 10
    assert 200 < layout["measured"]["azimuth_coverage_deg"] < 240
    assert layout["measured"]["bounds_method"] == "rig"
    # desk, wall and room behind it: no constant border colour
    assert scene["background"]["value"] == "none" and scene["background_color"]["value"] is None
    assert scene["background"]["measured"]["border_within_tolerance"] < 0.5


def test_lego_is_inward360_with_alpha_composited_on_white(tmp_path):
    capture, cameras = lego_capture(tmp_path)
    scene = run_scene(capture, cameras, tmp_path / "run")
    assert scene["layout"]["value"] == "inward360"
    assert scene["layout"]["measured"]["azimuth_coverage_deg"] > 250
    background = scene["background"]
    assert background["value"] == "alpha" and background["measured"]["with_alpha"] == len(cameras.frames) == 13
    assert 0.3 < background["measured"]["transparent_fraction"] < 0.95
    assert scene["background_color"]["value"] == [1.0, 1.0, 1.0]
    # the usual 2 / 6 bounds of the synthetic scenes, in normalized units
    assert scene["far"] / scene["near"] == pytest.approx(3.0, rel=0.02)


def test_undistorted_frames_are_read_from_the_undistort_output(capture, tmp_path):
    names = [f"templeSR000{i}.png" for i in range(1, 5)]
    cameras = with_hints(temple_cameras(names), undistorted=True, displacement=3.25, root="undistort")
    grey = {name: np.full((48, 64, 3), 128, np.uint8) for name in names}
    scene = run_scene(capture, cameras, tmp_path / "run", undistorted=grey)
    assert scene["background"]["value"] == "color"
    assert scene["background_color"]["value"] == pytest.approx([128 / 255] * 3, abs=1e-4)
    assert scene["lens"]["value"] == "undistorted"
    assert "up to 3.25 px, undistorted" in scene["lens"]["evidence"]


def test_lens_evidence_per_camera():
    from nerfpipe.analysis.lens import decide_lens

    cameras = CameraSet({}, [], hints=PoseHints(undistortion={
        "1": {"model": "OPENCV", "max_displacement_px": 0.12, "undistorted": False},
        "2": {"model": "OPENCV_FISHEYE", "max_displacement_px": None, "undistorted": True},
    }))
    value, evidence, _ = decide_lens(cameras)
    assert value == "undistorted"
    assert evidence == ("camera 1: distortion moves pixels by up to 0.12 px, left as is; "
                        "camera 2: distortion moves pixels beyond 90° off-axis (fisheye), undistorted")
    assert decide_lens(CameraSet({}, []))[0] == "pinhole"


def test_lens_evidence_sums_up_one_camera_per_photo():
    """71 phone frames, a camera each: one sentence with the spread and the counts, not 71 clauses."""
    from nerfpipe.analysis.lens import decide_lens

    record = {str(i): {"model": "SIMPLE_RADIAL", "max_displacement_px": 0.2 + 0.4 * i, "undistorted": True}
              for i in range(1, 72)}
    record["1"] = {"model": "SIMPLE_RADIAL", "max_displacement_px": 0.2, "undistorted": False}
    value, evidence, measured = decide_lens(CameraSet({}, [], hints=PoseHints(undistortion=record)))
    assert value == "undistorted"
    assert evidence == "71 cameras: distortion 0.2-29 px, 70 undistorted, 1 left as is"
    assert measured == {"cameras": record}  # the per-camera numbers stay on record

    record["71"]["max_displacement_px"] = None  # a fisheye beyond 90 degrees
    for info in record.values():
        info["undistorted"] = False
    value, evidence, _ = decide_lens(CameraSet({}, [], hints=PoseHints(undistortion=record)))
    assert value == "pinhole"
    assert evidence == "71 cameras: distortion 0.2-28 px, 1 beyond 90° off-axis (fisheye), 0 undistorted, 71 left as is"

    four = {str(i): {"max_displacement_px": 3.0, "undistorted": True} for i in range(1, 5)}
    assert decide_lens(CameraSet({}, [], hints=PoseHints(undistortion=four)))[1] == "4 cameras: distortion 3 px, 4 undistorted, 0 left as is"
    three = {str(i): {"max_displacement_px": 3.0, "undistorted": True} for i in range(1, 4)}
    assert decide_lens(CameraSet({}, [], hints=PoseHints(undistortion=three)))[1].count("camera ") == 3  # named one by one


# -- layout on synthetic rigs ----------------------------------------------------------------------------
def synthetic(c2ws: list[np.ndarray], xyz: np.ndarray) -> tuple[CameraSet, Bounds]:
    """A world CameraSet with points, and bounds frames with the points' depth range per camera."""
    frames = [Frame(f"{i}.png", 1, c) for i, c in enumerate(c2ws)]
    points = Points(xyz, np.zeros((len(xyz), 3), np.uint8), np.zeros(len(xyz)), [])
    depth = [(xyz - c[:3, 3]) @ c[:3, 2] for c in c2ws]
    frame_bounds = tuple(FrameBounds(f.name, d[d > 0].min(), d[d > 0].max(), "points") for f, d in zip(frames, depth))
    eye = np.eye(4).tolist()
    bounds = Bounds(eye, eye, 1.0, [0.0, 0.0, 1.0], "inward", "points", ([-1.0] * 3, [1.0] * 3),
                    min(f.near for f in frame_bounds), max(f.far for f in frame_bounds), frame_bounds)
    return CameraSet({1: Camera.pinhole(100, 100, 50, 50, 100, 100)}, frames, points), bounds


def test_layout_forward_for_a_handheld_forward_facing_rig():
    rng = np.random.default_rng(0)
    eyes = np.c_[rng.uniform(-0.5, 0.5, 20), np.full(20, -1.0), rng.uniform(-0.3, 0.3, 20)]
    c2ws = [look_at(e, e + [0, 1, 0] + rng.normal(scale=0.1, size=3)) for e in eyes]
    world, bounds = synthetic(c2ws, rng.uniform([-3, 2, -2], [3, 9, 2], (2000, 3)))
    value, evidence, measured = decide_layout(world, bounds, SceneParams())
    assert value == "forward" and measured["max_angle_to_mean_deg"] < 15
    assert evidence.startswith("all cameras face one way: viewing directions lie within")


def test_layout_unbounded_when_the_points_reach_far_beyond_the_ring():
    rng = np.random.default_rng(1)
    c2ws = [look_at(np.array([np.cos(a), np.sin(a), 0.3]), np.zeros(3)) for a in np.linspace(0, 6.2, 30)]
    near = rng.uniform(-0.3, 0.3, (1500, 3))
    far = rng.normal(size=(1500, 3))
    far = 8 * far / np.linalg.norm(far, axis=1, keepdims=True)  # a room / landscape all around
    world, bounds = synthetic(c2ws, np.r_[near, far])
    value, evidence, measured = decide_layout(world, bounds, SceneParams())
    assert value == "unbounded360" and measured["points_outside_ring"] == pytest.approx(0.5, abs=0.01)
    assert "50.0% of the 3000 sparse points lie farther out than the cameras" in evidence
    world, bounds = synthetic(c2ws, near)
    assert decide_layout(world, bounds, SceneParams())[0] == "inward360"


def test_layout_unbounded_when_cameras_share_no_centre():
    # a panorama: cameras at one spot looking outwards in every direction
    c2ws = [look_at(np.zeros(3), np.array([np.cos(a), np.sin(a), 0.0])) for a in np.linspace(0, 6.2, 24)]
    rng = np.random.default_rng(2)
    world, bounds = synthetic(c2ws, rng.normal(size=(500, 3)) * 5)
    value, evidence, _ = decide_layout(world, bounds, SceneParams())
    assert value == "unbounded360" and "nor look at a common centre" in evidence


# -- photometry from the ingest records ------------------------------------------------------------------
def record(t: float | None, f: float | None, iso: int | None, raw: bool = False, linear: bool = False,
           name: str | None = None) -> PhotoRecord:
    name = name or f"{t}_{f}_{iso}_{np.random.default_rng().integers(1 << 30)}.png"
    return PhotoRecord(name, raw=raw, linear=linear, exif={"exposure_time_s": t, "f_number": f, "iso": iso})


def test_exposure_varies_beyond_a_third_of_a_stop():
    # 1/100 s f/4 ISO 100 vs 1/80 s: log2(100/80) = 0.32 stop -> constant
    varies, evidence, measured = decide_exposure([record(1 / 100, 4.0, 100), record(1 / 80, 4.0, 100)])
    assert varies is False and measured["spread_stops"] == pytest.approx(0.3219, abs=1e-4)
    # ISO 100 -> 200 at f/4 -> f/5.6: +1 - log2(5.6^2/16) = +1 - 0.971 = 0.03 stop: still constant
    assert decide_exposure([record(1 / 100, 4.0, 100), record(1 / 100, 5.6, 200)])[0] is False
    varies, evidence, measured = decide_exposure([record(1 / 100, 4.0, 100), record(1 / 50, 4.0, 100), record(None, 4.0, 100)])
    assert varies is True and measured["spread_stops"] == pytest.approx(1.0)
    assert "EXIF exposure (time x ISO / f-number^2) of 2 of 3 photos spans 1.00 stops" in evidence
    assert sorted(measured["stops"].values()) == pytest.approx([-0.5, 0.5])  # each photo's, about their mean
    assert decide_exposure([record(None, None, None)] * 3)[0] is False


def test_exposure_measured_from_the_same_points_in_each_photo(tmp_path: Path) -> None:
    """Without EXIF: four cameras over a textured plane, the photos taken 0, +0.5, -0.7 and +1 stop apart
    (sRGB-encoded, bright parts clipped); the points' brightness gives each photo's stops back."""
    import cv2

    stops = [0.0, 0.5, -0.7, 1.0]
    size, f = 64, 64.0
    camera = Camera.pinhole(f, f, size / 2, size / 2, size, size)
    rng = np.random.default_rng(0)
    centres = [np.array([0.1 * i, -0.05 * i, -2.0]) for i in range(4)]
    frames, paths = [], {}
    u, v = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    for i, (centre, s) in enumerate(zip(centres, stops)):
        x = centre[0] + 2.0 * (u - size / 2) / f  # the plane z = 0, two units ahead of every camera
        y = centre[1] + 2.0 * (v - size / 2) / f
        light = (0.25 + 0.2 * np.sin(4 * x) * np.cos(3 * y)) * 2.0**s
        encoded = np.where(light > 0.0031308, 1.055 * np.clip(light, 0, 1) ** (1 / 2.4) - 0.055, 12.92 * light)
        grey = np.round(np.clip(encoded, 0, 1) * 255).astype(np.uint8)
        paths[f"p{i}.png"] = tmp_path / f"p{i}.png"
        cv2.imwrite(str(paths[f"p{i}.png"]), np.repeat(grey[..., None], 3, axis=-1))
        pose = np.eye(4)
        pose[:3, 3] = centre
        frames.append(Frame(f"p{i}.png", 1, pose))
    xyz = np.concatenate([rng.uniform(-0.6, 0.6, size=(300, 2)), np.zeros((300, 1))], axis=1)
    points = Points(xyz, np.zeros((300, 3), np.uint8), np.zeros(300), [np.arange(300)] * 4)
    measured = measure_exposure(CameraSet({1: camera}, frames, points), paths, linear=False)
    relative = np.array([measured[f"p{i}.png"] for i in range(4)])
    assert relative == pytest.approx(np.array(stops) - np.median(stops), abs=0.05)
    varies, evidence, numbers = decide_exposure([record(None, None, None, name=n) for n in paths], lambda: measured)
    assert varies and numbers["source"] == "brightness" and "brightness of the same sparse points in 4 of 4" in evidence
    assert measure_exposure(CameraSet({1: camera}, frames, None), paths, linear=False) == {}


def test_photometric_from_the_records():
    assert decide_photometric([record(None, None, None, raw=True, linear=True)] * 2)[0] == "linear_raw"
    value, evidence, _ = decide_photometric([record(None, None, None, raw=True, linear=True), record(None, None, None)])
    assert value == "srgb" and "mixed" in evidence
    assert decide_photometric([record(None, None, None, raw=True)])[0] == "srgb"
