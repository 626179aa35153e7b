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

import contextlib
import math
import os
import re
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Literal

import numpy as np

from nerfpipe.artifacts import ImageIndex
from nerfpipe.geometry.cameras import Camera, CameraSet, Frame, Points, invert_pose
from nerfpipe.pipeline.errors import StageError
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
    max_image_size: int = field(default=1600, metadata={"help": "SIFT extraction: longest side in pixels"})
    max_features: int = field(default=8192, metadata={"help": "SIFT extraction: features per image"})
    matcher: Literal["auto", "exhaustive", "sequential", "spatial"] = field(
        default="auto", metadata={"help": "auto: exhaustive up to exhaustive_max photos, then spatial (GPS) or sequential (video)"}
    )
    exhaustive_max: int = field(default=100, metadata={"help": "largest capture matched exhaustively by auto"})
    sequential_overlap: int = field(default=10, metadata={"help": "sequential matching: neighbours per frame"})
    mapper: Literal["incremental", "global"] = field(default="incremental", metadata={"help": "COLMAP mapper or GLOMAP"})
    relaxed_retry: bool = field(default=True, metadata={"help": "retry mapping with relaxed options when photos stay unregistered"})
    min_registered: float = field(default=0.5, metadata={"help": "fail when fewer than this fraction of photos register"})
    min_images: int = field(default=3, metadata={"help": "fewest photos SfM will try"})
    seed: int = field(default=0, metadata={"help": "random seed of COLMAP's RANSAC and mapper"})
    triangulate: Literal["auto", "true", "false"] = field(
        default="auto",
        metadata={"help": "imported poses: triangulate sparse points from SIFT matches with the poses fixed; auto when "
                          "the pose file has neither points nor near/far and the photos have no alpha (renders of an "
                          "object inside the camera ring, which the rig box holds); true also replaces a model's own "
                          "points; false never"},
    )
    min_triangulated_points: int = field(
        default=100, metadata={"help": "fewer triangulated points than this: keep none and say so (bounds then use "
                                       "the pose file's near/far, or the rig guess)"}
    )

    def __post_init__(self) -> None:
        if not 0.0 < self.min_registered <= 1.0:
            raise ValueError(f"min_registered must be in (0, 1], got {self.min_registered}")
        if self.max_image_size < 64 or self.max_features < 64:
            raise ValueError("max_image_size and max_features must be at least 64")
        if self.min_images < 2:
            raise ValueError(f"min_images must be at least 2, got {self.min_images}")
        if self.min_triangulated_points < 1:
            raise ValueError(f"min_triangulated_points must be at least 1, got {self.min_triangulated_points}")


class SfmStage(Stage):
    """Camera poses + sparse points: COLMAP SfM through pycolmap, or the capture's own pose files."""

    name = "sfm"
    version = 3  # 2: seeded two-view RANSAC and mapper; 3: triangulated points for imported poses
    Params = SfmParams
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

    def describe(self, result: Path, manifest: dict[str, Any]) -> list[str]:
        s = manifest.get("summary", {})
        line = f"{s.get('method')}: {s.get('registered')}/{s.get('total')} photos registered"
        if "mean_reprojection_error_px" in s:
            line += (f", mean reprojection error {s['mean_reprojection_error_px']} px, "
                     f"mean track length {s['mean_track_length']}, {s['points']} points")
        lines = [line + points_line(s)]
        if s.get("triangulation_fallback"):
            lines.append(f"warning: {s['triangulation_fallback']}")
        if s.get("aabb_scale"):
            lines.append(aabb_hint(s["aabb_scale"]))
        if s.get("unregistered"):
            lines.append("unregistered: " + ", ".join(s["unregistered"]))
        return lines

    def input_files(self, source: Path, params: SfmParams) -> list[Path]:
        if params.poses == "sfm":
            return []
        layout = detect_layout(source, None if params.poses == "auto" else params.poses)
        if layout.kind == "folder":  # auto found no poses: say so if it found half a COLMAP model
            check_colmap_model(source, "or pass --set sfm.poses=sfm to compute the poses and ignore the model")
        return layout.pose_files

    def run(self, inputs: StageInputs, out: Path, params: SfmParams, ctx: StageContext) -> dict[str, Any]:
        records = ImageIndex.load(inputs["images_json"]).records
        layout = detect_layout(inputs.source, None if params.poses in ("auto", "sfm") else params.poses)
        (out / "model").mkdir()
        if params.poses == "sfm" or layout.kind in ("folder", "video"):
            cameras, summary = run_sfm(inputs["images"], records, out, params, ctx)
        else:
            cameras, summary = import_with_points(inputs["images"], layout, records, out, params, ctx)
        cameras.save(out / "model")
        return summary


def points_line(s: dict[str, Any]) -> str:
    """Where an import's points came from, for ``describe``: '' for SfM (its line already counts them)."""
    source = s.get("points_from")
    if source == "triangulated":
        t = s["triangulation"]
        return (f", {s['points']} points triangulated with the poses fixed "
                f"({t['matcher']} matching, {t['seconds']:.0f} s, mean reprojection error {t['mean_reprojection_error_px']} px)")
    if source == "pose file":
        return f", {s['points']} points from the pose file"
    return ", no sparse points" if source == "none" else ""


def needs_points(cameras: CameraSet, records: list[dict]) -> bool:
    """Whether imported poses call for triangulated points: the pose file has no points and no near/far
    (LLFF's come from COLMAP's points), and the photos are no alpha renders (a synthetic object inside
    the camera ring, which the bounds stage's rig box holds)."""
    has_alpha = bool(records) and all(r.get("has_alpha") for r in records)
    return cameras.points is None and not cameras.extra.get("llff_bounds") and not has_alpha


def aabb_hint(scale: float) -> str:
    return (f"hint: instant-ngp aabb_scale {scale:g}: the scene extends {scale:g}x the cameras' unit cube"
            + (" (content well beyond the cameras)" if scale > 1 else " (an object inside the camera ring)"))


# -- imported poses, and points triangulated for them -----------------------------------------------------


def import_with_points(
    image_dir: Path, layout: Any, records: list[dict], out: Path, params: SfmParams, ctx: StageContext
) -> tuple[CameraSet, dict[str, Any]]:
    """The capture's own poses; points triangulated for them as ``sfm.triangulate`` asks, else its own."""
    from nerfpipe.poses.importers import import_poses

    cameras = import_poses(layout, records)
    summary: dict[str, Any] = {"method": f"imported {layout.kind}", "registered": len(cameras.frames),
                               "total": len(records), "unregistered": cameras.unregistered}
    ctx.log.info("sfm: imported %d camera poses from %s", len(cameras.frames), ", ".join(p.name for p in layout.pose_files))
    own = cameras.points
    if params.triangulate == "true" or (params.triangulate == "auto" and needs_points(cameras, records)):
        points, triangulation = triangulate_known_poses(image_dir, cameras, records, out, params, ctx)
        summary["triangulation"] = triangulation
        # the model keeps what the run found, not how long it took, so equal runs write equal models
        cameras.extra["triangulation"] = {k: v for k, v in triangulation.items() if k != "seconds"}
        if points is not None:
            cameras.points, summary["points_from"] = points, "triangulated"
        else:
            instead = ("the pose file's own points" if own is not None else
                       "the pose file's near/far" if cameras.extra.get("llff_bounds") else "the rig guess")
            summary["triangulation_fallback"] = f"{triangulation['reason']}; bounds fall back to {instead}"
            summary["points_from"] = "pose file" if own is not None else "none"
            ctx.log.warning("sfm: %s", summary["triangulation_fallback"])
    else:
        summary["points_from"] = "pose file" if own is not None else "none"
    summary["points"] = 0 if cameras.points is None else len(cameras.points.xyz)
    if "aabb_scale" in cameras.extra:
        summary["aabb_scale"] = cameras.extra["aabb_scale"]
        ctx.log.info("sfm: %s", aabb_hint(cameras.extra["aabb_scale"]))
    return cameras, summary


def choose_triangulation_matcher(records: list[dict], params: SfmParams) -> tuple[str, str]:
    """As ``choose_matcher``, but known poses give every photo a position: a large capture that is not a
    video is matched with its nearest cameras (spatial) instead of exhaustively."""
    n = len(records)
    if params.matcher == "spatial":
        return "spatial", "set by sfm.matcher: neighbours by the known camera positions"
    if params.matcher != "auto" or n <= params.exhaustive_max:
        return choose_matcher(records, params)
    if _looks_like_video(records):
        return "sequential", f"{n} photos named as numbered frames"
    return "spatial", f"{n} photos > sfm.exhaustive_max {params.exhaustive_max}: neighbours by the known camera positions"


def triangulate_known_poses(
    image_dir: Path, cameras: CameraSet, records: list[dict], out: Path, params: SfmParams, ctx: StageContext
) -> tuple[Points | None, dict[str, Any]]:
    """Triangulate in a scratch folder, so the stage's result holds only what is the same on every run (COLMAP's
    database and its log, which has timestamps, stay out; a failure's reason is in the summary)."""
    with tempfile.TemporaryDirectory(prefix="nerfpipe-triangulate-") as scratch:
        return _triangulate_in(Path(scratch), image_dir, cameras, records, params, ctx)


def _triangulate_in(
    work: Path, image_dir: Path, cameras: CameraSet, records: list[dict], params: SfmParams, ctx: StageContext
) -> tuple[Points | None, dict[str, Any]]:
    """The pycolmap script: SIFT on the posed photos, matching, then COLMAP's point triangulator with the
    known poses and intrinsics held fixed, its files in ``work``. Returns the points, or None (with the
    reason) when COLMAP fails or keeps fewer than ``min_triangulated_points``; and what happened."""
    import pycolmap

    from nerfpipe.poses.triangulate import (
        known_poses_model, max_pose_change, triangulated_points, write_to_database,
    )

    start = time.monotonic()
    names = [f.name for f in cameras.frames]
    by_name = {r["name"]: r for r in records}
    matcher, why = choose_triangulation_matcher([by_name[n] for n in names], params)
    info: dict[str, Any] = {"photos": len(names), "matcher": matcher, "matcher_reason": why}
    if len(names) < 2:
        return None, {**info, "status": "failed", "reason": f"triangulation needs 2 posed photos, the pose file has {len(names)}"}
    colmap_dir = work / "colmap"
    colmap_dir.mkdir()
    database, log_path = colmap_dir / "database.db", work / "colmap.log"
    pycolmap.set_random_seed(params.seed)
    pycolmap.Database.open(database).close()
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = params.max_image_size
    extraction.sift.max_num_features = params.max_features
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = params.seed
    options.mapper.random_seed = params.seed
    ctx.log.info("sfm: triangulating points for the %d known poses: SIFT, %s matching (%s)", len(names), matcher, why)
    model = known_poses_model(pycolmap, cameras)
    try:
        with colmap_log(pycolmap, log_path):
            with pycolmap.Database.open(database) as db:
                write_to_database(model, db)
            pycolmap.extract_features(database, image_dir, names, pycolmap.CameraMode.PER_IMAGE,
                                      pycolmap.ImageReaderOptions(), extraction, device=pycolmap.Device.auto)
            if matcher == "spatial":
                _write_known_positions(pycolmap, database, cameras)
            _match(pycolmap, database, matcher, params, known_positions=matcher == "spatial")
            (colmap_dir / "triangulated").mkdir()
            model = pycolmap.triangulate_points(model, database, image_dir, colmap_dir / "triangulated", options=options)
    except Exception as err:  # COLMAP raises ValueError / RuntimeError when there is too little to work with
        info.update(status="failed", seconds=round(time.monotonic() - start, 1))
        return None, {**info, "reason": f"triangulation failed ({type(err).__name__}: {str(err).strip()[:200]})"}
    points = triangulated_points(model, cameras)
    count = 0 if points is None else len(points.xyz)
    info.update(points=count, seconds=round(time.monotonic() - start, 1),
                max_pose_change=float(f"{max_pose_change(model, cameras):.3g}"),
                mean_reprojection_error_px=round(float(model.compute_mean_reprojection_error()), 4) if count else None,
                mean_track_length=round(float(model.compute_mean_track_length()), 3) if count else None)
    if count < params.min_triangulated_points:
        return None, {**info, "status": "too_few", "reason": f"triangulation kept only {count} points "
                      f"(< sfm.min_triangulated_points {params.min_triangulated_points})"}
    ctx.log.info("sfm: triangulated %d points in %.0f s, mean reprojection error %.3f px, mean track length %.2f",
                 count, info["seconds"], info["mean_reprojection_error_px"], info["mean_track_length"])
    return points, {**info, "status": "ok"}


def _write_known_positions(pycolmap: Any, database: Path, cameras: CameraSet) -> None:
    """Each photo's known camera centre as a Cartesian position prior, which spatial matching pairs by."""
    centers = {f.name: f.center for f in cameras.frames}
    with pycolmap.Database.open(database) as db:
        for image in db.read_all_images():
            db.write_pose_prior(pycolmap.PosePrior(
                corr_data_id=image.data_id, position=np.asarray(centers[image.name], dtype=np.float64),
                coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN))


# -- structure from motion ---------------------------------------------------------------------------


def run_sfm(
    image_dir: Path, records: list[dict], out: Path, params: SfmParams, ctx: StageContext
) -> tuple[CameraSet, dict[str, Any]]:
    import pycolmap

    names = [r["name"] for r in records]
    if len(names) < params.min_images:
        raise StageError(
            f"only {len(names)} photo{'s' if len(names) != 1 else ''} to reconstruct; SfM needs at least "
            f"{params.min_images} overlapping photos (a NeRF wants dozens): take more photos around the subject"
        )
    colmap_dir = out / "colmap"
    colmap_dir.mkdir()
    log_path = out / "colmap.log"
    pycolmap.set_random_seed(params.seed)
    database = colmap_dir / "database.db"
    pycolmap.Database.open(database).close()

    single = _single_camera(records) if params.single_camera == "auto" else params.single_camera == "yes"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = params.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = params.max_image_size
    extraction.sift.max_num_features = params.max_features
    mode = pycolmap.CameraMode.SINGLE if single else pycolmap.CameraMode.PER_IMAGE
    ctx.log.info("sfm: extracting SIFT features from %d photos (%s)", len(names),
                 "one shared camera" if single else "one camera per photo")
    with colmap_log(pycolmap, log_path):
        pycolmap.extract_features(database, image_dir, names, mode, reader, extraction, device=pycolmap.Device.auto)
    priors = _write_priors(pycolmap, database, records, single)

    matcher, why = choose_matcher(records, params)
    ctx.log.info("sfm: %s matching (%s)", matcher, why)
    with colmap_log(pycolmap, log_path):
        _match(pycolmap, database, matcher, params)
        best = _map(pycolmap, database, image_dir, colmap_dir / "default", params,
                    _mapper_options(pycolmap, params, relaxed=False))
    relaxed_used = False
    if params.relaxed_retry and _registered(best) < len(names):
        ctx.log.info("sfm: %d of %d photos registered; retrying mapping with relaxed options", _registered(best), len(names))
        with colmap_log(pycolmap, log_path):
            retry = _map(pycolmap, database, image_dir, colmap_dir / "relaxed", params,
                         _mapper_options(pycolmap, params, relaxed=True))
        if _registered(retry) > _registered(best):
            best, relaxed_used = retry, True

    registered = _registered(best)
    if registered < params.min_registered * len(names):
        raise StageError(
            f"SfM registered only {registered} of {len(names)} photos"
            f"{' even with relaxed options' if params.relaxed_retry else ''}; the photos may lack texture or overlap. "
            "Try: more photos with 60-80% overlap, --set sfm.matcher=exhaustive, "
            "--set sfm.max_features=16384, or --set ingest.max_size=0 for full-resolution features "
            f"(COLMAP's log: {out / 'colmap.log'})"
        )
    best.write(colmap_dir)  # the kept model, as COLMAP binary files, for other tools
    cameras = camera_set_from_reconstruction(best, records)
    summary = {
        "method": f"colmap {params.mapper}",
        "registered": registered,
        "total": len(names),
        "unregistered": cameras.unregistered,
        "mean_reprojection_error_px": round(float(best.compute_mean_reprojection_error()), 4),
        "mean_track_length": round(float(best.compute_mean_track_length()), 3),
        "points": int(best.num_points3D()),
        "matcher": matcher,
        "matcher_reason": why,
        "single_camera": single,
        "focal_priors": priors,
        "relaxed_retry_used": relaxed_used,
    }
    cameras.extra["sfm"] = summary
    ctx.log.info(
        "sfm: registered %d/%d photos, mean reprojection error %.3f px, mean track length %.2f, %d points%s",
        registered, len(names), summary["mean_reprojection_error_px"], summary["mean_track_length"],
        summary["points"], f"; unregistered: {', '.join(cameras.unregistered)}" if cameras.unregistered else "",
    )
    return cameras, summary


@contextlib.contextmanager
def colmap_log(pycolmap: Any, path: Path) -> Iterator[None]:
    """Send what COLMAP writes to stderr (its glog output) to ``path`` instead of the terminal.

    glog picks its log file once per process, so instead of its file destination the process-level
    stderr is pointed at the stage's log for the duration of each COLMAP call.
    """
    pycolmap.logging.logtostderr = True
    pycolmap.logging.minloglevel = 0
    sys.stderr.flush()
    saved = os.dup(2)
    with open(path, "ab") as log_file:
        os.dup2(log_file.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)


def _single_camera(records: list[dict]) -> bool:
    """One physical camera: every photo has the same size and the same EXIF make, model and focal prior."""
    def identity(r: dict) -> tuple:
        exif = r.get("exif") or {}
        prior = (r.get("focal_prior") or {}).get("focal_px")
        return (r["width"], r["height"], exif.get("make"), exif.get("model"), None if prior is None else round(prior, 1))
    return len({identity(r) for r in records}) == 1


def _write_priors(pycolmap: Any, database: Path, records: list[dict], single: bool) -> int:
    """Seed each camera's focal length with the EXIF prior from ingest, and each image's position with its
    GPS (for spatial matching): COLMAP's own reader sees no EXIF in the PNGs ingest writes."""
    by_name = {r["name"]: r for r in records}
    with pycolmap.Database.open(database) as db:
        cameras = {c.camera_id: c for c in db.read_all_cameras()}
        focal_by_camera: dict[int, list[float]] = {}
        for image in db.read_all_images():
            record = by_name[image.name]
            prior = record.get("focal_prior")
            if prior:
                focal_by_camera.setdefault(image.camera_id, []).append(prior["focal_px"])
            gps = (record.get("exif") or {}).get("gps")
            if gps:
                lat, lon, alt = gps
                db.write_pose_prior(pycolmap.PosePrior(
                    corr_data_id=image.data_id, position=np.array([lat, lon, alt or 0.0], dtype=np.float64),
                    coordinate_system=pycolmap.PosePriorCoordinateSystem.WGS84))
        for camera_id, focals in focal_by_camera.items():
            camera = cameras[camera_id]
            for i in camera.focal_length_idxs():
                camera.params[i] = float(np.median(focals))
            camera.has_prior_focal_length = True
            db.update_camera(camera)
        return sum(len(f) for f in focal_by_camera.values())


def choose_matcher(records: list[dict], params: SfmParams) -> tuple[str, str]:
    """Which COLMAP matcher suits the capture, and why (the reason is logged and kept in the manifest)."""
    n = len(records)
    if params.matcher != "auto":
        return params.matcher, "set by sfm.matcher"
    if n <= params.exhaustive_max:
        return "exhaustive", f"{n} photos <= sfm.exhaustive_max {params.exhaustive_max}"
    with_gps = sum(1 for r in records if (r.get("exif") or {}).get("gps"))
    if with_gps >= 0.9 * n:
        return "spatial", f"{with_gps} of {n} photos carry GPS"
    if _looks_like_video(records):
        return "sequential", f"{n} photos named as numbered frames"
    return "exhaustive", f"{n} photos, no GPS, not numbered frames (exhaustive matching is slow at this size)"


def _looks_like_video(records: list[dict]) -> bool:
    """Frames of a video: ingest took them from one, or their names end in mostly consecutive numbers."""
    if records and all("video_frame" in r for r in records):
        return True
    numbers = []
    for r in records:
        match = re.search(r"(\d+)\D*$", r["name"])
        if match is None:
            return False
        numbers.append(int(match.group(1)))
    steps = np.diff(sorted(numbers))
    return len(steps) > 0 and float(np.median(steps)) <= 2


def _match(pycolmap: Any, database: Path, matcher: str, params: SfmParams, known_positions: bool = False) -> None:
    device = pycolmap.Device.auto
    # two-view RANSAC is seeded too, so the same photos give the same matches, and the same model
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = params.seed
    if matcher == "exhaustive":
        pycolmap.match_exhaustive(database, verification_options=verification, device=device)
    elif matcher == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = params.sequential_overlap
        pycolmap.match_sequential(database, pairing_options=pairing, verification_options=verification, device=device)
    elif known_positions:
        # Cartesian positions in the pose file's units: 3D distances, no distance cut-off, nearest neighbours
        pairing = pycolmap.SpatialPairingOptions()
        pairing.ignore_z = False
        pairing.max_distance = math.inf
        pycolmap.match_spatial(database, pairing_options=pairing, verification_options=verification, device=device)
    else:
        with pycolmap.Database.open(database) as db:
            if db.num_pose_priors() == 0:
                raise StageError("sfm.matcher=spatial needs GPS in the photos' EXIF; none was found. "
                                 "Use --set sfm.matcher=exhaustive or sequential")
        pycolmap.match_spatial(database, verification_options=verification, device=device)


def _mapper_options(pycolmap: Any, params: SfmParams, relaxed: bool) -> Any:
    if params.mapper == "global":
        options = pycolmap.GlobalPipelineOptions()
        options.random_seed = params.seed
        if relaxed:
            options.min_num_matches = 10
        return options
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = params.seed
    options.mapper.random_seed = params.seed
    if relaxed:
        # Fewer inliers to start and to register, a smaller initial triangulation angle: what gets
        # low-texture objects on a sparse ring (like the Middlebury temple) fully registered.
        options.min_num_matches = 10
        options.mapper.init_min_num_inliers = 50
        options.mapper.abs_pose_min_num_inliers = 15
        options.mapper.abs_pose_min_inlier_ratio = 0.1
        options.mapper.init_min_tri_angle = 4.0
    return options


def _map(pycolmap: Any, database: Path, image_dir: Path, output: Path, params: SfmParams, options: Any) -> Any:
    """Run the mapper; returns the reconstruction with the most registered images (or None)."""
    output.mkdir()
    if params.mapper == "global":
        models = pycolmap.global_mapping(database, image_dir, output, options)
    else:
        models = pycolmap.incremental_mapping(database, image_dir, output, options)
    return max(models.values(), key=lambda m: m.num_reg_images(), default=None)


def _registered(model: Any) -> int:
    return 0 if model is None else int(model.num_reg_images())


def camera_set_from_reconstruction(model: Any, records: list[dict]) -> CameraSet:
    """A pycolmap ``Reconstruction`` of the ingested images as a ``CameraSet`` (OpenCV c2w, COLMAP cameras)."""
    from nerfpipe.poses.importers import colmap_points

    cameras = {int(cid): Camera(c.model.name, int(c.width), int(c.height), tuple(float(p) for p in c.params))
               for cid, c in model.cameras.items()}
    split_of = {r["name"]: r.get("split") for r in records}
    frames, frame_of_image = [], {}
    for image in sorted((img for img in model.images.values() if img.has_pose), key=lambda img: img.name):
        w2c = np.vstack([np.asarray(image.cam_from_world().matrix(), dtype=np.float64), [0.0, 0.0, 0.0, 1.0]])
        frame_of_image[image.image_id] = len(frames)
        frames.append(Frame(image.name, int(image.camera_id), invert_pose(w2c), split_of.get(image.name)))
    registered = {f.name for f in frames}
    unregistered = [r["name"] for r in records if r["name"] not in registered]
    points = colmap_points(model, frame_of_image, len(frames))
    return CameraSet(cameras, frames, points, "colmap_sfm", unregistered)
