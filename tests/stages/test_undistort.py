"""The undistort stage: real chessboards come out straight, pinhole captures pass through untouched."""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from nerfpipe import Pipeline
from nerfpipe.artifacts import frame_image_path
from nerfpipe.geometry.cameras import Camera, CameraSet, Frame, Points, PoseHints
from nerfpipe.geometry.distortion import max_distortion_displacement, undistort_pixels, undistortion_maps
from nerfpipe.imaging.png import read_png, write_png
from nerfpipe.pipeline import StageContext, StageError, StageInputs
from nerfpipe.stages import IngestStage
from nerfpipe.stages.undistort import UndistortParams, UndistortStage
from tests.helpers import SavedCameras, shared

PATTERN = (9, 6)  # inner corners per row, rows
SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-6)


def pipeline(capture: Path, run_dir: Path, camera_set: CameraSet, **undistort: object) -> Pipeline:
    digest = hashlib.sha256(json.dumps({k: c.to_json() for k, c in camera_set.cameras.items()}).encode()).hexdigest()
    stages = [IngestStage(), SavedCameras(camera_set, name="sfm", artifact="sfm_model", requires=("images_json",)), UndistortStage()]
    overrides = {"ingest": {"max_size": 0}, "sfm": {"tag": digest[:16]}, "undistort": undistort}
    return Pipeline(stages, capture, run_dir, overrides=overrides)


def run_undistort(
    capture: Path, run_dir: Path, camera_set: CameraSet, **undistort: object
) -> tuple[Path, Path, CameraSet]:
    """Run ingest -> fake sfm -> undistort; return (ingest images, undistorted images, pinhole camera set)."""
    outcomes = {o.name: o for o in pipeline(capture, run_dir, camera_set, **undistort).run()}
    out = outcomes["undistort"].path
    return outcomes["ingest"].path / "images", out / "images", CameraSet.load(out / "pinhole")


def one_camera(camera: Camera, names: list[str]) -> CameraSet:
    return CameraSet({1: camera}, [Frame(n, 1, np.eye(4)) for n in names], source="test")


# -- straightness of chessboard rows and columns ---------------------------------------------------------
def detect_corners(gray: np.ndarray) -> np.ndarray:
    """(54, 2) inner corners, OpenCV pixel convention, row by row (9 per row)."""
    found, corners = cv2.findChessboardCorners(gray, PATTERN)
    assert found, "chessboard not found"
    return cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), SUBPIX).reshape(-1, 2)


def chessboard_lines(corners: np.ndarray) -> list[np.ndarray]:
    grid = corners.reshape(PATTERN[1], PATTERN[0], 2)
    return list(grid) + list(grid.transpose(1, 0, 2))  # 6 rows of 9, then 9 columns of 6


def line_fit(points: np.ndarray, centre: np.ndarray) -> tuple[float, float]:
    """Total-least-squares line through (n, 2) points: (max perpendicular residual, bulge) in pixels.

    The bulge is the sagitta of a parabola fitted to the residuals along the line, positive when the
    middle of the line bows away from ``centre`` (barrel distortion bows lines outwards).
    """
    mean = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - mean)
    direction, normal = vt[0], vt[1]
    if (mean - centre) @ normal < 0:
        normal = -normal
    along, across = (points - mean) @ direction, (points - mean) @ normal
    a = np.polyfit(along, across, 2)[0]
    return float(np.abs(across).max()), float(-a * (np.ptp(along) / 2) ** 2)


def straightness(corners: np.ndarray, centre: np.ndarray) -> tuple[float, float]:
    """(worst residual over the rows, mean bulge over rows and columns) of one chessboard view."""
    fits = [line_fit(line, centre) for line in chessboard_lines(corners)]
    return max(f[0] for f in fits[: PATTERN[1]]), float(np.mean([f[1] for f in fits]))


# -- real data: the XIMEA chessboards ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def ximea() -> tuple[list[Path], list[np.ndarray], Camera, np.ndarray, np.ndarray]:
    """The 25 left images, their detected corners, the camera calibrated on every other image, and
    OpenCV's own K and distortion coefficients of that calibration."""
    paths = sorted(shared("chessboard_stereo_ximea", "left").glob("left*.jpg"))
    assert len(paths) == 25
    corners = [detect_corners(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)) for p in paths]
    board = np.zeros((54, 3), np.float32)
    board[:, :2] = np.mgrid[0 : PATTERN[0], 0 : PATTERN[1]].T.reshape(-1, 2)
    used = corners[::2]  # 13 images calibrate, so 12 of the 25 checked below played no part in it
    image_points = [c.astype(np.float32) for c in used]
    rms, K, dist, _, _ = cv2.calibrateCamera([board] * len(used), image_points, (640, 512), None, None)
    assert rms < 0.3
    k1, k2, p1, p2, k3 = dist.ravel()
    # OpenCV puts the first pixel centre at 0, COLMAP at 0.5
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5
    if k3 != 0:
        camera = Camera("FULL_OPENCV", 640, 512, tuple(map(float, (fx, fy, cx, cy, k1, k2, p1, p2, k3, 0, 0, 0))))
    else:
        camera = Camera("OPENCV", 640, 512, tuple(map(float, (fx, fy, cx, cy, k1, k2, p1, p2))))
    return paths, corners, camera, K, dist


def test_real_chessboards_come_out_straight(ximea, tmp_path):
    paths, original_corners, camera, K, dist = ximea
    capture = tmp_path / "capture"
    capture.mkdir()
    for path in paths:
        shutil.copy2(path, capture / path.name)
    names = [p.with_suffix(".png").name for p in paths]
    _, undistorted, pinhole = run_undistort(capture, tmp_path / "run", one_camera(camera, names))

    new = pinhole.cameras[1]
    assert new.model == "PINHOLE" and (new.width, new.height) == (640, 512)
    assert pinhole.hints.image_roots == {n: "undistort" for n in names}
    assert pinhole.hints.undistortion["1"]["undistorted"] is True
    assert pinhole.hints.undistortion["1"]["max_displacement_px"] > 1.0

    centre_before = np.array([camera.cx, camera.cy]) - 0.5  # OpenCV convention, like the detected corners
    centre_after = np.array([new.cx, new.cy]) - 0.5
    residual_before, residual_after, bulge_before, bulge_after, offsets = [], [], [], [], []
    for name, before in zip(names, original_corners):
        after = detect_corners(cv2.cvtColor(read_png(undistorted / name), cv2.COLOR_RGB2GRAY))
        worst, bulge = straightness(before, centre_before)
        residual_before.append(worst)
        bulge_before.append(bulge)
        worst, bulge = straightness(after, centre_after)
        residual_after.append(worst)
        bulge_after.append(bulge)
        # route 2: OpenCV undistorts the corners found in the original image, all in its own pixel
        # convention (the calibration's K, and the new camera's K shifted by hand)
        new_K = new.K() - [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]]
        expected = cv2.undistortPoints(before.reshape(-1, 1, 2).astype(np.float64), K, dist, P=new_K).reshape(-1, 2)
        offsets.append(np.linalg.norm(after - expected, axis=1))
    offsets = np.concatenate(offsets)
    print(
        f"\nworst row residual: original {max(residual_before):.3f} px, undistorted {max(residual_after):.3f} px"
        f"\nmean bulge of rows and columns: original {np.mean(bulge_before):+.3f} px, "
        f"undistorted {np.mean(bulge_after):+.3f} px"
        f"\ncorners in the undistorted images vs. undistorted corners: max {offsets.max():.3f} px, "
        f"RMS {np.sqrt(np.mean(offsets ** 2)):.3f} px"
    )
    # The images and the point model agree: half a pixel off anywhere (the pixel convention) would show here.
    assert offsets.max() < 0.25 and np.sqrt(np.mean(offsets**2)) < 0.1
    # This lens moves pixels by ~2 px only, so a row's bend (a few tenths of a pixel) is the size of the
    # corner detector's noise: the systematic part, averaged over 25 x 15 lines, is what shows it.
    assert np.mean(bulge_before) > 0.035  # barrel: lines bow outwards before...
    assert abs(np.mean(bulge_after)) < 0.025  # ... and not after
    # Max residuals are noise-dominated here (exact point-wise undistortion of the detected corners
    # leaves ~0.37 px too): bound them at the noise floor only; the synthetic test checks 0.3 px.
    assert max(residual_after) < 0.45


def render_chessboard(camera: Camera, R: np.ndarray, t: np.ndarray, supersample: int = 2) -> np.ndarray:
    """(H, W) uint8 image of a 10 x 7-square board (9 x 6 inner corners) seen through ``camera``.

    Board point (u, v, 0), in squares, is at R (u, v, 0) + t in camera coordinates (OpenCV axes).
    Each pixel averages supersample^2 rays, so edges are anti-aliased.
    """
    s, W, H = supersample, camera.width, camera.height
    offsets = (np.arange(s) + 0.5) / s
    xs, ys = (np.arange(W)[:, None] + offsets).ravel(), (np.arange(H)[:, None] + offsets).ravel()
    pixels = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)  # COLMAP convention: pixel i spans [i, i + 1]
    ideal = undistort_pixels(camera, pixels)
    rays = np.column_stack([(ideal - [camera.cx, camera.cy]) / [camera.fx, camera.fy], np.ones(len(ideal))])
    depth = (R[:, 2] @ t) / (rays @ R[:, 2])
    u, v = ((rays * depth[:, None] - t) @ R).T[:2]
    dark = (u >= 0) & (u < 10) & (v >= 0) & (v < 7) & ((np.floor(u) + np.floor(v)) % 2 == 0)
    return np.round(np.where(dark, 30.0, 225.0).reshape(H, s, W, s).mean(axis=(1, 3))).astype(np.uint8)


def test_strongly_distorted_synthetic_chessboard_rows_are_straight_within_0_3_px(tmp_path):
    camera = Camera("OPENCV", 640, 480, (420.0, 420.0, 322.0, 238.0, -0.28, 0.07, 0.0, 0.0))
    R = cv2.Rodrigues(np.array([0.0, -0.2, 0.0]))[0] @ cv2.Rodrigues(np.array([0.15, 0.0, 0.0]))[0]
    image = render_chessboard(camera, R, np.array([-5.0, -3.5, 9.0]))
    capture = tmp_path / "capture"
    write_png(capture / "board.png", np.dstack([image] * 3))
    _, undistorted, pinhole = run_undistort(capture, tmp_path / "run", one_camera(camera, ["board.png"]))
    new = pinhole.cameras[1]

    def worst_row(gray: np.ndarray, cam: Camera) -> float:
        found, corners = cv2.findChessboardCornersSB(gray, PATTERN, flags=cv2.CALIB_CB_ACCURACY)
        assert found
        return straightness(corners.reshape(-1, 2), np.array([cam.cx, cam.cy]) - 0.5)[0]

    before = worst_row(image, camera)
    after = worst_row(cv2.cvtColor(read_png(undistorted / "board.png"), cv2.COLOR_RGB2GRAY), new)
    print(f"\nsynthetic board, worst row residual: original {before:.3f} px, undistorted {after:.3f} px")
    assert before > 1.0  # the lens bends the rows by pixels: the bound below can fail
    assert after < 0.3


# -- pass-through ------------------------------------------------------------------------------------------
def temple_camera_set(capture: Path) -> CameraSet:
    names = sorted(p.with_suffix(".png").name for p in capture.glob("*.png"))
    rng = np.random.default_rng(1)
    poses = [np.eye(4) + np.pad(rng.normal(size=(3, 4)), ((0, 1), (0, 0))) for _ in names]
    frames = [Frame(n, 1 if i < 2 else 2, c2w) for i, (n, c2w) in enumerate(zip(names, poses))]
    points = Points(rng.normal(size=(5, 3)), rng.integers(0, 255, (5, 3), dtype=np.uint8), rng.random(5),
                    [np.array([0, 1]), np.array([2]), np.array([], np.int64), np.array([3, 4])])
    cameras = {1: Camera("SIMPLE_PINHOLE", 640, 480, (800.0, 320.0, 240.0)),
               2: Camera("PINHOLE", 640, 480, (810.0, 805.0, 321.5, 239.5))}
    return CameraSet(cameras, frames, points, "test", ["extra.png"], PoseHints(["poses.txt"], aabb_scale=2.0))


def test_pinhole_cameras_pass_through_with_no_images_written(capture, tmp_path, caplog):
    model = temple_camera_set(capture)
    with caplog.at_level(logging.INFO, logger="nerfpipe"):
        ingest_images, undistorted, pinhole = run_undistort(capture, tmp_path / "run", model)
    assert undistorted.is_dir() and list(undistorted.rglob("*")) == []
    assert pinhole.hints.image_roots == {f.name: "ingest" for f in model.frames}
    assert pinhole.hints.undistortion == {
        "1": {"model": "SIMPLE_PINHOLE", "max_displacement_px": 0.0, "undistorted": False},
        "2": {"model": "PINHOLE", "max_displacement_px": 0.0, "undistorted": False},
    }
    assert pinhole.hints.pose_files == ["poses.txt"] and pinhole.hints.aabb_scale == 2.0  # kept
    assert pinhole.unregistered == ["extra.png"]
    assert pinhole.cameras == {1: Camera("PINHOLE", 640, 480, (800.0, 800.0, 320.0, 240.0)), 2: model.cameras[2]}
    assert [(f.name, f.camera_id) for f in pinhole.frames] == [(f.name, f.camera_id) for f in model.frames]
    assert all(np.array_equal(a.c2w, b.c2w) for a, b in zip(pinhole.frames, model.frames))
    assert np.array_equal(pinhole.points.xyz, model.points.xyz) and np.array_equal(pinhole.points.rgb, model.points.rgb)
    assert [v.tolist() for v in pinhole.points.visible] == [v.tolist() for v in model.points.visible]
    for frame in pinhole.frames:
        path = frame_image_path(frame.name, pinhole.hints.image_roots[frame.name], ingest_images, undistorted)
        assert path == ingest_images / frame.name and path.is_file()
    assert "undistort: max displacement 0.00 px <= 0.5 px: images pass through untouched" in caplog.messages


def test_a_threshold_above_the_displacement_passes_through(capture, tmp_path, caplog):
    camera = Camera("SIMPLE_RADIAL", 640, 480, (800.0, 320.0, 240.0, 0.01))
    displacement = max_distortion_displacement(camera)  # 800 * 0.01 * 0.5^3 = 1.0 px at the corner
    assert 0.9 < displacement < 1.1
    names = sorted(p.with_suffix(".png").name for p in capture.glob("*.png"))
    model = one_camera(camera, names)

    with caplog.at_level(logging.INFO, logger="nerfpipe"):
        _, undistorted, pinhole = run_undistort(capture, tmp_path / "run", model, threshold_px=2.0)
    assert list(undistorted.rglob("*")) == []
    assert set(pinhole.hints.image_roots.values()) == {"ingest"}
    assert pinhole.cameras[1] == Camera("PINHOLE", 640, 480, (800.0, 800.0, 320.0, 240.0))
    assert pinhole.hints.undistortion["1"] == {
        "model": "SIMPLE_RADIAL", "max_displacement_px": round(displacement, 4), "undistorted": False
    }
    assert f"undistort: max displacement {displacement:.2f} px <= 2 px: images pass through untouched" in (
        caplog.messages
    )

    caplog.clear()
    with caplog.at_level(logging.INFO, logger="nerfpipe"):
        _, undistorted, pinhole = run_undistort(capture, tmp_path / "run", model)  # default 0.5 px
    assert sorted(p.name for p in undistorted.iterdir()) == names
    assert set(pinhole.hints.image_roots.values()) == {"undistort"}
    assert pinhole.cameras[1] == undistortion_maps(camera)[2]
    assert f"undistort: undistorted 4 images of camera 1 (max displacement {displacement:.1f} px)" in caplog.messages
    manifest = json.loads((undistorted.parent / "manifest.json").read_text())
    assert manifest["summary"] == {"cameras": 1, "undistorted_cameras": 1, "images_undistorted": 4,
                                   "images_passed_through": 0, "max_displacement_px": round(displacement, 4)}
    assert UndistortStage().describe(undistorted.parent, manifest) == [
        f"4 images undistorted (1 of 1 cameras, max displacement {displacement:.2f} px), 0 untouched"
    ]


def test_one_camera_per_photo_is_logged_in_sum(capture, tmp_path, caplog):
    """Four photos, each its own camera: three distorted ones are named one by one, four are summed up
    (as phone captures with a camera per frame would otherwise list 71 cameras in one line)."""
    names = sorted(p.with_suffix(".png").name for p in capture.glob("*.png"))
    ks = (0.01, 0.02, 0.04, 0.08)  # 1, 2, 4 and 8 px at the corner (800 * k * 0.5^3)
    cameras = {i + 1: Camera("SIMPLE_RADIAL", 640, 480, (800.0, 320.0, 240.0, k)) for i, k in enumerate(ks)}
    shifts = [max_distortion_displacement(c) for c in cameras.values()]
    model = CameraSet(cameras, [Frame(n, i + 1, np.eye(4)) for i, n in enumerate(names)], source="test")
    with caplog.at_level(logging.INFO, logger="nerfpipe"):
        _, undistorted, _ = run_undistort(capture, tmp_path / "run", model)
    assert sorted(p.name for p in undistorted.iterdir()) == names
    line = next(m for m in caplog.messages if m.startswith("undistort: ") and "cameras" in m)
    assert line == (f"undistort: 4 cameras: max displacement {shifts[0]:.2g}-{shifts[3]:.2g} px; "
                    "4 undistorted (4 images)")

    caplog.clear()
    with caplog.at_level(logging.INFO, logger="nerfpipe"):
        run_undistort(capture, tmp_path / "run", model, threshold_px=1.5)  # camera 1 stays as it is
    line = next(m for m in caplog.messages if m.startswith("undistort: undistorted"))
    assert line.startswith(f"undistort: undistorted 1 image of camera 2 (max displacement {shifts[1]:.1f} px); ")
    assert line.endswith(f"1 camera within 1.5 px (max {shifts[0]:.2f} px) passes through untouched")


def test_the_summed_up_log_line_for_71_cameras():
    displacement = {i: 0.2 + 0.4 * i for i in range(1, 72)}  # 0.6 .. 28.6 px
    displacement[72] = float("inf")  # a fisheye beyond 90 degrees
    displacement[1] = 0.21
    written = {i: 1 for i in range(2, 73)}
    line = UndistortStage._log_line(displacement, written, 0.5)
    assert line == ("72 cameras: max displacement 0.21-29 px, 1 beyond 90° off-axis; "
                    "71 undistorted (71 images), 1 within 0.5 px left as is")
    assert "camera 7 " not in line and len(line) < 120


def test_threshold_and_interpolation_move_only_the_undistort_key(capture, tmp_path):
    model = one_camera(Camera("PINHOLE", 640, 480, (800.0, 800.0, 320.0, 240.0)), ["templeSR0001.png"])

    def keys(**undistort):
        return {name: p.key for name, p in pipeline(capture, tmp_path / "run", model, **undistort).plan().items()}

    base = keys()
    assert keys(threshold_px=0.5) == base  # the default, given explicitly
    for changed in (keys(threshold_px=1.0), keys(threshold_px="0.25"), keys(interpolation="lanczos")):
        assert changed["undistort"] != base["undistort"]
        assert (changed["ingest"], changed["sfm"]) == (base["ingest"], base["sfm"])
    with pytest.raises(ValueError, match="threshold_px"):
        UndistortParams(threshold_px=-1.0)


# -- direct runs: mixed cameras, 16-bit RGBA, sub-folders, unicode names, bad models --------------------
def direct_run(
    tmp_path: Path, model: CameraSet, images: dict[str, np.ndarray], **params: object
) -> tuple[Path, CameraSet, list[str]]:
    """Run the stage by hand on ingest-like images; return (its output folder, pinhole set, log lines)."""
    ingest = tmp_path / "ingest"
    for name, pixels in images.items():
        write_png(ingest / "images" / name, pixels)
    records = [{"name": n, "width": p.shape[1], "height": p.shape[0]} for n, p in images.items()]
    (ingest / "images.json").write_text(json.dumps({"images": records}), encoding="utf-8")
    (tmp_path / "sfm").mkdir()
    model.save(tmp_path / "sfm")
    out = tmp_path / "out"
    out.mkdir()
    messages: list[str] = []
    log = logging.getLogger("test_undistort")
    handler = logging.Handler()
    handler.emit = lambda record: messages.append(record.getMessage())  # type: ignore[method-assign]
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    try:
        artifacts = {"images": ingest / "images", "images_json": ingest / "images.json", "sfm_model": tmp_path / "sfm"}
        inputs = StageInputs(artifacts, tmp_path)
        UndistortStage().run(inputs, out, UndistortParams(**params), StageContext(log=log))
    finally:
        log.removeHandler(handler)
    return out, CameraSet.load(out / "pinhole"), messages


def test_16_bit_rgba_in_sub_folders_with_unicode_names(tmp_path):
    distorted = Camera("SIMPLE_RADIAL", 64, 48, (60.0, 32.0, 24.0, 0.1))  # 60 * 0.1 * 0.67^3 ~ 1.8 px at the corner
    straight = Camera("PINHOLE", 64, 48, (60.0, 60.0, 32.0, 24.0))
    rng = np.random.default_rng(2)
    rgba = rng.integers(0, 65536, (48, 64, 4), dtype=np.uint16)
    rgba[..., 3] = np.where(np.arange(64) < 30, 0, 65535)[None, :]  # a hard alpha edge
    frames = [Frame("train/ü_0.png", 1, np.eye(4)), Frame("train/b.png", 2, np.eye(4))]
    images = {"train/ü_0.png": rgba, "train/b.png": rgba[..., :3]}
    model = CameraSet({1: distorted, 2: straight}, frames)
    out, pinhole, messages = direct_run(tmp_path, model, images, interpolation="lanczos")

    assert sorted(str(p.relative_to(out / "images")) for p in (out / "images").rglob("*.png")) == ["train/ü_0.png"]
    result = read_png(out / "images" / "train" / "ü_0.png")
    assert result.dtype == np.uint16 and result.shape == (48, 64, 4)
    map_x, map_y, _ = undistortion_maps(distorted)
    replicate = cv2.BORDER_REPLICATE
    colour = cv2.remap(np.ascontiguousarray(rgba[..., :3]), map_x, map_y, cv2.INTER_LANCZOS4, borderMode=replicate)
    alpha = cv2.remap(np.ascontiguousarray(rgba[..., 3]), map_x, map_y, cv2.INTER_LINEAR, borderMode=replicate)
    assert np.array_equal(result[..., :3], colour)  # same channel order, requested interpolation
    assert np.array_equal(result[..., 3], alpha)  # alpha: linear, a ramp with no ringing
    assert 0 < np.count_nonzero((alpha > 0) & (alpha < 65535))

    assert pinhole.hints.image_roots == {"train/ü_0.png": "undistort", "train/b.png": "ingest"}
    assert pinhole.cameras[2] == straight and pinhole.cameras[1].model == "PINHOLE"
    assert frame_image_path("train/ü_0.png", "undistort", tmp_path / "ingest" / "images", out / "images").is_file()
    moved = max_distortion_displacement(distorted)
    assert messages == [
        f"undistort: undistorted 1 image of camera 1 (max displacement {moved:.1f} px); "
        "1 camera within 0.5 px (max 0.00 px) passes through untouched"
    ]
    with pytest.raises(ValueError, match="image root"):
        frame_image_path("a.png", "sfm", tmp_path, tmp_path)


def test_a_model_that_does_not_match_the_ingest_images_is_refused(tmp_path):
    camera = Camera("PINHOLE", 64, 48, (60.0, 60.0, 32.0, 24.0))
    image = np.zeros((48, 64, 3), np.uint8)
    with pytest.raises(StageError, match="frame b.png is not an ingest image"):
        direct_run(tmp_path / "a", one_camera(camera, ["b.png"]), {"a.png": image})
    with pytest.raises(StageError, match=r"frame a.png is 64x48 pixels but its camera 1 is 32x24"):
        direct_run(tmp_path / "b", one_camera(camera.scaled(0.5), ["a.png"]), {"a.png": image})
