"""Small inputs of the NeRF policy for the tests: scene decisions, bounds, and image folders with a loader."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nerfpipe.artifacts import Bounds, Decision, FrameBounds, SceneDecisions
from nerfpipe.geometry.cameras import Camera, CameraSet, Frame, PoseHints
from nerfpipe.imaging.png import write_png
from nerfpipe.nerf.train.images import ImageLoader


def scene_of(layout: str, background: str = "none", color=None, photometric: str = "srgb",
             tolerance: float | None = None, stops: dict[str, float] | None = None) -> SceneDecisions:
    """Scene decisions with the values the policy reads; the rest as a plain capture's. ``tolerance``: the
    backdrop tolerance the scene analysis measured with (none recorded when None); ``stops``: each photo's
    exposure, which then varies."""
    box = ([-1.0] * 3, [1.0] * 3)
    measured = {} if tolerance is None else {"tolerance": tolerance}
    exposure = Decision(stops is not None, "", False, {} if stops is None else {"stops": stops})
    return SceneDecisions(Decision(layout, ""), Decision(background, "", False, measured), Decision(color, ""),
                          Decision("pinhole", ""),
                          Decision(photometric, ""), exposure, 2.0, 9.0, box)


def bounds_of(*near_far: tuple[float, float], names: tuple[str, ...] = ()) -> Bounds:
    """Bounds in [-1, 1]^3 with one frame per (near, far), named ``names`` (else img0.png, img1.png ...)."""
    names = names or tuple(f"img{i}.png" for i in range(len(near_far)))
    frames = tuple(FrameBounds(name, near, far, "points") for name, (near, far) in zip(names, near_far))
    eye = np.eye(4).tolist()
    return Bounds(eye, eye, 1.0, [0.0, 0.0, 1.0], "inward", "points", ([-1] * 3, [1] * 3), 2.0, 9.0, frames)


def world_of_one_camera() -> CameraSet:
    return CameraSet({1: Camera.pinhole(50, 50, 20, 15, 40, 30)}, [Frame("a.png", 1, np.eye(4))])


IMAGES = ("a.png", "grey.png", "b.png")
WIDTH, HEIGHT = 12, 8  # SSIM's 11x11 window needs more than 5 pixels a side


def write_image_folders(root: Path) -> dict[str, Path]:
    """Ingest's folder with a 12x8 RGBA image (red at alpha 0.2) and a grey one (128), undistort's with a white
    RGB one; the pinhole camera set says which folder holds which."""
    images, undistorted, pinhole = root / "images", root / "undistorted", root / "pinhole"
    pinhole.mkdir(parents=True)
    rgba = np.zeros((HEIGHT, WIDTH, 4), np.uint8)
    rgba[..., 0], rgba[..., 3] = 255, 51
    write_png(images / "a.png", rgba)
    write_png(images / "grey.png", np.full((HEIGHT, WIDTH), 128, np.uint8))
    write_png(undistorted / "b.png", np.full((HEIGHT, WIDTH, 3), 255, np.uint8))
    CameraSet({}, [], hints=PoseHints(image_roots={"a.png": "ingest", "grey.png": "ingest", "b.png": "undistort"})).save(pinhole)
    return {"images": images, "undistorted_images": undistorted, "pinhole": pinhole}


def loader_of(folders: dict[str, Path], background: str = "alpha", width: int = WIDTH,
              tolerance: float | None = None) -> ImageLoader:
    """A loader of the three images (cameras ``width`` x 8; near/far (1, 5), (2, 6), (3, 7)) over a blue backdrop
    (``tolerance``: the one the scene analysis recorded for a ``color`` background)."""
    world = CameraSet({1: Camera.pinhole(10.0, 10.0, 6.0, 4.0, width, HEIGHT)}, [Frame(name, 1, np.eye(4)) for name in IMAGES])
    bounds = bounds_of((1.0, 5.0), (2.0, 6.0), (3.0, 7.0), names=IMAGES)
    scene = scene_of("inward360", background, [0.0, 0.0, 1.0] if background != "none" else None, tolerance=tolerance)
    return ImageLoader(folders["images"], folders["undistorted_images"], folders["pinhole"], world, bounds, scene)
