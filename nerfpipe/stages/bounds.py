"""bounds: the normalized world (z up, region of interest in [-1, 1]^3) and per-image near/far bounds.

Reads the undistorted cameras (``pinhole``), moves them and their sparse points into the normalized world
of ``nerfpipe.geometry.normalize`` and writes:

- ``world/``: the same CameraSet (names, cameras, splits unchanged) with every c2w and point transformed;
- ``bounds.json``: ``to_world`` (4x4 similarity SfM -> normalized) and ``to_sfm`` (its inverse) so exports
  can go back, ``scale``, ``up`` (in the SfM frame), ``scene_box`` (with points: their robust box, which
  normalization maps to [-1, 1]^3, grown by ``box_margin`` on every side) and per-frame ``near`` / ``far`` in
  normalized units, and the ``method`` that produced them: ``points`` (depth percentiles of the sparse
  points each image sees, as LLFF computes the bounds of the NeRF paper's forward-facing scenes) or
  ``rig`` (no points, e.g. an imported ``transforms.json``: a sphere around the rig's look-at centre).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from nerfpipe.artifacts import PINHOLE, Bounds, FrameBounds
from nerfpipe.geometry.cameras import CameraSet, Points
from nerfpipe.geometry.normalize import (
    Similarity,
    in_view,
    near_far_from_points,
    near_far_from_rig,
    normalization,
    robust_box,
    up_direction,
)
from nerfpipe.geometry.rig import look_at_center, rig_kind, rig_radius
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.summary import Summary
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs

# Without points a non-converging rig says nothing about depth: wide bounds in normalized units (the
# cameras fit the unit cube), which NDC (forward-facing) does not need anyway.
UNCONSTRAINED_NEAR = 0.01
UNCONSTRAINED_FAR = 100.0


@dataclass(frozen=True)
class BoundsParams:
    near_percentile: float = field(default=0.1, metadata={"bounds": (0.0, 100.0), "help": "percentile of the point depths an image sees taken as its near bound"})
    far_percentile: float = field(default=99.9, metadata={"bounds": (0.0, 100.0), "help": "percentile of the point depths an image sees taken as its far bound"})
    margin: float = field(
        default=0.1, metadata={"bounds": (0.0, 0.99), "help": "relative margin: near * (1 - margin), far * (1 + margin). "
                               "Beer scored 0.2-0.4 dB higher at 0.5 (its walls' screens move towards their own cameras) "
                               "and the cup 0.8 dB lower, in its views where training cameras are sparse; 0.8 cost beer "
                               "1.3 dB (docs/benchmarks.md)"}
    )
    box_outlier_quantile: float = field(
        default=0.01, metadata={"bounds": (0.0, 0.49), "help": "per-axis quantile cut from each side of the sparse points for the scene box"}
    )
    box_mad_k: float = field(
        default=5.0, metadata={"bounds": (0.1, 1000.0), "help": "points farther from the median than median + k MADs are left out of the scene box"}
    )
    box_margin: float = field(
        default=0.1, metadata={"bounds": (0.0, 1.0), "help": "the sparse points' box grows by this fraction of its extent on every side: "
                               "points are only where features matched, and the object goes on beyond them"}
    )
    min_points: int = field(
        default=10, metadata={"bounds": (1, 1_000_000), "help": "fewest sparse points an image must see for point-based near/far (else rig-based)"}
    )
    rig_radius: float = field(
        default=0.5, metadata={"bounds": (0.001, 0.999), "help": "without points: scene sphere radius as a fraction of the camera distance to the look-at centre"}
    )

    def __post_init__(self) -> None:
        if not 0.0 <= self.near_percentile < self.far_percentile <= 100.0:
            raise ValueError(
                f"need 0 <= near_percentile < far_percentile <= 100, got {self.near_percentile} and {self.far_percentile}"
            )
        if not 0.0 <= self.margin < 1.0:
            raise ValueError(f"margin must be in [0, 1), got {self.margin}")
        if not 0.0 <= self.box_outlier_quantile < 0.5:
            raise ValueError(f"box_outlier_quantile must be in [0, 0.5), got {self.box_outlier_quantile}")
        if not 0.0 <= self.box_margin <= 1.0:
            raise ValueError(f"box_margin must be in [0, 1], got {self.box_margin}")
        if self.box_mad_k <= 0:
            raise ValueError(f"box_mad_k must be positive, got {self.box_mad_k}")
        if self.min_points < 1:
            raise ValueError(f"min_points must be >= 1, got {self.min_points}")
        if not 0.0 < self.rig_radius < 1.0:
            raise ValueError(f"rig_radius must be in (0, 1), got {self.rig_radius}")


def frustum_box(world: CameraSet, frames: list[FrameBounds]) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box of every image's view frustum between its near and far depth."""
    corners = []
    for frame, bounds in zip(world.frames, frames):
        camera = world.cameras[frame.camera_id]
        for depth in (bounds.near, bounds.far):
            for u, v in ((0, 0), (camera.width, 0), (0, camera.height), (camera.width, camera.height)):
                ray = np.array([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0]) * depth
                corners.append(frame.c2w[:3, :3] @ ray + frame.c2w[:3, 3])
    corners = np.array(corners)
    return corners.min(axis=0), corners.max(axis=0)


def frame_points(cameras: CameraSet, index: int) -> np.ndarray:
    """(M, 3) sparse points that frame ``index`` sees: its SfM track list, else the points in its view."""
    points = cameras.points
    if points is None:
        return np.zeros((0, 3))
    if index < len(points.visible) and len(points.visible[index]) > 0:
        return points.xyz[points.visible[index]]
    frame = cameras.frames[index]
    camera = cameras.camera_of(frame)
    return points.xyz[in_view(frame.c2w, camera.K(), camera.width, camera.height, points.xyz)]


def transform_camera_set(cameras: CameraSet, similarity: Similarity) -> CameraSet:
    """The CameraSet with every frame's c2w and every point moved by ``similarity``; nothing else changes."""
    frames = [replace(f, c2w=similarity.apply_c2w(f.c2w)) for f in cameras.frames]
    points = None
    if cameras.points is not None:
        p = cameras.points
        points = Points(similarity.apply_points(p.xyz).reshape(-1, 3), p.rgb, p.error, p.visible)
    return CameraSet(dict(cameras.cameras), frames, points, cameras.source, list(cameras.unregistered),
                     dataclasses.replace(cameras.hints))


@dataclass(frozen=True)
class BoundsSummary(Summary):
    """How near/far were found (``points`` or ``sphere``), the rig, the scale to the normalized world, and the
    nearest near and farthest far."""

    method: str = ""
    rig: str = ""
    scale: float = 0.0
    near: float | None = None
    far: float | None = None
    frames: int = 0

    def describe(self) -> list[str]:
        if self.near is None or self.far is None:
            return []
        return [f"{self.frames} images, {self.method}-based near/far {self.near:.3g} .. {self.far:.3g} "
                f"(normalized units), {self.rig} rig, scale {self.scale:.4g}"]


class BoundsStage(Stage):
    """Normalize the world (z up, scene in [-1, 1]^3) and compute per-image near/far bounds."""

    name = "bounds"
    version = 3  # 3: up from the y axes of photos turned a quarter; 2: the points' scene box grows by box_margin
    Params = BoundsParams
    Summary = BoundsSummary
    requires = ("pinhole",)
    provides = {"world": "world", "bounds": "bounds.json"}
    libraries = ("numpy",)

    def run(self, inputs: StageInputs, out: Path, params: BoundsParams, ctx: StageContext) -> BoundsSummary:
        sfm = inputs.load(PINHOLE)
        if not sfm.frames:
            raise StageError("bounds: no registered images to normalize; check the sfm / pose import result")
        c2ws = np.array([f.c2w for f in sfm.frames])
        xyz = sfm.points.xyz if sfm.points is not None and len(sfm.points.xyz) >= params.min_points else None

        up = up_direction(c2ws)
        similarity = normalization(c2ws, xyz, params.box_outlier_quantile, params.box_mad_k)
        world = transform_camera_set(sfm, similarity)
        (out / "world").mkdir()
        world.save(out / "world")
        kind = rig_kind(np.array([f.c2w for f in world.frames]))
        if xyz is not None:
            method, (lo, hi), frames = "points", *self._from_points(world, params, ctx)
        elif sfm.hints.llff_bounds:
            # LLFF's poses_bounds.npy carries near/far depths from the points COLMAP had: use them, scaled
            llff = sfm.hints.llff_bounds
            frames = [FrameBounds(f.name, float(llff[f.name][0]) * similarity.scale,
                                  float(llff[f.name][1]) * similarity.scale, "pose_file") for f in world.frames]
            method, (lo, hi) = "pose_file", frustum_box(world, frames)
        else:
            method, (lo, hi), frames = "rig", *self._from_rig(world, kind, params, ctx)

        bounds = Bounds(
            to_world=similarity.matrix().tolist(), to_sfm=similarity.inverse().matrix().tolist(),
            scale=similarity.scale, up=up.tolist(), rig=kind, method=method, scene_box=(lo.tolist(), hi.tolist()),
            near=min(f.near for f in frames), far=max(f.far for f in frames), frames=tuple(frames),
        )
        bounds.save(out / "bounds.json")
        ctx.log.info(
            "bounds: %d images, %s-based near/far %.3g .. %.3g (normalized units), scale %.4g, %s rig",
            len(frames), method, bounds.near, bounds.far, similarity.scale, kind,
        )
        return BoundsSummary(method=method, rig=kind, scale=similarity.scale, near=bounds.near, far=bounds.far,
                             frames=len(frames))

    @staticmethod
    def _from_points(world: CameraSet, params: BoundsParams, ctx: StageContext):
        """The robust box of the sparse points, and near/far from the points each image sees."""
        lo, hi = robust_box(world.points.xyz, params.box_outlier_quantile, params.box_mad_k)
        grow = params.box_margin * (hi - lo)
        lo, hi = lo - grow, hi + grow
        # images that see too few points fall back to the sphere around the scene box
        box_center, box_radius = (lo + hi) / 2.0, float(np.linalg.norm(hi - lo) / 2.0)
        frames = []
        for i, frame in enumerate(world.frames):
            bounds = near_far_from_points(
                frame.c2w, frame_points(world, i), params.near_percentile, params.far_percentile,
                params.margin, params.min_points,
            )
            if bounds is None:
                near, far = near_far_from_rig(frame.c2w[None], box_center, box_radius)
                frames.append(FrameBounds(frame.name, float(near[0]), float(far[0]), "rig"))
            else:
                frames.append(FrameBounds(frame.name, bounds[0], bounds[1], "points"))
        fallback = sum(f.method != "points" for f in frames)
        if fallback:
            ctx.log.warning(
                "bounds: %d of %d images see fewer than %d sparse points; their near/far come from the scene box",
                fallback, len(frames), params.min_points,
            )
        return (lo, hi), frames

    @staticmethod
    def _from_rig(world: CameraSet, kind: str, params: BoundsParams, ctx: StageContext):
        """Without points: the sphere the cameras look at (inward rigs), else wide defaults."""
        c2ws = np.array([f.c2w for f in world.frames])
        if kind == "inward":
            center = look_at_center(c2ws)
            radius = rig_radius(c2ws, center, params.rig_radius)
            near, far = near_far_from_rig(c2ws, center, radius)
            frames = [FrameBounds(f.name, float(n), float(x), "rig") for f, n, x in zip(world.frames, near, far)]
            return (center - radius, center + radius), frames
        ctx.log.warning(
            "bounds: no sparse points and the cameras do not look at a common centre (%s rig); "
            "near/far are wide defaults %.2f / %.0f", kind, UNCONSTRAINED_NEAR, UNCONSTRAINED_FAR,
        )
        centers = c2ws[:, :3, 3]
        frames = [FrameBounds(f.name, UNCONSTRAINED_NEAR, UNCONSTRAINED_FAR, "rig") for f in world.frames]
        return (centers.min(axis=0), centers.max(axis=0)), frames
