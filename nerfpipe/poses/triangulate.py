"""Sparse points for known poses: the pieces between a ``CameraSet`` and COLMAP's point triangulator.

Pose files without points (LLFF, ``transforms.json``, Middlebury) still describe photos whose features
can be matched and triangulated with the poses held fixed, which gives the bounds stage the same
evidence SfM gives it. This module turns the known cameras into a
``pycolmap.Reconstruction`` (``known_poses_model``) and writes it into the COLMAP database the sfm stage
then extracts and matches features into (``write_to_database``), and turns COLMAP's triangulated points
back into ``Points`` indexed by the ``CameraSet``'s frames (``triangulated_points``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from nerfpipe.geometry.cameras import CameraSet, Points
from nerfpipe.poses.importers import colmap_points


def known_poses_model(pycolmap: Any, cameras: CameraSet) -> Any:
    """A reconstruction of ``cameras``: image ``i + 1`` is frame ``i`` registered at its known pose, with a
    camera (and trivial rig and frame) of its own holding the frame's known intrinsics; no points.

    Every camera is marked as a focal-length prior, so two-view verification of the matches uses the
    calibration rather than a guess.
    """
    model = pycolmap.Reconstruction()
    for index, frame in enumerate(cameras.frames, start=1):
        known = cameras.camera_of(frame)
        camera = pycolmap.Camera(model=known.model, width=known.width, height=known.height,
                                 params=list(known.params), camera_id=index)
        camera.has_prior_focal_length = True
        model.add_camera_with_trivial_rig(camera)
        w2c = frame.w2c
        model.add_image_with_trivial_frame(pycolmap.Image(name=frame.name, camera_id=index, image_id=index),
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
