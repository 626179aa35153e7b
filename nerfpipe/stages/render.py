"""render: novel views of the trained model along a path that suits the scene, as PNG frames and MP4s.

A forward-facing capture is only seen from the front, so its video follows LLFF's spiral around the mean
camera (the path of the NeRF paper's forward-facing videos); a 360° capture whose cameras go all round
gets an orbit about the world's up (the bounds stage's +z, whatever the photos' roll) around the scene box
centre, at the distance and elevation of its photos; one whose cameras cover less of the circle (a phone
walked part way round) gets a sweep out and back along them, looking where their axes converge, so the
video never leaves the region the photos saw (``nerfpipe.export.paths``). Each frame is rendered
with the first training camera's intrinsics, scaled by ``scale``: far from every photo, a new view is still
seen through the lens the model was trained on.

Writes ``frames/rgb_0000.png`` ... and ``frames/depth_0000.png`` ... (depth coloured as
``nerfpipe.export.video`` documents), ``render.mp4`` and ``depth.mp4``, and ``camera_path.json``: the
intrinsics and every pose, in the normalized world and in the SfM frame (through bounds' ``to_sfm``), so
the same path can be rendered again or brought into another tool. Linear RAW models are sRGB-encoded on
the way out, as their previews in train are.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Literal, Mapping, Sequence

import numpy as np

from nerfpipe.artifacts import BOUNDS, CAMERAS, SCENE
from nerfpipe.geometry.cameras import Camera, CameraSet
from nerfpipe.imaging.png import read_png, srgb_encode, write_png
from nerfpipe.nerf.presets import gpu_preset
from nerfpipe.pipeline.budget import Fit, FloorWork, check_affordable, fit_within
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.summary import Summary
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs
from nerfpipe.pipeline.store import write_json_atomic

# Percentiles of the first frame's depth (over pixels with a surface) that set the colour range of the
# depth video: one range for all frames, so a colour means the same depth throughout, without the far
# bound of an unbounded scene squeezing the object into one colour. The same rule serves whatever depth
# ``render_image`` gives (world depth, or a forward-facing model's NDC t' = 1 - near / z, coloured as is):
# both grow with distance, so near stays red and far blue.
DEPTH_RANGE_PERCENTILES = (2.0, 98.0)


PATH_KINDS = ("auto", "spiral", "orbit", "sweep")
# the least a video is worth watching at: this many pixels on its short side, at least 3 s (issue 47)
VIDEO_FLOOR_SIDE = 360


@dataclass(frozen=True)
class RenderParams:
    frames: int = field(default=45, metadata={"bounds": (1, 100_000), "help": "frames along the path (45 at 15 fps: 3 s)"})
    fps: float = field(default=15.0, metadata={"bounds": (1.0, 240.0), "help": "frames per second of the videos"})
    short_side: int = field(default=VIDEO_FLOOR_SIDE, metadata={"bounds": (0, 4320), "help": "the frames' short side in pixels, the "
                            "first training camera's aspect kept (360: the least worth watching; 4320: 8K); 0: its size times scale"})
    scale: float = field(default=0.5, metadata={"bounds": (0.01, 4.0), "help": "with short_side 0: render size relative to the first training camera (0.5: half width and height)"})
    max_side: int = field(default=0, metadata={"bounds": (0, 16_384), "help": "with short_side 0: cap on the longest side of the render in pixels, after scale (0: none)"})
    path: str = field(
        default="auto", metadata={"help": "camera path: auto, spiral, orbit, sweep, or a camera_path.json (keyframes "
                                          "recorded in `nerfpipe view --web`; its frames and fps apply); auto: "
                                          "spiral for forward-facing scenes, orbit around the world's up for 360° "
                                          "ones whose cameras go all round (300° or more), else a sweep out and "
                                          "back along the cameras"}
    )
    n_rotations: float = field(default=2.0, metadata={"bounds": (0.01, 100.0), "help": "spiral: turns around the mean camera (LLFF: 2)"})
    elevation: str = field(default="auto", metadata={"help": "orbit: degrees above the target, or auto (the cameras' mean)"})
    chunk: int = field(default=4096, metadata={"keyed": False, "bounds": (1, 1_048_576), "help": "rays per chunk while rendering (4096: measured fastest on a 2-core CPU, scripts/bench_throughput.py)"})
    device: Literal["auto", "cpu", "cuda"] = field(default="auto", metadata={"keyed": False, "help": "auto: CUDA when present, else CPU"})

    def __post_init__(self) -> None:
        if self.path not in PATH_KINDS:
            file = Path(self.path).expanduser()
            if file.suffix.lower() != ".json" or not file.is_file():
                raise ValueError(f"path must be one of {', '.join(PATH_KINDS)} or an existing camera_path.json file, "
                                 f"got {self.path!r}")
            object.__setattr__(self, "path", str(file.resolve()))  # the same file from wherever status runs
        for name in ("frames", "chunk"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not self.fps > 0:
            raise ValueError(f"fps must be > 0, got {self.fps}")
        if not 0 < self.scale <= 4:
            raise ValueError(f"scale must be in (0, 4], got {self.scale}")
        if self.short_side == 1:
            raise ValueError(f"short_side must be 0 (scale decides) or at least 2, got {self.short_side}")
        if self.max_side < 0 or self.max_side == 1:
            raise ValueError(f"max_side must be 0 (no cap) or at least 2, got {self.max_side}")
        if not self.n_rotations > 0:
            raise ValueError(f"n_rotations must be > 0, got {self.n_rotations}")
        if self.elevation != "auto":
            try:
                degrees = float(self.elevation)
            except ValueError:
                raise ValueError(f"elevation must be auto or degrees, got {self.elevation!r}") from None
            if not -90 < degrees < 90:
                raise ValueError(f"elevation must be in (-90, 90) degrees, got {degrees}")

    def elevation_degrees(self) -> float | None:
        return None if self.elevation == "auto" else float(self.elevation)


# The default is the floor of a video worth watching: 3 s (45 frames at 15 fps) of 360 pixels on the short side
# (480 x 360 for 4:3 photos, 360 x 640 for portrait phone photos). The preview: 12 frames of at most 96 x 72.
# Under a job budget the frames shrink to fit the stage's share, never below that floor (or the size asked for,
# when that is smaller); when even that does not fit, the job takes longer and says so. A frame costs its rays,
# timed, and this much beside: two PNGs written, read back and encoded into the videos (21 ms measured at 480x360
# and 360x640; until 2026-12-06 a tenth of the rays' time was added instead, which priced the cup's video at 146 s
# where it took 126).
FRAME_SECONDS = 0.025
# The frames timed to price the video, spread along its path: its middle frame alone, the far end of a sweep out
# and back along the photos, priced beer's video at 173 s where it took 148 s. The cup's 45 frames, each timed
# (docs/benchmarks.md): 2.58 s on average, and 2.50-2.60 s over these four.
TIMED_FRAMES = 4
PREVIEW = {"frames": 12, "short_side": 0, "scale": 0.25, "max_side": 96}
FULL = {"frames": 120, "short_side": 0, "scale": 1.0, "max_side": 0}


def render_size(camera: Camera, scale: float, max_side: int = 0, short_side: int = 0) -> tuple[int, int]:
    """(width, height) of the renders: the camera's with its short side ``short_side`` pixels, or (0) its size
    times ``scale``, shrunk to fit ``max_side`` (0: no cap); its aspect kept, rounded to even numbers (MPEG-4
    encodes 2x2 chroma blocks and would otherwise crop or pad the video), at least 2 x 2."""
    if short_side:
        scale = short_side / min(camera.width, camera.height)
    width, height = camera.width * scale, camera.height * scale
    if max_side and max(width, height) > max_side:
        shrink = max_side / max(width, height)
        width, height = width * shrink, height * shrink
    return even(width), even(height)


@dataclass(frozen=True)
class RenderSummary(Summary):
    """The video: its frames, path, size, rate and what a frame cost, and the depth range its colours span."""

    frames: int = 0
    path: str = ""
    seconds_per_frame: float = 0.0
    resolution: list[int] = field(default_factory=lambda: [0, 0])  # width, height
    fps: float = 0.0
    device: str = ""
    depth_range: list[float] | None = None

    def describe(self) -> list[str]:
        if not self.frames:
            return []
        width, height = self.resolution
        return [f"{self.frames} frames of {width}x{height} at {self.fps:g} fps, {self.seconds_per_frame:.2f} s a frame "
                f"on {self.device}", f"path: {self.path}"]


class RenderStage(Stage):
    """Render novel views along a spiral (forward-facing) or an orbit (360°): PNG frames, MP4s, the path."""

    name = "render"
    version = 8  # 8: camera_path.nerfstudio.json too; 7: sweeps framed on the largest gap; 6: orbits from 300 deg of azimuth (270 before); 5: keyframe paths
    Params = RenderParams
    Summary = RenderSummary
    presets = {
        "preview": PREVIEW,
        "draft": PREVIEW,  # with ingest's and the others' draft: a quick run end to end
        # the length of the NeRF paper's videos (120 frames), at the training resolution
        "full": FULL,
        "gpu": {"short_side": 0, "scale": 1.0, "max_side": 1920},  # a CUDA device's: the photos' size, at most 1080p
        "paper": FULL,
    }
    requires = ("model", "model_json", "cameras", "bounds", "scene")
    provides = {"video": "render.mp4", "depth_video": "depth.mp4", "frames": "frames", "camera_path": "camera_path.json",
                "camera_path_nerfstudio": "camera_path.nerfstudio.json"}
    libraries = ("torch", "numpy", "av", "matplotlib")
    accelerated = True
    budget_share = 0.10
    optional = True

    def machine_preset(self, overrides: Mapping[str, Any]) -> tuple[str, str] | None:
        return gpu_preset(overrides, "the video at the photos' size, at most 1080p")

    def input_files(self, source: Path, params: RenderParams) -> list[Path]:
        """A camera path file, when ``path`` names one: its content enters the cache key."""
        return [] if params.path in PATH_KINDS else [Path(params.path)]

    def floor_work(self, params: RenderParams, world: CameraSet, *rest: Any) -> FloorWork | None:
        """The video at its floor (``VIDEO_FLOOR_SIDE``, or the size asked for when smaller): its frames' rays, as
        ``_run`` weighs them, and each frame's fixed cost."""
        from nerfpipe.export.camera_path import CameraPath

        if not world.frames:
            return None
        frames = params.frames if params.path in PATH_KINDS else CameraPath.load(Path(params.path)).frames
        width, height = floor_size(render_size(world.camera_of(world.frames[0]), params.scale, params.max_side,
                                               params.short_side))
        # a path of its own renders over the bounds' whole depth range (``_run``): priced at that range's rate
        return FloorWork(float(frames * width * height), FRAME_SECONDS * frames,
                         f"the video, {frames} frames at {width}x{height}", "scene" if params.path in PATH_KINDS else None)

    def run(self, inputs: StageInputs, out: Path, params: RenderParams, ctx: StageContext) -> RenderSummary:
        from nerfpipe.nerf.device import rendering_device

        with rendering_device(params.device, "render.device") as device:
            return self._run(inputs, out, params, ctx, device)

    def _run(self, inputs: StageInputs, out: Path, params: RenderParams, ctx: StageContext, device) -> RenderSummary:
        from nerfpipe.export.camera_path import CameraPath, fov_of, nerfstudio_path, view_range
        from nerfpipe.export.paths import path_for_scene, transform_poses
        from nerfpipe.geometry.normalize import Similarity
        from nerfpipe.export.video import write_mp4
        from nerfpipe.nerf.model import RadianceModel
        from nerfpipe.nerf.throughput import timed_view

        began = time.perf_counter()
        model = RadianceModel.load(inputs["model"].parent, device)
        world = inputs.load(CAMERAS)  # the training cameras as refined
        bounds = inputs.load(BOUNDS)
        layout = inputs.load(SCENE).layout.value
        if not world.frames:
            raise StageError("render: the normalized world has no cameras to build a path from; check the bounds stage")

        camera = world.camera_of(world.frames[0])
        fps, fovs = params.fps, None
        if params.path in PATH_KINDS:
            c2ws = np.array([f.c2w for f in world.frames])
            lo, hi = bounds.box()
            try:
                poses, description = path_for_scene(layout, c2ws, bounds.near, bounds.far, (lo + hi) / 2.0,
                                                    params.frames, kind=params.path, n_rotations=params.n_rotations,
                                                    elevation=params.elevation_degrees())
            except ValueError as err:
                raise StageError(f"render: cannot build the {params.path} camera path of this capture: {err}") from None
        else:
            keyed = CameraPath.load(Path(params.path))
            poses, fovs = keyed.sample()
            if keyed.frame == "sfm":  # nerfstudio's schema: in the SfM frame of the exported transforms.json
                poses = transform_poses(poses, Similarity.from_matrix(np.asarray(bounds.to_sfm)).inverse().matrix())
            fps = keyed.fps
            description = (f"the camera path of {params.path}: {len(keyed.keyframes)} keyframes, {keyed.frames} frames "
                           f"at {fps:g} fps{', looped' if keyed.loop else ''}")
        ctx.log.info("render: %s", description)
        # a path along the photos' cameras has their depth range; keyframes anywhere, each its own around the scene
        ranges = [(bounds.near, bounds.far) if fovs is None else view_range(c2w, bounds.far) for c2w in poses]

        def lens(width: int, height: int) -> list[Camera]:
            """Each frame's camera at ``width`` x ``height``: the first training camera's, zoomed to each keyframe's."""
            scaled = camera.scaled(width / camera.width, height / camera.height)
            return [scaled] * len(poses) if fovs is None else [with_fov(scaled, fov) for fov in fovs]

        # priced on a few frames spread along the path, at the least size the video may take: kept where it does
        wanted = render_size(camera, params.scale, params.max_side, params.short_side)
        least, timed = floor_size(wanted), {}
        views, loaded = lens(*least), time.perf_counter() - began  # the frames timed are priced among the others
        for i in spread(len(poses)):
            timed[i] = timed_view(model, views[i].intrinsics, poses[i], *least, *ranges[i], params.chunk)
            per_ray = sum(spent for spent, _ in timed.values()) / (len(timed) * least[0] * least[1])
            # a video the whole job could not afford even at its floor is refused at once, not timed further
            check_affordable(ctx.allotment, per_ray * len(poses) * least[0] * least[1] + FRAME_SECONDS * len(poses),
                             f"render: {len(poses)} frames, even at {least[0]}x{least[1]},", "lower render.frames")
        def fitting(spent: float) -> tuple[Fit, tuple[int, int]]:
            fit = fit_within(ctx.allotment, spent, per_ray * len(poses) * wanted[0] * wanted[1],
                             min(1.0, VIDEO_FLOOR_SIDE / min(wanted)), FRAME_SECONDS * len(poses))
            return fit, (even(wanted[0] * fit.scale), even(wanted[1] * fit.scale))

        fit, (width, height) = fitting(loaded)
        if (width, height) != least:  # larger: the frames timed are not the video's, and their time is spent
            fit, (width, height) = fitting(time.perf_counter() - began)
        fits = "" if ctx.allotment is None else f" to fit its {ctx.allotment.describe()}" + (
            f"; {wanted[0]}x{wanted[1]} would take {per_ray * len(poses) * wanted[0] * wanted[1]:.0f} s"
            if (width, height) != wanted else "")
        if (longer := fit.longer(f"render: {len(poses)} frames at {width}x{height} (never smaller than {VIDEO_FLOOR_SIDE} "
                                 "pixels on the short side, or the size asked for)", ctx.allotment)) is not None:
            ctx.log.warning(longer)
        ctx.log.info("render: %d frames of %dx%d (the camera of %s scaled by %.3g) on %s, about %.0f s%s", len(poses),
                     width, height, world.frames[0].name, width / camera.width, device,
                     per_ray * len(poses) * width * height, fits)

        cameras = lens(width, height)
        started = time.perf_counter()
        # the frames timed are frames of the video where it takes their size: not rendered again
        done = {i: view for i, (_, view) in timed.items() if view is not None and (width, height) == least}
        depth_range = render_frames(model, poses, cameras, ranges, out / "frames", params.chunk, ctx, done)
        seconds = time.perf_counter() - started + sum(timed[i][0] for i in done)  # the kept frames' renders too
        count = write_mp4(read_frames(out / "frames", "rgb", len(poses)), out / "render.mp4", fps)
        write_mp4(read_frames(out / "frames", "depth", len(poses)), out / "depth.mp4", fps)

        to_sfm = np.asarray(model.info.get("to_sfm", bounds.to_sfm), dtype=np.float64)
        write_json_atomic(out / "camera_path.json", camera_path_json(
            description, layout, fps, cameras, (bounds.near, bounds.far), depth_range, to_sfm, poses))
        write_json_atomic(out / "camera_path.nerfstudio.json", nerfstudio_path(
            transform_poses(poses, to_sfm), np.array([fov_of(c.height, c.fy) for c in cameras]), width, height, fps))
        per_frame = seconds / max(len(poses), 1)
        ctx.log.info("render: %d frames in %.1f s (%.2f s a frame) -> render.mp4, depth.mp4", count, seconds, per_frame)
        return RenderSummary(
            frames=count,
            path=description,
            seconds_per_frame=round(per_frame, 3),
            resolution=[width, height],
            fps=fps,
            device=str(device),
            depth_range=[round(v, 6) for v in depth_range] if depth_range is not None else None,
        )


def floor_size(wanted: tuple[int, int]) -> tuple[int, int]:
    """(width, height) of the least video worth watching of frames ``wanted`` (``VIDEO_FLOOR_SIDE`` on the short
    side, or ``wanted`` where that is smaller): even sides, the aspect kept."""
    floor = min(1.0, VIDEO_FLOOR_SIDE / min(wanted))
    return even(wanted[0] * floor), even(wanted[1] * floor)


def even(side: float) -> int:
    """A side of a video frame: the nearest even number of pixels (MPEG-4 encodes 2x2 chroma blocks), at least 2."""
    return max(2, 2 * round(side / 2))


def spread(count: int, k: int = TIMED_FRAMES) -> list[int]:
    """Up to ``k`` frames of a path of ``count``, at the middles of ``k`` equal stretches of it: the frames that
    price a video. For even ``k`` they pair up as frame i and frame count - 1 - i, as a sweep out and back does."""
    return sorted({min(count - 1, (2 * j + 1) * count // (2 * k)) for j in range(k)})


def with_fov(camera: Camera, fov: float) -> Camera:
    """``camera`` (a pinhole) zoomed to the vertical field of view ``fov`` (degrees), its pixel aspect kept."""
    from nerfpipe.export.camera_path import focal_of

    fy = focal_of(camera.height, fov)
    return Camera.pinhole(fy * camera.fx / camera.fy, fy, camera.cx, camera.cy, camera.width, camera.height)


def render_frames(model, poses: np.ndarray, cameras: Sequence[Camera], ranges: Sequence[tuple[float, float]],
                  folder: Path, chunk: int, ctx: StageContext,
                  done: Mapping[int, Mapping[str, Any]] | None = None) -> tuple[float, float] | None:
    """Render each pose (N, 4, 4) with its camera of ``cameras`` (N, all of one size) and its (near, far) of
    ``ranges`` into ``folder/rgb_NNNN.png`` and a coloured ``depth_NNNN.png``; returns the depth colour
    range, fixed by the first frame (None without frames). ``done``: frames already rendered, by index
    (``RadianceModel.render_image``'s maps), written as they are."""
    from nerfpipe.export.video import colorize_depth

    linear = model.info.get("photometric") == "linear_raw"
    folder.mkdir(parents=True, exist_ok=True)
    depth_range: tuple[float, float] | None = None
    with ctx.progress(len(poses), "render") as advance:
        for i, (c2w, camera, near_far) in enumerate(zip(poses, cameras, ranges)):
            began = time.perf_counter()
            result = (done or {}).get(i) or model.render_image(camera.intrinsics, c2w, camera.width, camera.height,
                                                               *near_far, chunk)
            rgb = result["rgb"].clamp(0.0, 1.0).numpy()
            depth, acc = result["depth"].numpy(), result["acc"].numpy()
            if depth_range is None:
                depth_range = depth_colour_range(depth, acc, *near_far)
            shown = srgb_encode(rgb) if linear else rgb
            write_png(folder / f"rgb_{i:04d}.png", np.round(np.clip(shown, 0.0, 1.0) * 255).astype(np.uint8))
            write_png(folder / f"depth_{i:04d}.png", colorize_depth(depth, acc, *depth_range))
            advance(1, info=f"frame {i + 1}: {time.perf_counter() - began:.1f} s")
    return depth_range


def camera_path_json(description: str, layout: str, fps: float, cameras: Sequence[Camera],
                     near_far: tuple[float, float], depth_range: tuple[float, float] | None, to_sfm: np.ndarray,
                     poses: np.ndarray) -> dict[str, Any]:
    """``camera_path.json``: the path's intrinsics and every pose, in the normalized world and the SfM frame,
    with each frame's vertical field of view (``render.path=`` this file renders the same frames again)."""
    from nerfpipe.export.camera_path import fov_of
    from nerfpipe.export.paths import transform_poses

    sfm_poses = transform_poses(poses, to_sfm)
    return {
        "convention": "opencv c2w (x right, y down, z forward); COLMAP intrinsics, pixel centres at +0.5",
        "path": description,
        "layout": layout,
        "fps": fps,
        "camera": cameras[0].to_json(),
        "near": near_far[0],
        "far": near_far[1],
        "depth_colours": {"range": list(depth_range) if depth_range is not None else None,
                          "map": "turbo, red at the range's start to blue at its end, black where acc < 0.5"},
        "to_sfm": to_sfm.tolist(),
        "frames": [
            {"rgb": f"frames/rgb_{i:04d}.png", "depth": f"frames/depth_{i:04d}.png", "c2w": pose.tolist(),
             "c2w_sfm": sfm_pose.tolist(), "fov": fov_of(camera.height, camera.fy)}
            for i, (pose, sfm_pose, camera) in enumerate(zip(poses, sfm_poses, cameras))
        ],
    }


def depth_colour_range(depth: np.ndarray, acc: np.ndarray, near: float, far: float) -> tuple[float, float]:
    """The colour range of a depth video from its first frame (H, W): the ``DEPTH_RANGE_PERCENTILES`` of
    depth where there is a surface (acc >= 0.5); the bounds' [near, far] when that frame shows none."""
    from nerfpipe.export.video import EMPTY_ACC

    surface = depth[(acc >= EMPTY_ACC) & np.isfinite(depth)]
    if surface.size:
        lo, hi = (float(v) for v in np.percentile(surface, DEPTH_RANGE_PERCENTILES))
        if hi > lo:
            return lo, hi
    return near, far


def read_frames(folder: Path, kind: str, count: int) -> Iterator[np.ndarray]:
    """The written PNGs ``<kind>_0000.png`` ... back, one at a time, so a video never holds every frame in memory."""
    for i in range(count):
        yield read_png(folder / f"{kind}_{i:04d}.png")
