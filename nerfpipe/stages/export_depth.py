"""export_depth: depth, opacity and disparity maps of the trained field, for every training and held-out view.

Per view, in ``depth/``: ``<view>.depth.npy`` (expected depth along the camera axis, float32),
``<view>.acc.npy`` (accumulated opacity), ``<view>.disparity.npy``, ``<view>.depth.png`` (16-bit, with
``<view>.depth.json`` giving its scale), ``<view>.preview.png`` (colour-mapped disparity) and
``<view>.rgb.png`` (the rendered colour, which points and TSDF fusion take their colours from).
``depth.json`` lists the views with their cameras at the exported resolution. Units are those of the
normalized world; ``to_sfm`` there and in every sidecar maps them back to the SfM frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Mapping

from nerfpipe.artifacts import BOUNDS, CAMERAS, VIEWS, ViewSplit, view_file_stem
from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.nerf.presets import gpu_preset
from nerfpipe.pipeline.budget import FloorWork, fit_within
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.summary import Summary
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs


@dataclass(frozen=True)
class ExportDepthParams:
    scale: float = field(default=0.25, metadata={"bounds": (0.01, 1.0), "help": "render at this fraction of each camera's resolution (1: full)"})
    views: Literal["all", "train", "heldout"] = field(default="all", metadata={"help": "which views: the training views, the held-out ones, or both"})
    acc_threshold: float = field(default=0.5, metadata={"bounds": (0.0, 1.0), "help": "accumulated opacity below which a pixel has no depth in the 16-bit PNG and preview"})
    chunk: int = field(default=4096, metadata={"keyed": False, "bounds": (1, 1_048_576), "help": "rays per chunk (4096: measured fastest on a 2-core CPU)"})
    device: Literal["auto", "cpu", "cuda"] = field(default="auto", metadata={"keyed": False, "help": "auto: CUDA when present, else CPU"})

    def __post_init__(self) -> None:
        if not 0 < self.scale <= 1:
            raise ValueError(f"scale must be in (0, 1], got {self.scale}")
        if not 0 <= self.acc_threshold <= 1:
            raise ValueError(f"acc_threshold must be in [0, 1], got {self.acc_threshold}")
        if self.chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {self.chunk}")


# Under a job budget the views shrink to fit the stage's share, never below this share of the photos' side (or
# export_depth.scale, when that is smaller): a depth map is useless smaller; when even that does not fit, the job
# takes longer and says so. Writing a view's files costs about this fraction of rendering its rays.
DEPTH_FLOOR = 0.25
VIEW_OVERHEAD = 1.15


def scaled_size(width: int, height: int, scale: float) -> tuple[int, int]:
    return max(1, round(width * scale)), max(1, round(height * scale))


def wanted_views(split: ViewSplit, params: ExportDepthParams) -> list[tuple[str, str]]:
    """(role, view name) of each view to export: the training views, the held-out ones, or both."""
    wanted = [("train", n) for n in split.train] * (params.views in ("all", "train"))
    return wanted + [("heldout", n) for n in split.heldout] * (params.views in ("all", "heldout"))


@dataclass(frozen=True)
class ExportDepthSummary(Summary):
    """The views whose depth was written, their size and what each cost, and their mean opacity."""

    views: int = 0
    train_views: int = 0
    heldout_views: int = 0
    scale: float = 0.0
    width: int = 0
    height: int = 0
    seconds_per_view: float = 0.0
    mean_acc: float = 0.0

    def describe(self) -> list[str]:
        if not self.views:
            return []
        return [f"{self.views} views ({self.train_views} training, {self.heldout_views} held out) at "
                f"{self.width}x{self.height}, {self.seconds_per_view:.1f} s each; mean opacity {self.mean_acc:.2f}"]


class ExportDepthStage(Stage):
    """Depth, opacity and disparity maps (.npy, 16-bit PNG, preview) of every training and held-out view."""

    name = "export_depth"
    version = 1
    Params = ExportDepthParams
    Summary = ExportDepthSummary
    presets = {
        "preview": {"scale": 0.125},
        # full resolution: what other tools want, at 16x the rendering time of the default
        "full": {"scale": 1.0},
        "gpu": {"scale": 1.0},  # a CUDA device's (``machine_preset``): full size is cheap there
    }
    requires = ("model", "model_json", "views", "cameras", "bounds")
    provides = {"depth": "depth", "depth_index": "depth.json"}
    libraries = ("torch", "numpy", "opencv-contrib-python-headless", "matplotlib")
    accelerated = True
    budget_share = 0.08
    optional = True

    def machine_preset(self, overrides: Mapping[str, Any]) -> tuple[str, str] | None:
        return gpu_preset(overrides, "depth maps at full size")

    def expected_bytes(self, inputs: StageInputs, params: ExportDepthParams) -> int:
        """The float32 depth, opacity and disparity arrays of every view (the PNGs beside them add less)."""
        world = inputs.load(CAMERAS)
        by_name = {f.name: f for f in world.frames}
        total = 0
        for _, name in wanted_views(inputs.load(VIEWS), params):
            if name in by_name:
                camera = world.camera_of(by_name[name])
                width, height = scaled_size(camera.width, camera.height, params.scale)
                total += width * height * 3 * 4
        return total

    def floor_work(self, params: ExportDepthParams, world: CameraSet, split: ViewSplit, *rest) -> FloorWork | None:
        """The depth maps at their floor (a quarter of the photos' side, ``DEPTH_FLOOR``, or the scale asked for when
        smaller): their rays, as ``_fitting_scale`` weighs them."""
        by_name = {f.name: f for f in world.frames}
        cameras = [world.camera_of(by_name[name]) for _, name in wanted_views(split, params) if name in by_name]
        if not cameras:
            return None
        scale = min(params.scale, DEPTH_FLOOR)
        sizes = [scaled_size(c.width, c.height, scale) for c in cameras]
        return FloorWork(VIEW_OVERHEAD * sum(w * h for w, h in sizes), 0.0,
                         f"{len(sizes)} depth maps at {sizes[0][0]}x{sizes[0][1]}")

    @staticmethod
    def _fitting_scale(model, frames, world: CameraSet, near_far, params: ExportDepthParams, ctx: StageContext,
                       began: float) -> tuple[float, dict[str, Any] | None]:
        """``params.scale``, or less where the views at that scale would not fit the stage's allotment, never below
        ``DEPTH_FLOOR``; logs the size and the predicted seconds, and a warning when the floor takes longer. Timed on
        the first view at the least size it may take (the floor, or the scale asked for when smaller), which is
        returned beside the scale where the views take that size (``RadianceModel.render_image``'s maps), else None."""
        from nerfpipe.nerf.throughput import timed_view

        if not frames:
            return params.scale, None
        first = world.camera_of(frames[0])
        least = min(params.scale, DEPTH_FLOOR)
        width, height = scaled_size(first.width, first.height, least)
        seconds, timed = timed_view(model, first.scaled(width / first.width, height / first.height).intrinsics, frames[0].c2w, width, height,
                                    *near_far[frames[0].name], params.chunk)
        per_ray = VIEW_OVERHEAD * seconds / (width * height)
        rays = sum(w * h for w, h in (scaled_size(c.width, c.height, params.scale) for c in map(world.camera_of, frames)))
        fit = fit_within(ctx.allotment, time.perf_counter() - began, per_ray * rays, min(1.0, DEPTH_FLOOR / params.scale))
        scale, fits = params.scale * fit.scale, ""
        if ctx.allotment is not None:
            fits = f" to fit its {ctx.allotment.describe()}"
            if scale < params.scale:
                fits += f"; at export_depth.scale {params.scale:g} they would take {per_ray * rays:.0f} s"
        size = scaled_size(first.width, first.height, scale)
        ctx.log.info("export_depth: %d views at %dx%d (scale %.3g), about %.0f s%s", len(frames), *size, scale,
                     fit.seconds, fits)
        longer = fit.longer(f"export_depth: {len(frames)} views at {size[0]}x{size[1]} (never smaller than a quarter of the "
                            "photos' side)",
                            ctx.allotment)
        if longer is not None:
            ctx.log.warning(longer)
        return scale, timed if size == (width, height) else None

    def run(self, inputs: StageInputs, out: Path, params: ExportDepthParams, ctx: StageContext) -> ExportDepthSummary:
        from nerfpipe.nerf.device import rendering_device

        with rendering_device(params.device, "export_depth.device") as device:
            return self._run(inputs, out, params, ctx, device)

    def _run(self, inputs: StageInputs, out: Path, params: ExportDepthParams, ctx: StageContext, device) -> ExportDepthSummary:
        import numpy as np

        from nerfpipe.export.depth import DepthIndex, DepthView, png_scale_for, write_view
        from nerfpipe.nerf.model import RadianceModel

        began = time.perf_counter()
        model = RadianceModel.load(inputs["model"].parent, device)
        world = inputs.load(CAMERAS)  # the training cameras as refined
        bounds = inputs.load(BOUNDS)
        split = inputs.load(VIEWS)
        near_far = bounds.near_far()
        by_name = {f.name: f for f in world.frames}
        wanted = wanted_views(split, params)
        missing = [n for _, n in wanted if n not in by_name]
        if missing:
            raise StageError(f"export_depth: views {missing[:3]} of the trained model are not in the world cameras; "
                             "rerun with --force train")

        scale, timed = self._fitting_scale(model, [by_name[n] for _, n in wanted], world, near_far, params, ctx, began)
        folder = out / "depth"
        folder.mkdir()
        png_scale = png_scale_for(max(far for _, far in near_far.values()))
        views, accs = [], []
        started = time.perf_counter()
        with ctx.progress(len(wanted), "export depth") as advance:
            for role, name in wanted:
                frame = by_name[name]
                camera = world.camera_of(frame)
                width, height = scaled_size(camera.width, camera.height, scale)
                intrinsics = camera.scaled(width / camera.width, height / camera.height).intrinsics
                near, far = near_far[name]
                # the first view was rendered at this size to time them all: kept, not rendered again
                image = timed if timed is not None and name == wanted[0][1] else \
                    model.render_image(intrinsics, frame.c2w, width, height, near, far, params.chunk)
                rendered = {k: v.numpy() for k, v in image.items()}
                view = DepthView(name, view_file_stem(name), role, width, height, intrinsics,
                                 tuple(map(tuple, np.asarray(frame.c2w).tolist())), near, far)
                write_view(folder, view, rendered, png_scale, params.acc_threshold, bounds.to_sfm)
                views.append(view)
                accs.append(float(rendered["acc"].mean()))
                advance(1, info=name)
        DepthIndex(views, png_scale, bounds.to_sfm, params.acc_threshold).save(out / "depth.json")
        seconds = time.perf_counter() - started
        ctx.log.info("export_depth: %d views in %.0f s (%.1f s a view)", len(views), seconds, seconds / max(len(views), 1))
        return ExportDepthSummary(
            views=len(views),
            train_views=sum(v.role == "train" for v in views),
            heldout_views=sum(v.role == "heldout" for v in views),
            scale=scale,
            width=views[0].width if views else 0,
            height=views[0].height if views else 0,
            seconds_per_view=round(seconds / max(len(views), 1), 3),
            mean_acc=round(float(np.mean(accs)), 4) if accs else 0.0,
        )
