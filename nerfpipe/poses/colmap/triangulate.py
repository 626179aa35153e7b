"""Sparse points for known poses: the pieces between a ``CameraSet`` and COLMAP's point triangulator.

Pose files without points (LLFF, ``transforms.json``, Middlebury) still describe photos whose features
can be matched and triangulated with the poses held fixed, which gives the bounds stage the same
evidence SfM gives it. This module turns the known cameras into a
``pycolmap.Reconstruction`` (``known_poses_model``) and writes it into the COLMAP database the sfm stage
then extracts and matches features into (``write_to_database``), and turns COLMAP's triangulated points
back into ``Points`` indexed by the ``CameraSet``'s frames (``triangulated_points``).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pycolmap

from nerfpipe.artifacts import PhotoRecord
from nerfpipe.geometry.cameras import Camera, CameraSet, Points, invert_pose
from nerfpipe.pipeline.stage import StageContext
from nerfpipe.poses.colmap.log import colmap_log
from nerfpipe.poses.colmap.matching import choose_matcher, match_features
from nerfpipe.poses.importers import colmap_points


def with_distortion(camera: Camera) -> Camera:
    """``camera`` in a model whose lens distortion bundle adjustment can refine, projecting as it does: a pinhole
    with one focal length as its radial twin with no distortion yet (SIMPLE_RADIAL: one term, as COLMAP fits a
    phone's lens by default). Any other camera as it is: a pinhole with two focal lengths (a lab's calibration,
    such as the temple's) would need OPENCV's four terms, which a photo's few hundred points do not pin down."""
    if camera.model == "SIMPLE_PINHOLE" or (camera.model == "PINHOLE" and camera.fx == camera.fy):
        return replace(camera, model="SIMPLE_RADIAL", params=(camera.fx, camera.cx, camera.cy, 0.0))
    return camera


def known_poses_model(cameras: CameraSet) -> Any:
    """A reconstruction of ``cameras``: image ``i + 1`` is frame ``i`` registered at its known pose, with the
    camera (and its trivial rig) of the ``CameraSet`` camera it shares with the frames that name the same one,
    in the model ``with_distortion`` gives it; no points.

    Every camera is marked as a focal-length prior, so two-view verification of the matches uses the
    calibration rather than a guess.
    """
    model = pycolmap.Reconstruction()
    for camera_id, known in sorted(cameras.cameras.items()):
        known = with_distortion(known)
        camera = pycolmap.Camera(model=known.model, width=known.width, height=known.height,
                                 params=list(known.params), camera_id=camera_id)
        camera.has_prior_focal_length = True
        model.add_camera_with_trivial_rig(camera)
    for index, frame in enumerate(cameras.frames, start=1):
        w2c = frame.w2c
        model.add_image_with_trivial_frame(pycolmap.Image(name=frame.name, camera_id=frame.camera_id, image_id=index),
                                           pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3]))
    return model


def write_to_database(model: Any, db: Any) -> None:
    """The cameras, rigs, frames and images of ``model`` into the empty open database ``db``, keeping their ids.

    Feature extraction then adds keypoints to these images instead of creating its own, whose ids would
    follow the order in which parallel workers happen to finish; fixed ids keep the matching, and with it
    the triangulated points, the same from run to run.
    """
    for camera_id in sorted(model.cameras):
        db.write_camera(model.cameras[camera_id], use_camera_id=True)
    for rig_id in sorted(model.rigs):
        db.write_rig(model.rigs[rig_id], use_rig_id=True)
    for frame_id in sorted(model.frames):
        db.write_frame(model.frames[frame_id], use_frame_id=True)
    for image_id in sorted(model.images):
        db.write_image(model.images[image_id], use_image_id=True)


def triangulated_points(model: Any, cameras: CameraSet) -> Points | None:
    """The points of ``model`` (a triangulated ``known_poses_model``), each frame's visibility by name."""
    index = {frame.name: i for i, frame in enumerate(cameras.frames)}
    frame_of_image = {int(image_id): index[image.name] for image_id, image in model.images.items()
                      if image.name in index}
    return colmap_points(model, frame_of_image, len(cameras.frames))


KEEP_ADJUSTED = 0.8  # bundle adjustment's poses and intrinsics are kept (auto) where they reproject within this share
MATCH_NOISE_PX = 0.5  # and where the given ones reproject beyond this: SIFT's matches cannot tell what is within it


def adjusts(choice: str, before: float, after: float, points_before: int, points_after: int) -> bool:
    """Whether the bundle-adjusted poses and intrinsics replace the given ones: where the adjusted cameras still
    triangulate at least half the points (fewer: the adjustment went astray), and ``sfm.bundle_adjust`` is on, or
    auto, the given ones reproject beyond ``MATCH_NOISE_PX`` and the adjusted ones within ``KEEP_ADJUSTED`` times
    that. A calibration the matches cannot improve on stays: the temple's lab calibration (0.36 px) does."""
    if choice == "off" or 2 * points_after < points_before:
        return False
    return choice == "on" or (before > MATCH_NOISE_PX and after <= KEEP_ADJUSTED * before)


SHARED_BY = 3  # photos a camera needs for its focal length and distortion to be adjusted
ONE_FOCAL = frozenset({"SIMPLE_RADIAL", "RADIAL"})  # the models whose intrinsics are adjusted (``with_distortion``)


def lenses_adjustable(model: Any) -> bool:
    """Whether every camera of ``model`` has one focal length and radial terms (``ONE_FOCAL``) and is shared by
    ``SHARED_BY`` photos or more: where ``bundle_adjust`` refines the lenses too."""
    photos = [image.camera_id for image in model.images.values()]
    return all(camera.model.name in ONE_FOCAL and photos.count(camera_id) >= SHARED_BY
               for camera_id, camera in model.cameras.items())


def bundle_adjust(model: Any) -> tuple[float, float]:
    """Refine ``model``'s poses and points together, and its focal lengths and lens distortion where every camera
    has one focal length and one or two radial terms and is shared by ``SHARED_BY`` photos or more (COLMAP's
    bundle adjuster; principal points held, which a capture's matches fix poorly), in place. Two focal lengths
    trade against the cameras' distance: on the temple's calibrated camera (16 photos, 24 degrees across) fx
    moved 14 % and fy the other way. Returns the mean reprojection error in pixels before and after."""
    model.update_point_3d_errors()
    before = float(model.compute_mean_reprojection_error())
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = options.refine_extra_params = lenses_adjustable(model)
    options.refine_principal_point = False
    pycolmap.bundle_adjustment(model, options)
    model.update_point_3d_errors()
    return before, float(model.compute_mean_reprojection_error())


ADJUST_ROUNDS = 3


def adjust_in_rounds(model: Any, triangulate: Callable[[Any, int], Any],
                     rounds: int = ADJUST_ROUNDS) -> tuple[Any, float, float]:
    """``bundle_adjust`` ``rounds`` times, the matches triangulated again (``triangulate(model, round)``, a new
    model) through the adjusted poses and lenses between rounds: a lens the given intrinsics left out puts the
    photos' corners beyond the triangulator's reach (the cup's, 7 px), so the first round sees their centres
    only. Returns the last model and the mean reprojection error before the first round and after the last."""
    before = None
    for index in range(rounds):
        first, after = bundle_adjust(model)
        before = first if before is None else before
        if index < rounds - 1:
            model = triangulate(model, index)
    return model, before, after


def adjusted_cameras(model: Any, cameras: CameraSet) -> CameraSet:
    """``cameras`` with the intrinsics and poses of ``model`` (a ``known_poses_model``, bundle-adjusted) and its
    points; the frames, their order and the hints as they were."""
    intrinsics = {camera_id: Camera(camera.model.name, int(camera.width), int(camera.height),
                                    tuple(float(v) for v in camera.params))
                  for camera_id, camera in model.cameras.items()}
    by_name = {image.name: image for image in model.images.values()}
    frames = [replace(frame, c2w=invert_pose(np.vstack([np.asarray(by_name[frame.name].cam_from_world().matrix()),
                                                        [0.0, 0.0, 0.0, 1.0]])))
              for frame in cameras.frames]
    return replace(cameras, cameras=intrinsics, frames=frames, points=triangulated_points(model, cameras))


def max_pose_change(model: Any, cameras: CameraSet) -> float:
    """Largest difference between a frame's known w2c (4x4) and the triangulated model's, over all entries:
    0 when the poses were held fixed, as they must be."""
    by_name = {frame.name: frame for frame in cameras.frames}
    change = 0.0
    for image in model.images.values():
        if image.name in by_name and image.has_pose:
            w2c = np.asarray(image.cam_from_world().matrix(), dtype=np.float64)
            change = max(change, float(np.abs(w2c - by_name[image.name].w2c[:3]).max()))
    return change


def choose_triangulation_matcher(records: list[PhotoRecord], params: Any) -> tuple[str, str]:
    """Which photos to match when the poses are known. All pairs up to ``sfm.exhaustive_max`` photos where bundle
    adjustment follows (``sfm.bundle_adjust``): the pairs across the capture are what tie its poses together. On
    the cup (77 photos, LLFF poses) all 2926 pairs took 56 s to triangulate against 32 s for each photo's 10
    nearest cameras, and its held-out views scored 27.2 dB after adjustment against 25.8-26.1 with 10 or 20
    nearest. Beyond that, or with the poses as given, each photo with its ``sfm.spatial_neighbors`` nearest
    cameras (spatial), since the poses say which photos can see the same points: against all pairs, 10
    neighbours kept 99 % of the cup's points at a lower reprojection error in 37 % of the time."""
    n = len(records)
    if params.matcher == "spatial":
        return "spatial", f"set by sfm.matcher: each photo with its {params.spatial_neighbors} nearest cameras"
    if params.matcher != "auto":
        return choose_matcher(records, params)
    if n <= 2 * params.spatial_neighbors:
        return "exhaustive", f"{n} photos <= 2 x sfm.spatial_neighbors {params.spatial_neighbors}"
    if params.bundle_adjust != "off" and n <= params.exhaustive_max:
        return "exhaustive", (f"{n} photos <= sfm.exhaustive_max {params.exhaustive_max}: all pairs, which tie the "
                              "poses together for bundle adjustment")
    return "spatial", f"{n} known poses: each photo with its {params.spatial_neighbors} nearest cameras"


def triangulate_known_poses(
    image_dir: Path, cameras: CameraSet, records: list[PhotoRecord], out: Path, params: Any, ctx: StageContext
) -> tuple[CameraSet | None, dict[str, Any]]:
    """Triangulate in a scratch folder, so the stage's result holds only what is the same on every run (COLMAP's
    database and its log, which has timestamps, stay out; a failure's reason is in the summary)."""
    with tempfile.TemporaryDirectory(prefix="nerfpipe-triangulate-") as scratch:
        return triangulate_in(Path(scratch), image_dir, cameras, records, params, ctx)


def triangulate_in(
    work: Path, image_dir: Path, cameras: CameraSet, records: list[PhotoRecord], params: Any, ctx: StageContext
) -> tuple[CameraSet | None, dict[str, Any]]:
    """The pycolmap script: SIFT on the posed photos, matching, COLMAP's point triangulator with the known poses
    and intrinsics held fixed, its files in ``work``, then bundle adjustment as ``sfm.bundle_adjust`` asks
    (``adjusts``). Returns ``cameras`` with the points (and the adjusted poses and intrinsics where kept), or
    None (with the reason) when COLMAP fails or keeps fewer than ``min_triangulated_points``; and what happened."""
    start = time.monotonic()
    names = [f.name for f in cameras.frames]
    by_name = {r.name: r for r in records}
    matcher, why = choose_triangulation_matcher([by_name[n] for n in names], params)
    info: dict[str, Any] = {"photos": len(names), "matcher": matcher, "matcher_reason": why,
                            "max_image_size": min(params.triangulate_max_size, params.max_image_size)}
    if len(names) < 2:
        return None, {**info, "status": "failed", "reason": f"triangulation needs 2 posed photos, the pose file has {len(names)}"}
    colmap_dir = work / "colmap"
    colmap_dir.mkdir()
    database, log_path = colmap_dir / "database.db", work / "colmap.log"
    pycolmap.set_random_seed(params.seed)
    pycolmap.Database.open(database).close()
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = min(params.triangulate_max_size, params.max_image_size)
    extraction.sift.max_num_features = params.max_features
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = params.seed
    options.mapper.random_seed = params.seed
    ctx.log.info("sfm: triangulating points for the %d known poses: SIFT at %d px, %s matching (%s)", len(names),
                 extraction.max_image_size, matcher, why)
    model = known_poses_model(cameras)
    try:
        with colmap_log(log_path):
            with pycolmap.Database.open(database) as db:
                write_to_database(model, db)
            pycolmap.extract_features(database, image_dir, names, pycolmap.CameraMode.PER_IMAGE,
                                      pycolmap.ImageReaderOptions(), extraction, device=pycolmap.Device.auto)
            if matcher == "spatial":
                write_known_positions(database, cameras)
            match_features(database, matcher, params, known_positions=matcher == "spatial")
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
    result = replace(cameras, points=points)
    if params.bundle_adjust != "off":
        def again(adjusted: Any, index: int) -> Any:
            (colmap_dir / f"adjusted{index}").mkdir()
            return pycolmap.triangulate_points(adjusted, database, image_dir, colmap_dir / f"adjusted{index}",
                                               options=options)

        try:
            with colmap_log(log_path):
                model, before, after = adjust_in_rounds(model, again)
        except Exception as err:  # as above: COLMAP's errors on too little to work with
            ctx.log.warning("sfm: bundle adjustment failed (%s: %s); the given poses and intrinsics stay",
                            type(err).__name__, str(err).strip()[:200])
            return result, {**info, "status": "ok", "bundle_adjustment": {"failed": str(err).strip()[:200]}}
        keep = adjusts(params.bundle_adjust, before, after, count, model.num_points3D())
        info["bundle_adjustment"] = {"before_px": round(before, 4), "after_px": round(after, 4),
                                     "points": model.num_points3D(), "kept": keep}
        if keep:
            result = adjusted_cameras(model, cameras)
        ctx.log.info("sfm: bundle adjustment of the poses%s: mean reprojection error %.3f -> %.3f px over %d points, "
                     "%s", ", focal lengths and lens distortion" if lenses_adjustable(model) else " (the lenses as given)",
                     before, after, model.num_points3D(), "kept" if keep else
                     f"not kept (within {MATCH_NOISE_PX:g} px before, less than {1 - KEEP_ADJUSTED:.0%} lower, "
                     "or under half the points: the given calibration stays)")
    return result, {**info, "status": "ok"}


def write_known_positions(database: Path, cameras: CameraSet) -> None:
    """Each photo's known camera centre as a Cartesian position prior, which spatial matching pairs by."""
    centers = {f.name: f.center for f in cameras.frames}
    with pycolmap.Database.open(database) as db:
        for image in db.read_all_images():
            db.write_pose_prior(pycolmap.PosePrior(
                corr_data_id=image.data_id, position=np.asarray(centers[image.name], dtype=np.float64),
                coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN))
