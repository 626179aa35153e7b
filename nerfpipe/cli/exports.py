"""``RUN_DIR/exports/`` from a pipeline's current results (``nerfpipe.export.bundle``), written after every
``nerfpipe run`` and by ``nerfpipe export``."""

from __future__ import annotations

import numpy as np

from nerfpipe.export.bundle import FILES, CapturedViews, Exported, collect
from nerfpipe.pipeline import Pipeline


def refresh_exports(pipe: Pipeline) -> Exported:
    """Collect the current results of ``pipe`` into its run's ``exports/``: the files the export and render
    stages made, and what the camera exports are made of (``captured_views``)."""
    artifacts = {name: pipe.optional_artifact(name) for name, _ in FILES}
    mesh = artifacts.get("mesh")
    # the optional meshes (mesh_watertight.*, mesh_poisson.*) and the textured OBJ's material and texture
    extra = tuple(sorted(p for p in mesh.parent.glob("mesh*.*") if p.suffix in (".ply", ".obj", ".glb", ".mtl", ".png")
                         and p.name not in {name for _, name in FILES}) if mesh else ())
    return collect(pipe.run_dir, artifacts, captured_views(pipe), extra)


def captured_views(pipe: Pipeline) -> CapturedViews | None:
    """The trained cameras in the SfM frame with their photos (the undistorted ones where undistortion made
    them), the SfM points, the held-out split, the masks where the scene has a backdrop or alpha, and the depth
    maps' index; None before the cameras are trained."""
    from nerfpipe.artifacts import Bounds, ViewSplit
    from nerfpipe.export.depth import DepthIndex
    from nerfpipe.export.paths import transform_poses
    from nerfpipe.geometry.cameras import CameraSet, Frame

    world, bounds = pipe.optional_artifact("cameras"), pipe.optional_artifact("bounds")
    if world is None or bounds is None:
        return None
    trained = CameraSet.load(world)
    to_sfm = Bounds.load(bounds).to_sfm
    poses = transform_poses(np.array([f.c2w for f in trained.frames]), to_sfm) if trained.frames else []
    frames = [Frame(f.name, f.camera_id, pose, f.split) for f, pose in zip(trained.frames, poses)]
    cameras = CameraSet(trained.cameras, frames, None, trained.source)
    folders = [p for p in (pipe.optional_artifact("undistorted_images"), pipe.optional_artifact("images")) if p]
    images = {frame.name: next((folder / frame.name for folder in folders if (folder / frame.name).is_file()), None)
              for frame in frames}
    if any(path is None for path in images.values()):
        return None
    sfm = pipe.optional_artifact("sfm_model")
    views, depth = pipe.optional_artifact("views"), pipe.optional_artifact("depth_index")
    return CapturedViews(cameras, images, CameraSet.load(sfm).points if sfm is not None else None, masks(pipe, trained),
                         tuple(ViewSplit.load(views).heldout) if views is not None else (),
                         DepthIndex.load(depth) if depth is not None else None)


def masks(pipe: Pipeline, trained) -> dict[str, np.ndarray] | None:
    """Each trained frame's mask as training used it (alpha, or the pixels off the constant backdrop); None
    when the scene has neither."""
    from nerfpipe.nerf.train.images import ImageLoader
    from nerfpipe.pipeline import NerfpipeError

    try:
        loader = ImageLoader.from_inputs(pipe.stage_inputs("train"))
    except NerfpipeError:
        return None
    if not loader.use_alpha and loader.backdrop is None:
        return None
    found = {f.name: loader.alpha(f) if loader.use_alpha else loader.foreground(f) for f in trained.frames}
    return {name: mask for name, mask in found.items() if mask is not None} or None
