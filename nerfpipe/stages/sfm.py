"""sfm: camera poses and sparse points, from COLMAP structure from motion (pycolmap, in process) or
from the pose files a capture already has.

SfM runs SIFT extraction, matching chosen by the capture (exhaustive for small sets, spatial when the
photos carry GPS, sequential for video frames) and incremental or global mapping. The EXIF focal prior
from ingest seeds the intrinsics. When not every photo registers, mapping is retried once with relaxed
options and the better model is kept; below ``min_registered`` the stage fails and says what to try.
COLMAP's own log goes to ``colmap.log`` in the stage folder.

Imported poses without sparse points (LLFF, ``transforms.json``, Middlebury) get points triangulated
from SIFT matches with the poses held fixed (``sfm.triangulate``), so the bounds stage derives near/far
and the scene box from data as it does after SfM; when that fails or yields too few points, the stage
says so and the bounds fall back to the pose file's near/far (LLFF) or the rig guess.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from nerfpipe.artifacts import IMAGES_JSON, PhotoRecord
from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.pipeline.summary import Summary
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs
from nerfpipe.poses.layout import check_colmap_model, detect_layout

PoseSource = Literal["auto", "sfm", "colmap", "transforms", "llff", "middlebury"]


@dataclass(frozen=True)
class SfmParams:
    poses: PoseSource = field(
        default="auto", metadata={"help": "auto: import the capture's pose files if it has any, else run SfM; or force one"}
    )
    camera_model: Literal[
        "SIMPLE_RADIAL", "SIMPLE_PINHOLE", "PINHOLE", "RADIAL", "OPENCV", "OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE"
    ] = field(default="SIMPLE_RADIAL", metadata={"help": "COLMAP camera model estimated by SfM"})
    single_camera: Literal["auto", "yes", "no"] = field(
        default="auto", metadata={"help": "one camera shared by all photos; auto = when EXIF make, model, size agree"}
    )
    max_image_size: int = field(default=1600, metadata={"bounds": (64, 16_384), "help": "SIFT extraction: longest side in pixels"})
    max_features: int = field(default=8192, metadata={"bounds": (64, 1_000_000), "help": "SIFT extraction: features per image"})
    matcher: Literal["auto", "exhaustive", "sequential", "spatial"] = field(
        default="auto", metadata={"help": "auto: exhaustive up to exhaustive_max photos, then spatial (GPS) or sequential (video)"}
    )
    exhaustive_max: int = field(default=100, metadata={"bounds": (0, 10_000), "help": "largest capture matched exhaustively by auto"})
    sequential_overlap: int = field(default=10, metadata={"bounds": (1, 1000), "help": "sequential matching: neighbours per frame"})
    spatial_neighbors: int = field(default=10, metadata={"bounds": (1, 1000), "help": "spatial matching of known camera positions: the "
                                                                  "nearest cameras each photo is matched with"})
    mapper: Literal["incremental", "global"] = field(default="incremental", metadata={"help": "COLMAP mapper or GLOMAP"})
    relaxed_retry: bool = field(default=True, metadata={"help": "retry mapping with relaxed options when photos stay unregistered"})
    min_registered: float = field(default=0.5, metadata={"bounds": (0.01, 1.0), "help": "fail when fewer than this fraction of photos register"})
    min_images: int = field(default=3, metadata={"bounds": (2, 100_000), "help": "fewest photos SfM will try"})
    seed: int = field(default=0, metadata={"bounds": (0, 2_147_483_647), "help": "random seed of COLMAP's RANSAC and mapper"})
    triangulate: Literal["auto", "true", "false"] = field(
        default="auto",
        metadata={"help": "imported poses: triangulate sparse points from SIFT matches with the poses fixed; auto when "
                          "the pose file has no points and the photos have no alpha (renders of an object inside the "
                          "camera ring, which the rig box holds); true also replaces a model's own points; false never"},
    )
    triangulate_max_size: int = field(
        default=1024, metadata={"bounds": (64, 16_384), "help": "imported poses: SIFT for the triangulated points at this "
                                "longest side (at most max_image_size); 640 takes 0.6x the time, but the cup's "
                                "held-out views lost 0.5 dB with its points (docs/benchmarks.md)"}
    )
    min_triangulated_points: int = field(
        default=100, metadata={"bounds": (1, 10_000_000), "help": "fewer triangulated points than this: keep none and say so (bounds then use "
                                       "the pose file's near/far, or the rig guess)"}
    )
    bundle_adjust: Literal["auto", "on", "off"] = field(
        default="auto",
        metadata={"help": "imported poses with triangulated points: refine the poses, focal lengths and lens distortion "
                          "with the points by bundle adjustment; auto keeps the result where the given ones reproject "
                          "beyond 0.5 px and the adjusted ones at least a fifth closer (the cup's LLFF poses: 1.33 -> "
                          "0.66 px, its held-out views +1.9 dB; docs/benchmarks.md)"},
    )

    def __post_init__(self) -> None:
        if not 0.0 < self.min_registered <= 1.0:
            raise ValueError(f"min_registered must be in (0, 1], got {self.min_registered}")
        if self.max_image_size < 64 or self.max_features < 64:
            raise ValueError("max_image_size and max_features must be at least 64")
        if self.min_images < 2:
            raise ValueError(f"min_images must be at least 2, got {self.min_images}")
        if self.spatial_neighbors < 1:
            raise ValueError(f"spatial_neighbors must be at least 1, got {self.spatial_neighbors}")
        if self.min_triangulated_points < 1:
            raise ValueError(f"min_triangulated_points must be at least 1, got {self.min_triangulated_points}")


@dataclass(frozen=True)
class SfmSummary(Summary):
    """How the poses were found (COLMAP's mapper, or imported), how many photos they cover, and the sparse
    points: their reprojection error and track length (SfM), or where they came from (an import)."""

    method: str = ""
    registered: int = 0
    total: int = 0
    unregistered: list[str] = field(default_factory=list)
    points: int = 0
    mean_reprojection_error_px: float | None = None  # SfM's
    mean_track_length: float | None = None
    matcher: str | None = None
    matcher_reason: str | None = None
    single_camera: bool | None = None
    focal_priors: int | None = None
    relaxed_retry_used: bool | None = None
    points_from: str | None = None  # an import's: "triangulated", "pose file" or "none"
    triangulation: dict[str, Any] | None = None  # {"matcher", "seconds", "mean_reprojection_error_px", ...}
    triangulation_fallback: str | None = None
    aabb_scale: float | None = None  # instant-ngp's hint from a transforms.json

    def describe(self) -> list[str]:
        line = f"{self.method}: {self.registered}/{self.total} photos registered"
        if self.mean_reprojection_error_px is not None and self.points_from is None:
            line += (f", mean reprojection error {self.mean_reprojection_error_px} px, "
                     f"mean track length {self.mean_track_length}, {self.points} points")
        lines = [line + self.points_line()]
        if self.triangulation_fallback:
            lines.append(f"warning: {self.triangulation_fallback}")
        if self.aabb_scale:
            lines.append(aabb_hint(self.aabb_scale))
        if self.unregistered:
            lines.append("unregistered: " + ", ".join(self.unregistered))
        return lines

    def points_line(self) -> str:
        """Where an import's points came from: '' for SfM (its line already counts them)."""
        if self.points_from == "triangulated" and self.triangulation is not None:
            t = self.triangulation
            line = (f", {self.points} points triangulated with the poses fixed ({t['matcher']} matching, "
                    f"{t['seconds']:.0f} s, mean reprojection error {t['mean_reprojection_error_px']} px)")
            adjusted = t.get("bundle_adjustment") or {}
            if adjusted.get("kept"):
                line += (f"; the poses (and a shared lens) then bundle-adjusted with them, "
                         f"{adjusted['before_px']} -> {adjusted['after_px']} px")
            return line
        if self.points_from == "pose file":
            return f", {self.points} points from the pose file"
        return ", no sparse points" if self.points_from == "none" else ""


class SfmStage(Stage):
    """Camera poses + sparse points: COLMAP SfM through pycolmap, or the capture's own pose files."""

    name = "sfm"
    version = 7  # 7: sfm.bundle_adjust, and all pairs matched for it; 6: sfm.triangulate_max_size; 5: LLFF poses triangulated too; 4: known poses matched with their nearest cameras; 3: triangulated points
    Params = SfmParams
    Summary = SfmSummary
    presets = {
        "draft": {"max_image_size": 800, "max_features": 4096},
        "fast": {"max_image_size": 1024},
        "balanced": {"max_image_size": 1600},
        "paper": {"max_image_size": 3200},
    }
    requires = ("images", "images_json")
    provides = {"sfm_model": "model"}
    libraries = ("pycolmap", "numpy")
    inputs_label = "pose files"

    def input_files(self, source: Path, params: SfmParams) -> list[Path]:
        if params.poses == "sfm":
            return []
        layout = detect_layout(source, None if params.poses == "auto" else params.poses)
        if layout.kind == "folder":  # auto found no poses: say so if it found half a COLMAP model
            check_colmap_model(source, "or pass --set sfm.poses=sfm to compute the poses and ignore the model")
        return layout.pose_files

    def run(self, inputs: StageInputs, out: Path, params: SfmParams, ctx: StageContext) -> SfmSummary:
        records = inputs.load(IMAGES_JSON).records
        layout = detect_layout(inputs.source, None if params.poses in ("auto", "sfm") else params.poses)
        (out / "model").mkdir()
        if params.poses == "sfm" or layout.kind in ("folder", "video"):
            from nerfpipe.poses.colmap.mapping import run_sfm  # pycolmap is imported where it is used

            cameras, summary = run_sfm(inputs["images"], records, out, params, ctx)
        else:
            cameras, summary = import_with_points(inputs["images"], layout, records, out, params, ctx)
        cameras.save(out / "model")
        return SfmSummary.from_json(summary)


def needs_points(cameras: CameraSet, records: list[PhotoRecord]) -> bool:
    """Whether imported poses call for triangulated points: the pose file has no points, and the photos are
    no alpha renders (a synthetic object inside the camera ring, which the bounds stage's rig box holds).

    An LLFF file's near/far too: they bound each view's depths but not the scene, and the box of their
    frusta is several times the object's size. On the cup (77 photos 800x600) it was 5.8 x 5.0 x 4.8 times
    the cameras' distance from the centre, the triangulated points' box 1.0 x 1.5 x 1.1 times it, so the
    grids spend 3-5 times the cells a side on the cup: held-out views scored 25.3 dB against 24.1 after
    150 s of training, for 22 s of triangulation."""
    has_alpha = bool(records) and all(r.has_alpha for r in records)
    return cameras.points is None and not has_alpha


def aabb_hint(scale: float) -> str:
    return (f"hint: instant-ngp aabb_scale {scale:g}: the scene extends {scale:g}x the cameras' unit cube"
            + (" (content well beyond the cameras)" if scale > 1 else " (an object inside the camera ring)"))


# -- imported poses, and points triangulated for them -----------------------------------------------------


def import_with_points(
    image_dir: Path, layout: Any, records: list[PhotoRecord], out: Path, params: SfmParams, ctx: StageContext
) -> tuple[CameraSet, dict[str, Any]]:
    """The capture's own poses; points triangulated for them as ``sfm.triangulate`` asks, else its own."""
    from nerfpipe.poses.colmap.triangulate import triangulate_known_poses
    from nerfpipe.poses.importers import import_poses

    cameras = import_poses(layout, records)
    summary: dict[str, Any] = {"method": f"imported {layout.kind}", "registered": len(cameras.frames),
                               "total": len(records), "unregistered": cameras.unregistered}
    ctx.log.info("sfm: imported %d camera poses from %s", len(cameras.frames), ", ".join(p.name for p in layout.pose_files))
    own = cameras.points
    if params.triangulate == "true" or (params.triangulate == "auto" and needs_points(cameras, records)):
        triangulated, triangulation = triangulate_known_poses(image_dir, cameras, records, out, params, ctx)
        summary["triangulation"] = triangulation
        # the model keeps what the run found, not how long it took, so equal runs write equal models
        cameras.hints.triangulation = {k: v for k, v in triangulation.items() if k != "seconds"}
        if triangulated is not None:
            cameras, summary["points_from"] = triangulated, "triangulated"
        else:
            instead = ("the pose file's own points" if own is not None else
                       "the pose file's near/far" if cameras.hints.llff_bounds else "the rig guess")
            summary["triangulation_fallback"] = f"{triangulation['reason']}; bounds fall back to {instead}"
            summary["points_from"] = "pose file" if own is not None else "none"
            ctx.log.warning("sfm: %s", summary["triangulation_fallback"])
    else:
        summary["points_from"] = "pose file" if own is not None else "none"
    summary["points"] = 0 if cameras.points is None else len(cameras.points.xyz)
    if cameras.hints.aabb_scale is not None:
        summary["aabb_scale"] = cameras.hints.aabb_scale
        ctx.log.info("sfm: %s", aabb_hint(cameras.hints.aabb_scale))
    return cameras, summary


# -- structure from motion ---------------------------------------------------------------------------


