"""export_points: a coloured, oriented point cloud from the rendered depth of the training views, and the
SfM sparse cloud, both as PLY in the original SfM frame.

Pixels whose accumulated opacity reaches ``acc_threshold``, and whose depth ``agree_views`` of the views
looking the most the same way confirm (the multi-view consistency check of depth-map fusion), are
back-projected with their expected depth and rendered colour; the union is down-sampled on a voxel grid (grown until at most ``target_points``
remain), cleared of statistical outliers, and given normals from its neighbours, oriented towards the
cameras that saw them (Open3D).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nerfpipe.artifacts import BOUNDS, SCENE, SFM_MODEL
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.summary import Summary
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs


@dataclass(frozen=True)
class ExportPointsParams:
    acc_threshold: float = field(default=0.9, metadata={"bounds": (0.0, 1.0), "help": "back-project pixels whose accumulated opacity reaches this"})
    voxel: float = field(default=0.0, metadata={"bounds": (0.0, 10.0), "help": "smallest down-sampling voxel in normalized units (0: scene box diagonal / 1000)"})
    target_points: int = field(default=200_000, metadata={"bounds": (0, 100_000_000), "help": "grow the voxel until at most this many points remain (0: no limit)"})
    outlier_neighbors: int = field(default=20, metadata={"bounds": (1, 1000), "help": "neighbours of the statistical outlier test"})
    outlier_std: float = field(default=2.0, metadata={"bounds": (0.01, 100.0), "help": "drop points whose mean neighbour distance is this many std above the mean"})
    agree_views: int = field(default=2, metadata={"bounds": (0, 100), "help": "keep a pixel's point only when this many neighbouring views' depths agree with it (multi-view consistency; 0: keep all)"})
    neighbours: int = field(default=6, metadata={"bounds": (1, 1000), "help": "views each view's depth is checked against: those looking the most the same way"})
    agree_tolerance: float = field(default=0.03, metadata={"bounds": (0.0, 1.0), "help": "relative depth difference within which two views agree"})
    crop_to_box: bool = field(default=True, metadata={"help": "360 scenes: keep the points inside the scene box only (false: all of them, background included)"})

    def __post_init__(self) -> None:
        if not 0 <= self.acc_threshold <= 1:
            raise ValueError(f"acc_threshold must be in [0, 1], got {self.acc_threshold}")
        if self.agree_views > self.neighbours:
            raise ValueError(f"agree_views ({self.agree_views}) cannot exceed neighbours ({self.neighbours})")
        for name in ("voxel", "outlier_std", "agree_tolerance"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("target_points", "outlier_neighbors", "agree_views", "neighbours"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class ExportPointsSummary(Summary):
    """The points kept, of those back-projected from the training views' depth, and the SfM sparse cloud."""

    points: int = 0
    raw_points: int = 0
    views: int = 0
    voxel: float = 0.0
    after_voxel: int = 0
    sparse_points: int = 0
    acc_threshold: float = 0.0
    consistency: dict[str, Any] | None = None  # {"agreed", "solid", ...}: the check against neighbouring views

    def describe(self) -> list[str]:
        if not self.views:
            return []
        sparse = f"; SfM sparse cloud: {self.sparse_points} points" if self.sparse_points else "; no SfM sparse points"
        agreed = (f", {self.consistency['agreed']} of {self.consistency['solid']} solid pixels confirmed by other views"
                  if self.consistency else "")
        return [f"{self.points} points from {self.views} training views ({self.raw_points} back-projected{agreed}, "
                f"voxel {self.voxel:.4g}){sparse}"]


class ExportPointsStage(Stage):
    """Point cloud from rendered depth (PLY, SfM frame), plus the SfM sparse cloud."""

    name = "export_points"
    version = 2  # 2: points only where neighbouring views' depths agree
    Params = ExportPointsParams
    Summary = ExportPointsSummary
    presets = {"dense": {"target_points": 1_000_000}, "preview": {"target_points": 50_000}}
    requires = ("depth", "depth_index", "bounds", "scene", "sfm_model")
    provides = {"points": "points.ply"}
    budget_share = 0.02  # reserved under a job budget; the stage is bounded by its own sizes
    optional = True
    libraries = ("numpy", "open3d")

    def run(self, inputs: StageInputs, out: Path, params: ExportPointsParams, ctx: StageContext) -> ExportPointsSummary:
        from nerfpipe.export.depth import DEPTH_INDEX, read_view
        from nerfpipe.export.points import Cloud, agreement, clean_cloud, solid, transformed, views_to_points, write_ply

        index = inputs.load(DEPTH_INDEX)
        bounds = inputs.load(BOUNDS)
        scene = inputs.load(SCENE)
        train = [v for v in index.views if v.role == "train"]
        if not train:
            raise StageError("export_points: the depth export holds no training views; "
                             "run it with --set export_depth.views=all")
        views = [(read_view(inputs["depth"], v), v.K(), np.asarray(v.c2w)) for v in train]
        box = bounds.scene_box if params.crop_to_box and scene.layout.value in ("inward360", "unbounded360") else None
        masks, checked = None, None
        if params.agree_views > 0 and len(views) > params.agree_views:
            counts = agreement(views, params.acc_threshold, params.neighbours, params.agree_tolerance)
            masks = [c >= params.agree_views for c in counts]
            solid_pixels = sum(int(solid(r, params.acc_threshold).sum()) for r, _, _ in views)
            kept = sum(int(m.sum()) for m in masks)
            checked = {"solid": solid_pixels, "agreed": kept}
            ctx.log.info("export_points: %d of %d solid pixels (%.0f%%) have depths that %d of their %d nearest views "
                         "agree with (within %g)", kept, solid_pixels, 100 * kept / max(solid_pixels, 1),
                         params.agree_views, params.neighbours, params.agree_tolerance)
        cloud, _ = views_to_points(views, params.acc_threshold, box, masks)
        if len(cloud) == 0 and masks is not None:
            # a field too rough for any two views to agree (a short or tiny run): its depths as they are
            ctx.log.warning("export_points: no two views' depths agree anywhere; the cloud keeps every solid pixel "
                            "unchecked (train longer for a checked one)")
            checked["fallback"] = True
            cloud, _ = views_to_points(views, params.acc_threshold, box)
        if len(cloud) == 0:
            raise StageError(f"export_points: no pixel of {len(train)} views reaches opacity {params.acc_threshold}; "
                             "lower export_points.acc_threshold or train longer")
        lo, hi = bounds.box()
        voxel = params.voxel or float(np.linalg.norm(hi - lo)) / 1000
        cleaned, report = clean_cloud(cloud, voxel, params.target_points, params.outlier_neighbors, params.outlier_std)
        if not len(cleaned):
            raise StageError(f"export_points: the outlier test left none of the {len(cloud)} points "
                             f"(export_points.outlier_neighbors={params.outlier_neighbors}, outlier_std="
                             f"{params.outlier_std:g}); raise either")
        write_ply(out / "points.ply", transformed(cleaned, bounds.to_sfm))
        ctx.log.info("export_points: %d points (%d back-projected from %d views) -> points.ply (SfM frame)", len(cleaned),
                     len(cloud), len(train))

        sparse = inputs.load(SFM_MODEL).points
        sparse_count = 0
        if sparse is not None and len(sparse.xyz):
            rgb = np.asarray(sparse.rgb, dtype=np.float64)
            write_ply(out / "sparse.ply", Cloud(np.asarray(sparse.xyz, dtype=np.float64), rgb / 255.0 if rgb.max() > 1 else rgb))
            sparse_count = len(sparse.xyz)
        else:
            ctx.log.info("export_points: the poses came without sparse points, so there is no sparse.ply")
        return ExportPointsSummary(
            points=len(cleaned), raw_points=len(cloud), views=len(train), voxel=report.voxel,
            after_voxel=report.after_voxel, sparse_points=sparse_count, acc_threshold=params.acc_threshold,
            consistency=checked,
        )
