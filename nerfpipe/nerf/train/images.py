"""The posed training images: which views train and which are held out, and their pixels as training targets.

Held-out views: the capture's test (else val) split when it has one; otherwise every ``holdout_every``-th
image, as the paper holds out 1/8 of its real scenes (Section 6.1).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from nerfpipe.artifacts import BOUNDS, SCENE, WORLD, Bounds, SceneDecisions, frame_image_path, mask_file
from nerfpipe.geometry.cameras import CameraSet, Frame
from nerfpipe.geometry.freespace import frame_least_depths
from nerfpipe.geometry.hull import Silhouettes
from nerfpipe.imaging.masks import object_mask
from nerfpipe.imaging.png import read_png
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.spaces.rays import pixel_centers
from nerfpipe.nerf.train.trainer import PixelSet
from nerfpipe.pipeline.errors import StageError

if TYPE_CHECKING:
    from nerfpipe.pipeline.stage import StageInputs


@dataclass
class Views:
    """The frames used for training and for evaluation, and why."""

    train: list[Frame]
    heldout: list[Frame]
    rule: str


def split_views(world: CameraSet, holdout_every: int = 8, train_images: int = 0, eval_stride: int = 1) -> Views:
    """Held-out views: the test split, else the val split, else every ``holdout_every``-th image. Then
    ``train_images`` (0: all) training views, evenly spaced, and every ``eval_stride``-th held-out view."""
    frames = world.frames
    splits = {f.split for f in frames}
    for name in ("test", "val"):
        if name in splits:
            train = [f for f in frames if f.split == "train"] or [f for f in frames if f.split != name]
            heldout = [f for f in frames if f.split == name]
            rule = f"the capture's {name} split"
            break
    else:
        heldout = frames[::holdout_every]
        train = [f for i, f in enumerate(frames) if i % holdout_every != 0]
        rule = f"every {holdout_every}th image"
    if train_images and train_images < len(train):
        keep = np.unique(np.linspace(0, len(train) - 1, train_images).round().astype(int))
        train = [train[i] for i in keep]
    heldout = heldout[::eval_stride]
    if not train:
        raise StageError(f"train: no training images left after holding out {rule}; lower train.holdout_every")
    return Views(train, heldout, rule)


class ImageLoader:
    """Training targets and cameras of frames, from the ingest / undistort images.

    ``images`` and ``undistorted_images`` are the image folders of ingest and undistort, ``pinhole`` the
    folder of undistort's camera set (its ``hints.image_roots`` says which folder holds each frame);
    ``world`` the normalized cameras, ``bounds`` their near/far and ``scene`` the background decisions.
    """

    def __init__(self, images: Path, undistorted_images: Path, pinhole: Path, world: CameraSet, bounds: Bounds,
                 scene: SceneDecisions) -> None:
        self.images, self.undistorted_images = Path(images), Path(undistorted_images)
        self.world = world
        self.bounds = bounds
        self.scene = scene
        self.roots = CameraSet.load(Path(pinhole)).hints.image_roots
        self.near_far = bounds.near_far()
        self.use_alpha = scene.background.value == "alpha"
        color = scene.background_color.value
        self.background = np.array(color if color is not None else (0.0, 0.0, 0.0), dtype=np.float32)
        self.backdrop = scene.backdrop()
        self._foreground: dict[str, np.ndarray] = {}  # GrabCut takes a second a photo: each frame's mask once

    @staticmethod
    def from_inputs(inputs: StageInputs) -> ImageLoader:
        """The loader of the train stage's inputs (``images``, ``undistorted_images``, ``pinhole``, ``world``,
        ``bounds``, ``scene``)."""
        return ImageLoader(inputs["images"], inputs["undistorted_images"], inputs["pinhole"],
                           inputs.load(WORLD), inputs.load(BOUNDS), inputs.load(SCENE))

    def stored(self, frame: Frame) -> np.ndarray:
        """(H, W, 3 or 4) float32 in [0, 1]: the frame's image as ingest or undistort wrote it (grey as RGB)."""
        path = frame_image_path(frame.name, self.roots.get(frame.name, "ingest"), self.images, self.undistorted_images)
        pixels = read_png(path)
        scale = 65535.0 if pixels.dtype == np.uint16 else 255.0
        pixels = pixels.astype(np.float32) / scale
        if pixels.ndim == 2:
            pixels = np.repeat(pixels[..., None], 3, axis=-1)
        camera = self.world.camera_of(frame)
        if pixels.shape[:2] != (camera.height, camera.width):
            raise StageError(f"train: {path} is {pixels.shape[1]}x{pixels.shape[0]} but its camera is "
                             f"{camera.width}x{camera.height}; rerun with --force undistort")
        return pixels

    def image(self, frame: Frame) -> np.ndarray:
        """(H, W, 3) float32 in [0, 1]; alpha composited onto the background colour when the scene uses it."""
        pixels = self.stored(frame)
        if pixels.shape[-1] == 4:
            rgb, alpha = pixels[..., :3], pixels[..., 3:]
            pixels = rgb * alpha + self.background * (1.0 - alpha) if self.use_alpha else rgb
        return pixels

    def alpha(self, frame: Frame) -> np.ndarray | None:
        """(H, W) bool: alpha >= 0.5, for an image with an alpha channel; else None."""
        pixels = self.stored(frame)
        return pixels[..., 3] >= 0.5 if pixels.shape[-1] == 4 else None

    def foreground(self, frame: Frame, pixels: np.ndarray | None = None) -> np.ndarray | None:
        """(H, W) bool: the frame's pixels that are not the constant backdrop (``nerfpipe.imaging.masks.object_mask``,
        with the scene's backdrop colour and tolerance); None when the scene has no constant backdrop.
        ``pixels``: the frame's ``image``, when already read."""
        if self.backdrop is None:
            return None
        if frame.name not in self._foreground:
            self._foreground[frame.name] = object_mask(self.image(frame) if pixels is None else pixels, *self.backdrop)
        return self._foreground[frame.name]

    def silhouettes(self, frames: list[Frame]) -> Silhouettes | None:
        """The object's silhouette in each of ``frames``, with their cameras: alpha >= 0.5 for photos with
        alpha, else the pixels that are not the constant backdrop (``foreground``); None when the scene has
        neither."""
        if self.use_alpha:
            masks = [self.alpha(frame) for frame in frames]
            if any(mask is None for mask in masks):
                return None
        elif self.backdrop is not None:
            masks = [self.foreground(frame) for frame in frames]
        else:
            return None
        return Silhouettes(masks, np.array([self.intrinsics(f) for f in frames]), np.array([f.c2w for f in frames]))

    def intrinsics(self, frame: Frame) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) of the frame's pinhole camera."""
        return self.world.camera_of(frame).intrinsics

    def pixel_set(self, frames: list[Frame]) -> PixelSet:
        """Every pixel of ``frames``, with its image's camera and near/far: what the trainer draws rays from;
        against a constant backdrop, with each pixel's ``alpha`` (``foreground``)."""
        rgb, image, uv, alpha = [], [], [], []
        for i, frame in enumerate(frames):
            pixels = self.image(frame)
            h, w = pixels.shape[:2]
            foreground = self.foreground(frame, pixels)
            if foreground is not None:
                alpha.append(torch.from_numpy(foreground.reshape(-1).astype(np.float32)))
            rgb.append(torch.from_numpy(np.ascontiguousarray(pixels.reshape(-1, 3))))
            uv.append(pixel_centers(w, h))
            image.append(torch.full((h * w,), i, dtype=torch.int64))
        least = frame_least_depths(self.world, frames) if frames else None
        return PixelSet(
            rgb=torch.cat(rgb), image=torch.cat(image), uv=torch.cat(uv),
            intrinsics=torch.tensor([self.intrinsics(f) for f in frames], dtype=torch.float32),
            c2w=torch.tensor(np.array([f.c2w for f in frames]), dtype=torch.float32),
            near=torch.tensor([self.near_far[f.name][0] for f in frames], dtype=torch.float32),
            far=torch.tensor([self.near_far[f.name][1] for f in frames], dtype=torch.float32),
            alpha=torch.cat(alpha) if alpha else None,
            least_depth=None if least is None else torch.from_numpy(least).float(),
        )


def write_masks(folder: Path, loader: ImageLoader, frames: list[Frame]) -> int:
    """Write into ``folder`` (made, empty when the scene has no masks) each frame's mask as training used it,
    one 8-bit channel, 255 on the subject and 0 where the pixel is ignored (alpha >= 0.5, or the pixels off the
    constant backdrop): nerfstudio's masks. Returns how many it wrote."""
    from nerfpipe.imaging.png import write_png

    folder.mkdir(parents=True, exist_ok=True)
    if not loader.use_alpha and loader.backdrop is None:
        return 0
    written = 0
    for frame in frames:
        mask = loader.alpha(frame) if loader.use_alpha else loader.foreground(frame)
        if mask is not None:
            write_png(folder / mask_file(frame.name), np.where(mask, 255, 0).astype(np.uint8))
            written += 1
    return written


def describe_masks(pixels: PixelSet) -> str | None:
    """A sentence on the backdrop masks of a pixel set (None without): how much of it is backdrop."""
    if pixels.alpha is None:
        return None
    backdrop = 100.0 * (1.0 - float(pixels.alpha.float().mean()))
    return f"backdrop masks: {backdrop:.1f}% of the training pixels are backdrop, trained as empty space"


def trained_cameras(model: RadianceModel, world: CameraSet, train: list[Frame]) -> tuple[CameraSet, dict]:
    """``world`` with the training frames' refined poses (``model.refinement``; held-out frames as given),
    each training frame's correction and exposure in ``hints.per_image``; and a summary for metrics.json:
    ``pose_refinement`` (how far the cameras moved) and ``appearance`` (the spread of the photos' exposures),
    each present when the model learned it."""
    per_image: dict[str, dict] = {f.name: {} for f in train}
    summary: dict[str, dict] = {}
    frames = list(world.frames)
    if model.refinement is not None:
        base = torch.tensor(np.array([f.c2w for f in train]), dtype=torch.float32, device=model.device)
        with torch.no_grad():
            refined = model.refinement(base).double().cpu().numpy()
        rotation, translation = (t.cpu().numpy() for t in model.refinement.moved())
        distance = float(np.median(np.linalg.norm(world.centers(), axis=1))) or 1.0
        by_name = {f.name: pose for f, pose in zip(train, refined)}
        frames = [Frame(f.name, f.camera_id, by_name[f.name], f.split) if f.name in by_name else f for f in frames]
        for f, r, t in zip(train, rotation, translation):
            per_image[f.name].update(rotation_deg=round(float(r), 4), translation=round(float(t), 5))
        largest = int(np.argmax(rotation))
        summary["pose_refinement"] = {
            "cameras": len(train), "median_rotation_deg": round(float(np.median(rotation)), 4),
            "max_rotation_deg": round(float(rotation.max()), 4), "largest": train[largest].name,
            "median_translation": round(float(np.median(translation)), 5),
            "max_translation": round(float(translation.max()), 5),
            "median_translation_share": round(float(np.median(translation)) / distance, 5),
        }
    if model.appearance is not None:
        stops = model.appearance.stops().cpu().numpy()
        for f, s in zip(train, stops):
            per_image[f.name]["exposure_stops"] = [round(float(v), 4) for v in s]
        mean = stops.mean(axis=1)
        summary["appearance"] = {"images": len(train), "spread_stops": round(float(mean.max() - mean.min()), 4),
                                 "darkest": train[int(np.argmin(mean))].name, "brightest": train[int(np.argmax(mean))].name}
    hints = dataclasses.replace(world.hints, per_image={k: v for k, v in per_image.items() if v})
    cameras = CameraSet(world.cameras, frames, None, world.source, world.unregistered, hints)
    return cameras, summary
