"""``RUN_DIR/exports/`` from a pipeline's current results (``nerfpipe.export.bundle``), written after every
``nerfpipe run`` and by ``nerfpipe export``."""

from __future__ import annotations

from pathlib import Path

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
    from nerfpipe.export.bundle import in_sfm_frame
    from nerfpipe.export.depth import DepthIndex
    from nerfpipe.geometry.cameras import CameraSet

    world, bounds = pipe.optional_artifact("cameras"), pipe.optional_artifact("bounds")
    if world is None or bounds is None:
        return None
    trained = CameraSet.load(world)
    cameras = in_sfm_frame(trained, Bounds.load(bounds).to_sfm)
    frames = cameras.frames
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


def masks(pipe: Pipeline, trained) -> dict[str, Path] | None:
    """Each trained frame's mask as the train stage wrote it (``masks/``: alpha, or the pixels off the constant
    backdrop), by frame name; None when it wrote none."""
    from nerfpipe.artifacts import mask_file

    folder = pipe.optional_artifact("masks")
    if folder is None or not folder.is_dir():
        return None
    found = {f.name: folder / mask_file(f.name) for f in trained.frames}
    return {name: path for name, path in found.items() if path.is_file()} or None
