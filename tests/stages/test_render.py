"""The render stage on a model with a known answer: a solid cube built by hand into a small NerfField.

Orbit (inward 360, world rays clipped to the box) and spiral (forward-facing, NDC rays): the frames, the
videos and the camera path are all written with the right count and size, the cube shows at the centre of
every frame in its colour (sRGB-encoded for a linear RAW model) and the corners are empty.
(``nerf.analytic.SphereField`` cannot stand in: ``RadianceModel.save`` / ``load`` only know ``NerfField``.)
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from nerfpipe.artifacts import Bounds, Decision, FrameBounds, SceneDecisions
from nerfpipe.geometry.cameras import Camera, CameraSet, Frame, mean_camera
from nerfpipe.imaging.png import read_png, srgb_encode
from nerfpipe.nerf.policy import NDC_NEAR_FACTOR
from tests.nerf.fieldfns import paper_mlp
from nerfpipe.nerf.fields.mlp import NerfField
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.spaces.ray_space import BoxSpace, NdcSpace
from nerfpipe.nerf.samplers.configs import HierarchicalConfig
from nerfpipe.nerf.samplers.hierarchical import HierarchicalSampler
from nerfpipe.pipeline.budget import Allotment
from nerfpipe.pipeline.errors import ParamError, StageError
from nerfpipe.pipeline.params import build_params
from nerfpipe.pipeline.stage import StageContext, StageInputs
from nerfpipe.stages.render import RenderParams, RenderStage, render_size
from tests.helpers import VideoInfo, count_progress, look_at, read_mp4, video_info

COLOUR = np.array([0.8, 0.3, 0.1])
CAMERA = Camera.pinhole(60.0, 60.0, 32.0, 24.0, 64, 48)
NEAR, FAR = 0.5, 4.0


def cube_field(half: tuple[float, float, float], density: float = 100.0, sharpness: float = 1000.0) -> NerfField:
    """A NerfField that is a solid box |x_i| <= half_i of constant ``COLOUR``, set by hand.

    With raw coordinates in (no encoding) one ReLU layer of six units measures how far a point is outside
    each face, h = relu(+-x_i - half_i); sigma = relu(density - sharpness * sum(h)) is ``density`` inside and
    0 from density / sharpness = 0.1 outside. The colour branch has zero weights and sigmoid^-1(COLOUR) as
    the output bias.
    """
    config = paper_mlp(depth=1, width=6, view_width=4, pos_freqs=0, dir_freqs=0, include_input=True,
                         view_dependence=False, density_activation="relu")
    field = NerfField(config)
    with torch.no_grad():
        for p in field.parameters():
            p.zero_()
        trunk = field.trunk[0]
        for i in range(3):
            trunk.weight[2 * i, i], trunk.weight[2 * i + 1, i] = 1.0, -1.0
            trunk.bias[2 * i] = trunk.bias[2 * i + 1] = -half[i]
        field.density.weight.fill_(-sharpness)
        field.density.bias.fill_(density)
        field.rgb.bias.copy_(torch.logit(torch.tensor(COLOUR, dtype=torch.float32)))
    return field


def ring() -> list[np.ndarray]:
    """Eight cameras on a circle of radius 2 at height 0.8 (world z up), looking at the origin."""
    return [look_at(np.array([2 * np.cos(a), 2 * np.sin(a), 0.8]), np.zeros(3)) for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)]


def grid() -> list[np.ndarray]:
    """Six forward-facing cameras at y = -3 looking along +y."""
    return [look_at(np.array([x, -3.0, z]), np.array([x, 0.0, z])) for x in (-0.2, 0.0, 0.2) for z in (-0.1, 0.1)]


# world -> SfM: scale 2, a quarter turn about z, a shift; camera_path.json must carry poses through it
TO_SFM = np.array([[0.0, -2.0, 0.0, 1.0], [2.0, 0.0, 0.0, 2.0], [0.0, 0.0, 2.0, 3.0], [0.0, 0.0, 0.0, 1.0]])


def write_scene(folder: Path, layout: str, photometric: str = "srgb") -> StageInputs:
    """The five artifacts render reads, for a cube model of ``layout`` and its capture, written by hand."""
    c2ws = grid() if layout == "forward" else ring()
    world = CameraSet({1: CAMERA}, [Frame(f"img{i}.png", 1, c2w) for i, c2w in enumerate(c2ws)])
    (folder / "world").mkdir(parents=True)
    world.save(folder / "world")
    box = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
    frames = tuple(FrameBounds(f.name, NEAR, FAR, "rig") for f in world.frames)
    Bounds(np.linalg.inv(TO_SFM).tolist(), TO_SFM.tolist(), 0.5, [0.0, 0.0, 1.0], "inward", "rig", (box[0], box[1]),
           NEAR, FAR, frames).save(folder / "bounds.json")
    SceneDecisions(
        layout=Decision(layout, "by hand"), background=Decision("none", "by hand"),
        background_color=Decision(None, "by hand"), lens=Decision("pinhole", "by hand"),
        photometric=Decision(photometric, "by hand"), exposure_varies=Decision(False, "by hand"),
        near=NEAR, far=FAR, scene_box=(box[0], box[1]),
    ).save(folder / "scene.json")

    if layout == "forward":
        # the cube sits in NDC space, where the field is queried: the middle of x', y' and most of z'
        field = cube_field((0.3, 0.3, 0.9))
        ray_space = NdcSpace(tuple(map(tuple, mean_camera(np.array(c2ws)).tolist())), CAMERA.fx,
                             (CAMERA.width, CAMERA.height), NDC_NEAR_FACTOR * NEAR)
    else:
        field = cube_field((0.3, 0.3, 0.3))
        ray_space = BoxSpace((tuple(box[0]), tuple(box[1])))
    info = {"layout": layout, "photometric": photometric, "to_sfm": TO_SFM.tolist()}
    model = RadianceModel(field, None, HierarchicalSampler(HierarchicalConfig(n_coarse=32, n_fine=16)), ray_space, None, info)
    (folder / "train").mkdir()
    model.save(folder / "train")
    artifacts = {"model": folder / "train" / "model.pt", "model_json": folder / "train" / "model.json",
                 "cameras": folder / "world", "bounds": folder / "bounds.json", "scene": folder / "scene.json"}
    return StageInputs(artifacts, source=folder)


def run_render(tmp_path: Path, layout: str, photometric: str = "srgb", allotment: Allotment | None = None,
               **params) -> tuple[Path, dict, list]:
    inputs = write_scene(tmp_path / "in", layout, photometric)
    out = tmp_path / "out"
    out.mkdir()
    calls: list = []
    ctx = StageContext(log=logging.getLogger("test"), progress=count_progress(calls), allotment=allotment)
    summary = RenderStage().run(inputs, out, RenderParams(frames=4, short_side=0, scale=0.5, device="cpu", **params), ctx)
    return out, summary.to_json(), calls


def check_outputs(out: Path, summary: dict, calls: list, expected_rgb: np.ndarray) -> None:
    width, height = 32, 24  # the 64 x 48 camera at scale 0.5
    assert summary["frames"] == 4 and summary["resolution"] == [width, height]
    assert calls == [(4, "render"), 1, 1, 1, 1]
    for name in RenderStage.provides.values():
        assert (out / name).exists()
    assert sorted(p.name for p in (out / "frames").iterdir()) == [f"{k}_{i:04d}.png" for k in ("depth", "rgb") for i in range(4)]
    for i in range(4):
        rgb = read_png(out / "frames" / f"rgb_{i:04d}.png")
        depth = read_png(out / "frames" / f"depth_{i:04d}.png")
        assert rgb.shape == depth.shape == (height, width, 3) and rgb.dtype == np.uint8
        # every pose looks at the cube: its colour fills the centre; the corners see nothing (black)
        assert np.allclose(rgb[10:14, 14:18].reshape(-1, 3), expected_rgb * 255, atol=2)
        assert np.all(depth[10:14, 14:18].max(axis=-1) > 0)
        for corner in (rgb[0, 0], rgb[-1, -1], depth[0, 0], depth[-1, -1]):
            assert np.all(corner == 0)
    for video in ("render.mp4", "depth.mp4"):
        frames = read_mp4(out / video)
        assert len(frames) == 4 and all(f.shape == (height, width, 3) for f in frames)
        # what Chrome and Firefox play: H.264 in yuv420p, the index first
        assert video_info(out / video) == VideoInfo("h264", "yuv420p", 4, width, height, index_first=True)

    path = json.loads((out / "camera_path.json").read_text())
    assert path["camera"] == {"model": "PINHOLE", "width": 32, "height": 24, "params": [30.0, 30.0, 16.0, 12.0]}
    assert len(path["frames"]) == 4 and path["frames"][0]["rgb"] == "frames/rgb_0000.png"
    world = np.array([f["c2w"] for f in path["frames"]])
    sfm = np.array([f["c2w_sfm"] for f in path["frames"]])
    # centres through the similarity; rotations through its rotation part (the quarter turn) alone
    assert np.allclose(sfm[:, :3, 3], world[:, :3, 3] @ TO_SFM[:3, :3].T + TO_SFM[:3, 3])
    assert np.allclose(sfm[:, :3, :3], (TO_SFM[:3, :3] / 2.0) @ world[:, :3, :3])


def test_orbit_of_a_360_scene(tmp_path: Path) -> None:
    out, summary, calls = run_render(tmp_path, "inward360")
    assert summary["path"].startswith("orbit (inward360 scene, cameras all round: 315 deg of azimuth): radius 2.15")
    check_outputs(out, summary, calls, COLOUR)
    poses = np.array([f["c2w"] for f in json.loads((out / "camera_path.json").read_text())["frames"]])
    assert np.allclose(np.linalg.norm(poses[:, :3, 3], axis=1), np.sqrt(4.64)) and np.allclose(poses[:, 2, 3], 0.8)
    # along the viewing axis -c / |c| (c: the camera centre, |c| = 2.154) a visible point p of the cube is
    # |c| - p.c / |c| deep: 1.76 at the near top edge p = (0.3, 0, 0.3) of the first view, c = (2, 0, 0.8),
    # 2.32 at the far top edge (-0.3, 0, 0.3); the soft shell adds up to 0.1 outside. The colours span that.
    lo, hi = summary["depth_range"]
    assert 1.6 < lo < 1.85 and 2.0 < hi < 2.35


def test_spiral_of_a_forward_raw_scene_is_srgb_encoded(tmp_path: Path) -> None:
    out, summary, calls = run_render(tmp_path, "forward", photometric="linear_raw")
    assert summary["path"].startswith("spiral (forward scene): 2 turns around the mean camera")
    check_outputs(out, summary, calls, srgb_encode(COLOUR))


def test_frames_shrink_to_fit_a_job_budget_but_never_below_a_watchable_video(tmp_path: Path, monkeypatch, caplog) -> None:
    """A slow machine (an injected cost: 10 s a frame of 32 x 24) under a tight budget: the frames shrink to the
    stage's share, down to the floor of a video worth watching and no further; below it the stage renders at the
    floor and says in one line how much longer the job takes."""
    import nerfpipe.nerf.throughput as throughput
    from nerfpipe.stages import render as stage

    # 10 s a frame of 32 x 24, whatever size a frame is timed at, and 0.025 s each beside: 4 frames of 32 x 24, 40.1 s
    monkeypatch.setattr(throughput, "timed_view", lambda *args: (10.0 * args[3] * args[4] / (32 * 24), None))
    caplog.set_level(logging.INFO, "test")
    _, summary, _ = run_render(tmp_path / "big", "inward360", allotment=Allotment(11.0, 110.0))
    # the real floor, 360 pixels on the short side, is above these frames' 24: they are not shrunk at all
    assert summary["resolution"] == [32, 24]
    assert re.search(r"render: 4 frames at 32x24 \(never smaller than 360 pixels on the short side, or the size asked "
                     r"for\) takes about 40 s, 29 s more than its 11 s \(10% of the 1 min 50 s budget\): the job takes "
                     r"that much longer", caplog.text)
    # the same floor where the stages before saved 40 s beyond the shares still to come: it takes 29 of them, and
    # the job keeps its budget
    caplog.clear()
    _, summary, _ = run_render(tmp_path / "saved", "inward360", allotment=Allotment(11.0, 110.0, spare=40.0))
    assert summary["resolution"] == [32, 24] and "takes that much longer" not in caplog.text
    assert "about 40 s to fit its 11 s (10% of the 1 min 50 s budget, and 40 s the stages before it saved)" in caplog.text
    monkeypatch.setattr(stage, "VIDEO_FLOOR_SIDE", 12)  # a floor of half each side of these tiny frames
    caplog.clear()
    _, summary, _ = run_render(tmp_path / "roomy", "inward360", allotment=Allotment(600.0, 6000.0))
    assert summary["resolution"] == [32, 24] and "takes that much longer" not in caplog.text
    assert "about 40 s to fit its 10 min (10% of the 100 min budget)" in caplog.text
    _, summary, _ = run_render(tmp_path / "tight", "inward360", allotment=Allotment(22.0, 220.0))
    # 22 s of 40.1 s: 0.73 of each side (sqrt 21.9 / 40, rounded down to hundredths), less the milliseconds of loading
    assert summary["resolution"] == [24, 18] and "32x24 would take 40 s" in caplog.text
    assert "takes that much longer" not in caplog.text
    # what the stages before saved pays for a floor, never for a larger video
    _, summary, _ = run_render(tmp_path / "tight_saved", "inward360", allotment=Allotment(22.0, 220.0, spare=1000.0))
    assert summary["resolution"] == [24, 18]
    _, summary, _ = run_render(tmp_path / "starved", "inward360", allotment=Allotment(0.001, 100.0))
    assert summary["resolution"] == [16, 12]  # the floor, not smaller
    assert re.search(r"render: 4 frames at 16x12 \(never smaller than 12 pixels on the short side, or the size asked "
                     r"for\) takes about 10 s, 10 s more than its 0 s .*: the job takes that much longer", caplog.text)
    # and when even that costs more than the whole job's budget, the stage says so instead of overrunning it
    with pytest.raises(StageError, match=r"render: 4 frames, even at 16x12, would take about \d+ s, more than the job's "
                                         r"whole budget of 0 s; lower render.frames, or pass --budget off"):
        run_render(tmp_path / "hopeless", "inward360", allotment=Allotment(0.001, 0.01))


def test_path_and_elevation_can_be_chosen(tmp_path: Path) -> None:
    out, summary, _ = run_render(tmp_path, "inward360", path="orbit", elevation="30")
    assert "30.0 deg elevation (given)" in summary["path"]
    poses = np.array([f["c2w"] for f in json.loads((out / "camera_path.json").read_text())["frames"]])
    assert np.allclose(poses[:, 2, 3], np.sqrt(4.64) * 0.5)  # radius x sin 30 deg


def test_a_keyframe_camera_path_is_rendered_frame_by_frame_with_its_fields_of_view(tmp_path: Path) -> None:
    """What the viewer's panel saves: its frames and fps apply, each frame zoomed to its field of view; the
    render's own camera_path.json renders the same frames again."""
    from nerfpipe.export.camera_path import CameraPath, Keyframe

    keys = (Keyframe(ring()[0], 40.0), Keyframe(ring()[2], 60.0), Keyframe(ring()[4], 40.0))
    path = CameraPath(keys, frames=5, fps=8.0)
    path.save(tmp_path / "keyed.json")
    out, summary, calls = run_render(tmp_path / "a", "inward360", path=str(tmp_path / "keyed.json"))
    assert summary["frames"] == 5 and summary["fps"] == 8.0 and calls[0] == (5, "render")
    assert summary["path"] == f"the camera path of {tmp_path / 'keyed.json'}: 3 keyframes, 5 frames at 8 fps"
    written = json.loads((out / "camera_path.json").read_text())
    poses, fovs = path.sample()
    assert np.allclose([f["c2w"] for f in written["frames"]], poses)
    assert [f["fov"] for f in written["frames"]] == pytest.approx(list(fovs))
    assert fovs[0] == pytest.approx(40.0) and fovs[2] == pytest.approx(60.0)
    # the keyframe at 60 deg sees the cube smaller than the one at 40 deg from the same distance
    cube = [int((read_png(out / "frames" / f"rgb_{i:04d}.png").sum(axis=-1) > 30).sum()) for i in (0, 2, 4)]
    assert cube[1] < 0.7 * cube[0] and cube[2] == pytest.approx(cube[0], rel=0.15)  # frames 0, 2 and 4
    again, _, _ = run_render(tmp_path / "b", "inward360", path=str(out / "camera_path.json"))
    assert np.allclose([f["c2w"] for f in json.loads((again / "camera_path.json").read_text())["frames"]], poses)
    assert (read_png(again / "frames" / "rgb_0002.png") == read_png(out / "frames" / "rgb_0002.png")).all()
    # and so does the path it wrote in nerfstudio's schema, in the SfM frame (TO_SFM away from the world)
    nerfstudio = json.loads((out / "camera_path.nerfstudio.json").read_text())
    assert len(nerfstudio["camera_path"]) == 5 and nerfstudio["render_width"] == summary["resolution"][0]
    assert [c["fov"] for c in nerfstudio["camera_path"]] == pytest.approx(list(fovs))
    third, _, _ = run_render(tmp_path / "c", "inward360", path=str(out / "camera_path.nerfstudio.json"))
    assert np.allclose([f["c2w"] for f in json.loads((third / "camera_path.json").read_text())["frames"]], poses)
    assert np.abs(read_png(third / "frames" / "rgb_0002.png").astype(int) - read_png(out / "frames" / "rgb_0002.png")).max() <= 1


def test_a_camera_path_file_enters_the_cache_key(tmp_path: Path, monkeypatch) -> None:
    from nerfpipe.export.camera_path import CameraPath, Keyframe
    from nerfpipe.pipeline.fingerprint import FingerprintCache

    path = tmp_path / "keyed.json"
    CameraPath((Keyframe(ring()[0], 40.0),), frames=3).save(path)
    monkeypatch.chdir(tmp_path)
    params = build_params("render", RenderParams, RenderStage.presets, None, {"path": "keyed.json"})
    assert params.path == str(path.resolve())  # the same file whichever folder status runs from
    (file,) = RenderStage().input_files(tmp_path / "capture", params)
    fingerprint = FingerprintCache(tmp_path / "fp.json").fingerprint(file, tmp_path / "capture")
    assert fingerprint.relpath == path.resolve().as_posix()  # outside the capture: known by its absolute path
    assert RenderStage().input_files(tmp_path / "capture", RenderParams()) == []
    with pytest.raises(ParamError, match="render: path must be one of auto, spiral, orbit, sweep or an existing "
                                         "camera_path.json file, got 'nowhere.json'"):
        build_params("render", RenderParams, RenderStage.presets, None, {"path": "nowhere.json"})


def test_params_presets_and_errors(tmp_path: Path) -> None:
    for preset in RenderStage.presets:
        build_params("render", RenderParams, RenderStage.presets, preset, {})
    full = build_params("render", RenderParams, RenderStage.presets, "full", {})
    assert (full.frames, full.scale, full.max_side) == (120, 1.0, 0)
    with pytest.raises(ParamError, match="elevation"):
        build_params("render", RenderParams, RenderStage.presets, None, {"elevation": "high"})
    with pytest.raises(ParamError, match="elevation"):
        build_params("render", RenderParams, RenderStage.presets, None, {"elevation": "90"})
    with pytest.raises(ParamError, match="scale"):
        build_params("render", RenderParams, RenderStage.presets, None, {"scale": "0"})
    photo = Camera.pinhole(100, 100, 50, 37, 101, 75)
    assert render_size(photo, 0.5) == (50, 38)  # even sides: 50.5 -> 50, 37.5 -> 38
    assert render_size(photo, 2.0, max_side=80) == (80, 60)  # 202 x 150 shrunk to fit 80: 80 x 59.4 -> 60
    # the default: 360 pixels on the short side, whatever the photos' size, for 3 s
    default = RenderParams()
    assert render_size(Camera.pinhole(1e3, 1e3, 800, 600, 1600, 1200), default.scale, default.max_side,
                       default.short_side) == (480, 360)
    assert render_size(Camera.pinhole(1e3, 1e3, 360, 640, 720, 1280), default.scale, default.max_side,
                       default.short_side) == (360, 640)
    assert render_size(photo, default.scale, default.max_side, default.short_side) == (484, 360)  # 484.8 -> 484
    assert default.frames / default.fps >= 3.0
    if not torch.cuda.is_available():
        inputs = write_scene(tmp_path, "inward360")
        with pytest.raises(StageError, match="render.device=cuda"):
            RenderStage().run(inputs, tmp_path / "out", RenderParams(device="cuda"), StageContext(log=logging.getLogger("test")))


def test_describe() -> None:
    summary = {"frames": 40, "resolution": [200, 150], "fps": 20.0, "seconds_per_frame": 1.234, "device": "cpu",
               "path": "orbit (inward360 scene): radius 2.15 around (0, 0, 0) at 21.8 deg elevation (the cameras' mean)"}
    assert RenderStage().describe(Path("."), {"summary": summary}) == [
        "40 frames of 200x150 at 20 fps, 1.23 s a frame on cpu",
        "path: orbit (inward360 scene): radius 2.15 around (0, 0, 0) at 21.8 deg elevation (the cameras' mean)",
    ]
    assert RenderStage().describe(Path("."), {}) == []


def test_depth_maps_shrink_to_a_job_budget_but_never_below_a_quarter_of_the_photos_side(monkeypatch, caplog) -> None:
    """export_depth's sizing under an injected cost (1 s a view at full size): the share it is given, down to
    a quarter of the photos' side, and at that floor one line saying how much longer the job takes."""
    import time

    import nerfpipe.nerf.throughput as throughput
    from nerfpipe.stages.export_depth import ExportDepthParams, ExportDepthStage
    from tests.nerf.scenes import world_of_one_camera

    world = world_of_one_camera()  # one 40 x 30 camera
    monkeypatch.setattr(throughput, "timed_view", lambda *args: (1.0 * (args[3] * args[4]) / (40 * 30), None))
    caplog.set_level(logging.INFO, "test")

    def scale(seconds: float, asked: float = 1.0) -> float:
        ctx = StageContext(log=logging.getLogger("test"), progress=count_progress([]), allotment=Allotment(seconds, 10 * seconds))
        return ExportDepthStage._fitting_scale(None, world.frames, world, {"a.png": (1.0, 5.0)},
                                               ExportDepthParams(scale=asked), ctx, time.perf_counter())[0]

    assert scale(100.0) == 1.0  # 1.15 s fits
    assert 0.5 <= scale(0.3) < 0.52  # sqrt(0.3 / 1.15) = 0.51
    assert "takes that much longer" not in caplog.text
    assert scale(0.001) == 0.25  # the floor
    assert re.search(r"export_depth: 1 views at 10x8 \(never smaller than a quarter of the photos' side\) takes about "
                     r"0 s, 0 s more than its 0 s .*the job takes that much longer", caplog.text)
    assert scale(0.001, asked=0.1) == 0.1  # asked smaller than the floor: as asked, never shrunk


def test_depth_maps_are_timed_at_their_floor_and_keep_that_view_where_they_take_that_size(monkeypatch, caplog) -> None:
    """The first view is timed at the least size the maps may take (its render kept where they take it): at the
    floor where the scale asked for is larger, at the scale asked for where that is smaller."""
    import time

    import nerfpipe.nerf.throughput as throughput
    from nerfpipe.stages.export_depth import ExportDepthParams, ExportDepthStage
    from tests.nerf.scenes import world_of_one_camera

    world = world_of_one_camera()  # one 40 x 30 camera
    timed: list = []
    monkeypatch.setattr(throughput, "timed_view", lambda *args: timed.append(args[3:5]) or (1e-3 * args[3] * args[4],
                                                                                             {"view": args[3:5]}))

    def fit(seconds: float, asked: float) -> tuple:
        ctx = StageContext(log=logging.getLogger("test"), progress=count_progress([]), allotment=Allotment(seconds, 10 * seconds))
        return ExportDepthStage._fitting_scale(None, world.frames, world, {"a.png": (1.0, 5.0)},
                                               ExportDepthParams(scale=asked), ctx, time.perf_counter())

    assert fit(0.001, 1.0) == (0.25, {"view": (10, 8)}) and timed == [(10, 8)]  # at the floor: the view timed
    assert fit(100.0, 1.0) == (1.0, None) and timed[-1] == (10, 8)  # 40 x 30 fits: timed at the floor, not kept
    assert fit(100.0, 0.1) == (0.1, {"view": (4, 3)}) and timed[-1] == (4, 3)  # asked below the floor


def test_the_frames_timed_are_frames_of_the_video_not_rendered_again(tmp_path: Path, monkeypatch) -> None:
    """The render stage prices its video on frames spread along the path, timed at the least size the video may
    take: where it takes that size, those renders are its frames (four frames cost four renders); where it is
    larger, they are not theirs."""
    from nerfpipe.nerf.model import RadianceModel
    from nerfpipe.stages import render as stage

    sizes: list = []
    render_image = RadianceModel.render_image
    monkeypatch.setattr(RadianceModel, "render_image",
                        lambda self, k, c2w, w, h, *rest: sizes.append((w, h)) or render_image(self, k, c2w, w, h, *rest))
    out, summary, calls = run_render(tmp_path / "kept", "inward360")
    assert sizes == [(32, 24)] * 4  # the floor (360 pixels) is above these frames: timed at their size, all kept
    check_outputs(out, summary, calls, COLOUR)  # the frames timed as right as the others would be
    sizes.clear()
    monkeypatch.setattr(stage, "VIDEO_FLOOR_SIDE", 12)
    _, summary, _ = run_render(tmp_path / "floor", "inward360", allotment=Allotment(0.001, 100.0))
    assert summary["resolution"] == [16, 12] and sizes == [(16, 12)] * 4  # at the floor: timed there and kept
    sizes.clear()
    _, summary, _ = run_render(tmp_path / "roomy", "inward360", allotment=Allotment(600.0, 6000.0))
    assert summary["resolution"] == [32, 24] and sizes == [(16, 12)] * 4 + [(32, 24)] * 4


def test_a_video_is_priced_on_frames_spread_along_its_path() -> None:
    """Four frames at the middles of four equal stretches of the path (or every frame of a shorter one): a sweep
    out and back mirrors frame i in frame n - 1 - i, and so do they."""
    from nerfpipe.stages.render import spread

    assert spread(45) == [5, 16, 28, 39] and all(44 - i in spread(45) for i in spread(45))
    assert spread(120) == [15, 45, 75, 105] and spread(4) == [0, 1, 2, 3] and spread(3) == [0, 1, 2] and spread(1) == [0]
