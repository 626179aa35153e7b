"""``RUN_DIR/exports/`` from a pipeline's current results (``nerfpipe.export.bundle``), written after every
``nerfpipe run`` and by ``nerfpipe export``."""

from __future__ import annotations

import numpy as np

from nerfpipe.export.bundle import FILES, Exported, collect
from nerfpipe.pipeline import Pipeline


def refresh_exports(pipe: Pipeline) -> Exported:
    """Collect the current results of ``pipe`` into its run's ``exports/``: the files the export and render
    stages made, and the trained cameras in the SfM frame with their photos (the undistorted ones where
    undistortion made them)."""
    from nerfpipe.artifacts import Bounds
    from nerfpipe.export.paths import transform_poses
    from nerfpipe.geometry.cameras import CameraSet, Frame

    artifacts = {name: pipe.optional_artifact(name) for name, _ in FILES}
    world, bounds = pipe.optional_artifact("cameras"), pipe.optional_artifact("bounds")
    cameras, images = None, {}
    if world is not None and bounds is not None:
        trained = CameraSet.load(world)
        to_sfm = Bounds.load(bounds).to_sfm
        poses = transform_poses(np.array([f.c2w for f in trained.frames]), to_sfm) if trained.frames else []
        frames = [Frame(f.name, f.camera_id, pose, f.split) for f, pose in zip(trained.frames, poses)]
        cameras = CameraSet(trained.cameras, frames, None, trained.source)
        folders = [p for p in (pipe.optional_artifact("undistorted_images"), pipe.optional_artifact("images")) if p]
        for frame in frames:
            images[frame.name] = next((folder / frame.name for folder in folders if (folder / frame.name).is_file()),
                                      None)
        if any(path is None for path in images.values()):
            cameras, images = None, {}
    mesh = artifacts.get("mesh")
    extra = tuple(sorted(p for p in mesh.parent.glob("mesh_*.*") if p.suffix in (".ply", ".obj", ".glb"))) if mesh else ()
    return collect(pipe.run_dir, artifacts, cameras, images, extra)
