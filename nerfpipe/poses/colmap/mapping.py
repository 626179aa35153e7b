"""Structure from motion with COLMAP: SIFT extraction with the EXIF focal prior, matching, incremental or
global mapping (retried once with relaxed options), and the CameraSet of the model it gives."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pycolmap

from nerfpipe.artifacts import PhotoRecord
from nerfpipe.geometry.cameras import Camera, CameraSet, Frame, invert_pose
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.stage import StageContext
from nerfpipe.poses.colmap.log import colmap_log
from nerfpipe.poses.colmap.matching import choose_matcher, match_features


def run_sfm(
    image_dir: Path, records: list[PhotoRecord], out: Path, params: Any, ctx: StageContext
) -> tuple[CameraSet, dict[str, Any]]:

    names = [r.name for r in records]
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

    single = single_camera(records) if params.single_camera == "auto" else params.single_camera == "yes"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = params.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = params.max_image_size
    extraction.sift.max_num_features = params.max_features
    mode = pycolmap.CameraMode.SINGLE if single else pycolmap.CameraMode.PER_IMAGE
    ctx.log.info("sfm: extracting SIFT features from %d photos (%s)", len(names),
                 "one shared camera" if single else "one camera per photo")
    # the bar: features, matches, then one step per photo the mapper registers
    with ctx.progress(len(names) + 2, "sfm") as advance:
        with colmap_log(log_path):
            pycolmap.extract_features(database, image_dir, names, mode, reader, extraction, device=pycolmap.Device.auto)
        priors = write_priors(database, records, single)
        advance(1, "features extracted")

        matcher, why = choose_matcher(records, params)
        ctx.log.info("sfm: %s matching (%s)", matcher, why)
        with colmap_log(log_path):
            match_features(database, matcher, params)
            advance(1, "matched")
            best = map_images(database, image_dir, colmap_dir / "default", params,
                              mapper_options(params, relaxed=False), Registered(advance, len(names)))
    relaxed_used = False
    if params.relaxed_retry and registered_count(best) < len(names):
        ctx.log.info("sfm: %d of %d photos registered; retrying mapping with relaxed options", registered_count(best), len(names))
        with colmap_log(log_path), ctx.progress(len(names), "sfm, relaxed") as advance:
            retry = map_images(database, image_dir, colmap_dir / "relaxed", params,
                               mapper_options(params, relaxed=True), Registered(advance, len(names)))
        if registered_count(retry) > registered_count(best):
            best, relaxed_used = retry, True

    registered = registered_count(best)
    if registered < params.min_registered * len(names):
        raise StageError(
            f"SfM registered only {registered} of {len(names)} photos"
            f"{' even with relaxed options' if params.relaxed_retry else ''}; the photos may lack texture or overlap. "
            "Try: more photos with 60-80% overlap, "
            f"{'--set sfm.matcher=exhaustive, ' if matcher != 'exhaustive' else ''}"
            f"{f'--set sfm.max_features={2 * params.max_features}, ' if params.max_features < 32768 else ''}"
            "or --set ingest.max_size=0 for full-resolution features "
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
    cameras.hints.sfm = summary
    ctx.log.info(
        "sfm: registered %d/%d photos, mean reprojection error %.3f px, mean track length %.2f, %d points%s",
        registered, len(names), summary["mean_reprojection_error_px"], summary["mean_track_length"],
        summary["points"], f"; unregistered: {', '.join(cameras.unregistered)}" if cameras.unregistered else "",
    )
    return cameras, summary


def single_camera(records: list[PhotoRecord]) -> bool:
    """One physical camera: every photo has the same size and the same EXIF make, model and focal prior."""
    def identity(r: PhotoRecord) -> tuple:
        exif = r.exif or {}
        prior = (r.focal_prior or {}).get("focal_px")
        return (r.width, r.height, exif.get("make"), exif.get("model"), None if prior is None else round(prior, 1))
    return len({identity(r) for r in records}) == 1


def write_priors(database: Path, records: list[PhotoRecord], single: bool) -> int:
    """Seed each camera's focal length with the EXIF prior from ingest, and each image's position with its
    GPS (for spatial matching): COLMAP's own reader sees no EXIF in the PNGs ingest writes."""
    by_name = {r.name: r for r in records}
    with pycolmap.Database.open(database) as db:
        cameras = {c.camera_id: c for c in db.read_all_cameras()}
        focal_by_camera: dict[int, list[float]] = {}
        for image in db.read_all_images():
            record = by_name[image.name]
            prior = record.focal_prior
            if prior:
                focal_by_camera.setdefault(image.camera_id, []).append(prior["focal_px"])
            gps = (record.exif or {}).get("gps")
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


def mapper_options(params: Any, relaxed: bool) -> Any:
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


class Registered:
    """The incremental mapper's callbacks as steps of a progress bar of ``photos`` steps: two for the initial
    pair, one for each photo it adds after. COLMAP calls back on every registration, those of a model it later
    drops and of photos registered again included (35 calls for the temple's 16), so the bar stops at its end."""

    def __init__(self, advance: Any, photos: int) -> None:
        self.advance, self.left, self.calls = advance, photos, 0

    def _step(self, n: int) -> None:
        self.calls += n
        taken = min(n, self.left)
        self.left -= taken
        self.advance(taken, f"mapping: {self.calls} registrations")

    def initial_pair(self) -> None:
        self._step(2)

    def next_image(self) -> None:
        self._step(1)


def map_images(database: Path, image_dir: Path, output: Path, params: Any, options: Any,
               registered: Registered | None = None) -> Any:
    """Run the mapper; returns the reconstruction with the most registered images (or None). The incremental
    mapper tells ``registered`` of each photo it adds (the global one of none)."""
    output.mkdir()
    if params.mapper == "global":
        models = pycolmap.global_mapping(database, image_dir, output, options)
    else:
        callbacks = {} if registered is None else {"initial_image_pair_callback": registered.initial_pair,
                                                   "next_image_callback": registered.next_image}
        models = pycolmap.incremental_mapping(database, image_dir, output, options, **callbacks)
    return max(models.values(), key=lambda m: m.num_reg_images(), default=None)


def registered_count(model: Any) -> int:
    return 0 if model is None else int(model.num_reg_images())


def camera_set_from_reconstruction(model: Any, records: list[PhotoRecord]) -> CameraSet:
    """A pycolmap ``Reconstruction`` of the ingested images as a ``CameraSet`` (OpenCV c2w, COLMAP cameras)."""
    from nerfpipe.poses.importers import colmap_points

    cameras = {int(cid): Camera(c.model.name, int(c.width), int(c.height), tuple(float(p) for p in c.params))
               for cid, c in model.cameras.items()}
    split_of = {r.name: r.split for r in records}
    frames, frame_of_image = [], {}
    for image in sorted((img for img in model.images.values() if img.has_pose), key=lambda img: img.name):
        w2c = np.vstack([np.asarray(image.cam_from_world().matrix(), dtype=np.float64), [0.0, 0.0, 0.0, 1.0]])
        frame_of_image[image.image_id] = len(frames)
        frames.append(Frame(image.name, int(image.camera_id), invert_pose(w2c), split_of.get(image.name)))
    registered = {f.name for f in frames}
    unregistered = [r.name for r in records if r.name not in registered]
    points = colmap_points(model, frame_of_image, len(frames))
    return CameraSet(cameras, frames, points, "colmap_sfm", unregistered)
