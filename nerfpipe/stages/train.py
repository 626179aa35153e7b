"""train: fit the NeRF of Mildenhall et al. 2020 to the posed images, then evaluate it on held-out views.

Reads the normalized world, per-image near/far and the scene decisions, and models what they call for:
rays in NDC for forward-facing captures (Section 6.1's real scenes), rays clipped to the scene box for
inward 360° captures, depth sampling linear in disparity for unbounded ones; compositing onto the
background colour for photos with alpha or a constant backdrop; sRGB previews of linear RAW renders.

Writes ``model.pt`` / ``model.json`` (``nerfpipe.nerf.model.RadianceModel``), ``views.json`` (which
frames trained it and which were held out), ``checkpoints/``,
``metrics.jsonl`` (loss and PSNR against wall time), ``metrics.json`` (PSNR and SSIM on held-out views)
and ``eval/`` (each held-out view rendered, beside its ground truth).

Held-out views: the capture's test (else val) split when it has one; otherwise every 8th image, as the
paper holds out 1/8 of its real scenes (Section 6.1).
"""

from __future__ import annotations

import contextlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from nerfpipe.geometry.cameras import CameraSet, Frame
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs
from nerfpipe.pipeline.store import write_json_atomic
from nerfpipe.artifacts import frame_image_path
from nerfpipe.imaging.png import read_png

param = field  # TrainParams has a parameter named ``field``, which shadows dataclasses.field in its body

NDC_NEAR_FACTOR = 0.75  # the NDC near plane at 0.75 x the nearest bound, as LLFF's bd_factor places it


@dataclass(frozen=True)
class TrainParams:
    """The defaults are the ``fast`` preset: the grid field with empty-space skipping."""

    steps: int = param(default=2000, metadata={"help": "optimization steps (the paper: 100-300k, Section 5.3)"})
    field: Literal["grid", "mlp"] = param(default="grid", metadata={"help": "grid: dense feature grids + a small MLP (fast); mlp: the paper's MLP (Fig. 7)"})
    batch_rays: int = param(default=4096, metadata={"help": "rays per batch (the paper: 4096); with batch_samples, the starting and largest / 16 batch"})
    batch_samples: int = param(default=32768, metadata={"help": "while marching, adapt the rays per batch to about this many samples (Instant-NGP), and evaluate at most twice as many a step; 0: fixed batch_rays"})
    occupancy: Literal["auto", "true", "false"] = param(default="auto", metadata={"help": "empty-space skipping with an occupancy grid; auto: with the grid field"})
    occupancy_resolution: int = param(default=64, metadata={"help": "cells a side of the occupancy grid"})
    march_steps: int = param(default=128, metadata={"help": "marching steps along the field box's diagonal (about one per image pixel at 100 px lego)"})
    early_stop: float = param(default=1e-4, metadata={"help": "stop a marched ray once its transmittance is below this (0: never)"})
    occupancy_threshold: float = param(default=0.01, metadata={"help": "a cell is occupied when one step through it is this optically thick"})
    grid_levels: int = param(default=2, metadata={"help": "grid field: levels of the multiresolution grid"})
    grid_min_resolution: int = param(default=32, metadata={"help": "grid field: cells a side of the coarsest level"})
    grid_max_resolution: int = param(default=96, metadata={"help": "grid field: cells a side of the finest level"})
    grid_features: int = param(default=4, metadata={"help": "grid field: features per vertex and level"})
    grid_hidden: int = param(default=64, metadata={"help": "grid field: width of its MLPs"})
    n_coarse: int = param(default=32, metadata={"help": "N_c stratified samples per ray (the paper: 64); without the occupancy grid"})
    n_fine: int = param(default=64, metadata={"help": "N_f samples from the coarse weights (the paper: 128; 0: no hierarchical sampling)"})
    hierarchical: bool = param(default=True, metadata={"help": "hierarchical sampling; false is Table 2's 'No Hierarchical' (N_c samples only)"})
    fine_network: bool = param(default=False, metadata={"help": "a separate fine network (the paper); false reuses the coarse one"})
    depth: int = param(default=4, metadata={"help": "mlp: layers of the trunk (the paper: 8)"})
    width: int = param(default=128, metadata={"help": "mlp: channels per trunk layer (the paper: 256)"})
    view_width: int = param(default=64, metadata={"help": "mlp: channels of the view-direction layer (the paper: 128)"})
    skip_after: int = param(default=0, metadata={"help": "mlp: concatenate the encoded input to this layer's activation (the paper: 5; 0: none)"})
    positional_encoding: bool = param(default=True, metadata={"help": "encode x and d with Eq. 4; false is Table 2's 'No Pos. Encoding'"})
    pos_freqs: int = param(default=10, metadata={"help": "L for positions (Section 5.1: 10)"})
    dir_freqs: int = param(default=4, metadata={"help": "L for directions (Section 5.1: 4)"})
    include_input: bool = param(default=True, metadata={"help": "feed the raw coordinates beside their encoding (the authors' code does)"})
    view_dependence: bool = param(default=True, metadata={"help": "colour depends on the viewing direction; false is Table 2's 'No View Dependence'"})
    density_activation: Literal["relu", "softplus"] = param(default="softplus", metadata={"help": "mlp: relu (the paper) or softplus"})
    lr: float = param(default=1e-2, metadata={"help": "initial Adam learning rate (the paper: 5e-4)"})
    lr_final: float = param(default=1e-3, metadata={"help": "learning rate at the last step, reached by exponential decay (the paper: 5e-5)"})
    adam_eps: float = param(default=1e-15, metadata={"help": "Adam epsilon (the paper: 1e-7)"})
    adam_beta2: float = param(default=0.99, metadata={"help": "Adam beta2 (the paper: 0.999; Instant-NGP: 0.99)"})
    density_noise: str = param(default="auto", metadata={"help": "std of noise on raw density: auto (1.0 for forward-facing real captures, else 0) or a number"})
    lindisp: Literal["auto", "true", "false"] = param(default="auto", metadata={"help": "sample linearly in disparity; auto: for unbounded scenes"})
    clip_to_box: bool = param(default=True, metadata={"help": "inward 360: clip each ray to the scene box"})
    train_images: int = param(default=0, metadata={"help": "train on this many images, evenly spaced (Table 2 rows 5-6); 0: all"})
    holdout_every: int = param(default=8, metadata={"help": "without a val/test split, hold out every n-th image (the paper: 8)"})
    eval_stride: int = param(default=1, metadata={"help": "evaluate every n-th held-out view"})
    checkpoint_every: int = param(default=500, metadata={"help": "write a checkpoint every n steps (a killed run resumes from the last)"})
    keep_checkpoints: int = param(default=2, metadata={"help": "checkpoints kept (0: all)"})
    seed: int = param(default=0, metadata={"help": "seed of initialization, batches and samples"})
    device: Literal["auto", "cpu", "cuda"] = param(default="auto", metadata={"help": "auto: CUDA when present, else CPU"})
    tf32: bool = param(default=False, metadata={"help": "CUDA: TF32 matmuls"})
    autocast: Literal["none", "bf16", "fp16"] = param(default="none", metadata={"help": "mixed precision for the MLP (compositing stays float32)"})
    chunk: int = param(default=2048, metadata={"help": "rays per chunk when rendering whole views"})

    def __post_init__(self) -> None:
        for name in ("steps", "batch_rays", "n_coarse", "depth", "width", "view_width", "holdout_every", "eval_stride",
                     "checkpoint_every", "chunk", "occupancy_resolution", "march_steps", "grid_levels",
                     "grid_min_resolution", "grid_max_resolution", "grid_features", "grid_hidden"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("n_fine", "pos_freqs", "dir_freqs", "train_images", "keep_checkpoints", "skip_after", "batch_samples",
                     "occupancy_threshold"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.skip_after > self.depth - 1:
            raise ValueError(f"skip_after must be below depth ({self.depth}), got {self.skip_after}")
        if not (0 < self.lr_final <= self.lr) or self.adam_eps <= 0 or not (0 < self.adam_beta2 < 1):
            raise ValueError("need 0 < lr_final <= lr, adam_eps > 0 and 0 < adam_beta2 < 1")
        if not (0 <= self.early_stop < 1):
            raise ValueError(f"early_stop must be in [0, 1), got {self.early_stop}")
        if self.grid_min_resolution > self.grid_max_resolution:
            raise ValueError("grid_min_resolution must not exceed grid_max_resolution")
        if self.density_noise != "auto":
            try:
                noise = float(self.density_noise)
            except ValueError:
                raise ValueError(f"density_noise must be auto or a number >= 0, got {self.density_noise!r}") from None
            if not noise >= 0:
                raise ValueError(f"density_noise must be >= 0, got {noise}")


# Section 5.3 and Fig. 7: the model, sampling and optimizer of the paper, without empty-space skipping
PAPER = {
    "field": "mlp", "occupancy": "false", "steps": 200_000, "batch_rays": 4096, "batch_samples": 0, "n_coarse": 64,
    "n_fine": 128, "fine_network": True, "depth": 8, "width": 256, "view_width": 128, "skip_after": 5,
    "include_input": False, "density_activation": "relu", "lr": 5e-4, "lr_final": 5e-5, "adam_eps": 1e-7,
    "adam_beta2": 0.999, "checkpoint_every": 10_000,
}
# the optimizer of the CPU-scale NeRF (4x128 MLP, softplus density, 512 rays a step, lr 3e-3 over 1500
# steps); ``nerfpipe bench``'s Table 2 ablations and the ``balanced`` preset start from it
MLP_CPU = {
    "field": "mlp", "occupancy": "false", "steps": 1500, "batch_rays": 512, "batch_samples": 0, "lr": 3e-3,
    "lr_final": 5e-5, "adam_eps": 1e-7, "adam_beta2": 0.999,
}
PRESETS = {
    # lego at 100 px on 2 CPU cores (``nerfpipe bench``): 500 steps in under a minute, 22.9 dB
    "draft": {"steps": 500, "grid_levels": 1, "grid_max_resolution": 64, "occupancy_resolution": 32},
    # the default: 2000 steps, about 6 minutes there; 28.9 dB after 3 minutes, 29.3 dB after 5
    "fast": {},
    # the 4x128 MLP (Fig. 7's shape, smaller) marching the occupancy grid: 6000 steps, about half an hour there
    "balanced": {**MLP_CPU, "occupancy": "true", "steps": 6000, "batch_rays": 1024, "batch_samples": 32768,
                 "lr_final": 1e-4},
    # one to two days on a V100 (Section 5.3), out of reach on a CPU
    "paper": PAPER,
}


@dataclass
class Views:
    """The frames used for training and for evaluation, and why."""

    train: list[Frame]
    heldout: list[Frame]
    rule: str


def split_views(world: CameraSet, params: TrainParams) -> Views:
    """Held-out views: the test split, else the val split, else every ``holdout_every``-th image."""
    frames = world.frames
    splits = {f.split for f in frames}
    for name in ("test", "val"):
        if name in splits:
            train = [f for f in frames if f.split == "train"] or [f for f in frames if f.split != name]
            heldout = [f for f in frames if f.split == name]
            rule = f"the capture's {name} split"
            break
    else:
        heldout = frames[:: params.holdout_every]
        train = [f for i, f in enumerate(frames) if i % params.holdout_every != 0]
        rule = f"every {params.holdout_every}th image"
    if params.train_images and params.train_images < len(train):
        keep = np.unique(np.linspace(0, len(train) - 1, params.train_images).round().astype(int))
        train = [train[i] for i in keep]
    heldout = heldout[:: params.eval_stride]
    if not train:
        raise StageError(f"train: no training images left after holding out {rule}; lower train.holdout_every")
    return Views(train, heldout, rule)


class TrainStage(Stage):
    """Train the NeRF (positional encoding, coarse + fine MLPs, hierarchical sampling) and evaluate it."""

    name = "train"
    version = 3
    Params = TrainParams
    presets = PRESETS
    requires = ("images", "undistorted_images", "pinhole", "world", "bounds", "scene")
    provides = {"model": "model.pt", "model_json": "model.json", "metrics": "metrics.json", "eval": "eval",
                "views": "views.json"}
    libraries = ("torch", "kornia", "numpy")
    accelerated = True
    resumable = True

    def describe(self, result: Path, manifest: dict[str, Any]) -> list[str]:
        s = manifest.get("summary", {})
        if "steps" not in s:
            return []
        if s.get("psnr") is None:
            return [f"{s['steps']} steps in {s['train_seconds']:.0f} s on {s['device']}; no held-out views to evaluate"]
        lines = [f"{s['steps']} steps in {s['train_seconds']:.0f} s on {s['device']} "
                 f"({s['samples_per_s']:.0f} samples/s); {s['heldout']} held-out views ({s['heldout_rule']}): "
                 f"PSNR {s['psnr']:.2f} dB, SSIM {s['ssim']:.3f}"]
        if s.get("resumed_from"):
            lines.append(f"resumed from the checkpoint at step {s['resumed_from']}")
        return lines

    def run(self, inputs: StageInputs, out: Path, params: TrainParams, ctx: StageContext) -> dict[str, Any]:
        from nerfpipe.nerf.cpu import flush_denormals, keep_freed_memory

        device = resolve_device(params.device, "train.device")
        with contextlib.ExitStack() as cpu_settings:
            if device.type == "cpu":
                keep_freed_memory()
                if not cpu_settings.enter_context(flush_denormals()):
                    ctx.log.warning("train: torch ran in this process before training, so its CPU threads do not flush "
                                    "denormal numbers; training on dark backgrounds may slow down (the CLI avoids this)")
            return self._run(inputs, out, params, ctx, device)

    def _run(self, inputs: StageInputs, out: Path, params: TrainParams, ctx: StageContext, device) -> dict[str, Any]:
        import torch

        from nerfpipe.nerf.trainer import TrainConfig, Trainer

        if device.type == "cuda" and params.tf32:
            torch.backends.cuda.matmul.allow_tf32 = True
            torch.backends.cudnn.allow_tf32 = True
        loader = ImageLoader.from_inputs(inputs)
        scene, world, bounds = loader.scene, loader.world, loader.bounds
        views = split_views(world, params)
        model, decisions = build_model(params, scene, world, bounds, device)
        for line in decisions:
            ctx.log.info("train: %s", line)
        ctx.log.info("train: %d training images, %d held out (%s)", len(views.train), len(views.heldout), views.rule)
        write_json_atomic(out / "views.json", {"train": [f.name for f in views.train],
                                               "heldout": [f.name for f in views.heldout], "rule": views.rule})

        pixels = loader.pixel_set(views.train)
        config = TrainConfig(
            steps=params.steps, batch_rays=params.batch_rays, lr=params.lr, lr_final=params.lr_final,
            adam_eps=params.adam_eps, adam_beta2=params.adam_beta2, batch_samples=params.batch_samples,
            density_noise=density_noise(params, scene), seed=params.seed,
            checkpoint_every=params.checkpoint_every, keep_checkpoints=params.keep_checkpoints, autocast=params.autocast,
        )
        trainer = Trainer(model, pixels, config, out, device)
        resumed = trainer.resume()
        if resumed is not None:
            ctx.log.info("train: resuming from the checkpoint at step %d of %d", resumed, params.steps)
        with ctx.progress(params.steps - trainer.step, "train") as advance:
            trainer.run(advance)
        model.save(out)
        evaluation = evaluate(model, loader, views.heldout, out / "eval", params.chunk, ctx)
        samples_per_s = trainer.total_samples / max(trainer.elapsed, 1e-9)
        summary = {
            "steps": params.steps,
            "train_seconds": round(trainer.elapsed, 2),
            "samples_per_s": round(samples_per_s),
            "samples_per_ray": round(trainer.total_samples / max(trainer.total_rays, 1), 2),
            "field": field_kind(params, loader.scene),
            "occupancy": None if model.occupancy is None else round(model.occupancy.occupancy(), 4),
            "device": str(device),
            "train_images": len(views.train),
            "heldout": len(views.heldout),
            "heldout_rule": views.rule,
            "psnr": evaluation["psnr"],
            "ssim": evaluation["ssim"],
            "resumed_from": resumed,
            "decisions": decisions,
        }
        write_json_atomic(out / "metrics.json", {**summary, "views": evaluation["views"], "eval_seconds": evaluation["seconds"]})
        ctx.log.info("train: held-out PSNR %.2f dB, SSIM %.3f over %d views", evaluation["psnr"], evaluation["ssim"],
                     len(views.heldout))
        return summary


def density_noise(params: TrainParams, scene: dict[str, Any]) -> float:
    """The authors regularize real forward-facing scenes with noise of std 1 on the raw density; not synthetic
    ones. The MLP's raw density only: the grid field has no such regularizer."""
    if params.density_noise != "auto":
        return float(params.density_noise)
    return 1.0 if scene["layout"]["value"] == "forward" and field_kind(params, scene) == "mlp" else 0.0


def field_kind(params: TrainParams, scene: dict[str, Any]) -> str:
    """The grid field needs a bounded box to hold its grids: unbounded 360 scenes train the MLP."""
    return "mlp" if scene["layout"]["value"] == "unbounded360" else params.field


def build_model(params: TrainParams, scene: dict[str, Any], world: CameraSet, bounds: dict[str, Any], device):
    """The fields, sampling, ray space and background this scene calls for, and a sentence per choice."""
    from nerfpipe.nerf.field import FieldConfig, NerfField
    from nerfpipe.nerf.grid_field import GridField, GridFieldConfig
    from nerfpipe.nerf.model import RadianceModel, RaySpace
    from nerfpipe.nerf.occupancy import MarchingConfig, OccupancyGrid
    from nerfpipe.nerf.renderer import SamplingConfig

    import torch

    torch.manual_seed(params.seed)
    layout = scene["layout"]["value"]
    decisions = []
    config = FieldConfig(
        depth=params.depth, width=params.width, skips=(params.skip_after - 1,) if params.skip_after else (),
        view_width=params.view_width, pos_freqs=params.pos_freqs if params.positional_encoding else 0,
        dir_freqs=params.dir_freqs if params.positional_encoding else 0, include_input=params.include_input,
        view_dependent=params.view_dependence, density_activation=params.density_activation,
    )
    lindisp = layout == "unbounded360" if params.lindisp == "auto" else params.lindisp == "true"
    sampling = SamplingConfig(params.n_coarse, params.n_fine if params.hierarchical else 0, lindisp)

    if layout == "forward":
        c2ws = np.array([f.c2w for f in world.frames])
        reference = world.camera_of(world.frames[0])
        near_plane = NDC_NEAR_FACTOR * min(f["near"] for f in bounds["frames"])
        ray_space = RaySpace(ndc=True, ndc_c2w=tuple(map(tuple, mean_camera(c2ws).tolist())), ndc_focal=reference.fx,
                             ndc_size=(reference.width, reference.height), ndc_near=near_plane)
        decisions.append(f"forward-facing: rays in NDC of the mean camera, near plane {near_plane:.3g}, "
                         "samples linear in NDC depth (near to infinity)")
    elif layout == "inward360" and params.clip_to_box:
        box = (tuple(bounds["scene_box"][0]), tuple(bounds["scene_box"][1]))
        ray_space = RaySpace(box=box)
        decisions.append("inward 360: world rays, each clipped to the scene box and its image's near/far")
    else:
        ray_space = RaySpace()
        what = "unbounded 360: world rays over each image's near/far" if layout == "unbounded360" else "world rays over each image's near/far"
        decisions.append(what + (", samples linear in disparity" if lindisp else ""))

    kind = field_kind(params, scene)
    field_box = ray_space.field_box(max(f["far"] for f in bounds["frames"]) if bounds["frames"] else None)
    if field_box is None and layout != "unbounded360":
        field_box = (tuple(bounds["scene_box"][0]), tuple(bounds["scene_box"][1]))
    if kind == "grid":
        grid_config = GridFieldConfig(
            levels=params.grid_levels, min_resolution=params.grid_min_resolution,
            max_resolution=params.grid_max_resolution, features=params.grid_features, hidden=params.grid_hidden,
            dir_freqs=params.dir_freqs if params.positional_encoding else 0, view_dependent=params.view_dependence,
        )
        coarse, fine = GridField(*field_box, grid_config).to(device), None
        decisions.append(f"grid field: {grid_config.levels} levels of {grid_config.resolutions()} cells a side, "
                         f"{grid_config.features} features each, and a {grid_config.hidden}-wide MLP")
    else:
        coarse = NerfField(config).to(device)
        fine = NerfField(config).to(device) if params.fine_network and params.hierarchical and params.n_fine > 0 else None
        if params.field == "grid":
            decisions.append("unbounded 360: the grid field needs a bounded box, so the MLP (Fig. 7) is trained")
    use_grid = params.occupancy == "true" or (params.occupancy == "auto" and kind == "grid")
    occupancy = marching = None
    if use_grid and field_box is not None:
        occupancy = OccupancyGrid(*field_box, params.occupancy_resolution).to(device)
        marching = MarchingConfig(steps=params.march_steps, threshold=params.occupancy_threshold,
                                  early_stop=params.early_stop)
        decisions.append(f"empty-space skipping: a {params.occupancy_resolution}^3 occupancy grid over the field box, "
                         f"{params.march_steps} marching steps along its diagonal, rays stop at transmittance "
                         f"{params.early_stop:g} (instead of N_c + N_f samples per ray)")
    elif use_grid:
        decisions.append("no occupancy grid: an unbounded scene has no box to grid; Section 5.2's sampling instead")
    background_kind = scene["background"]["value"]
    color = scene["background_color"]["value"]
    if background_kind in ("alpha", "color") and color is not None:
        background = tuple(float(c) for c in color)
        decisions.append(f"background {background_kind}: renders composited onto ({', '.join(f'{c:.2f}' for c in background)})")
    else:
        background = None
        decisions.append("no background model: the background is part of the scene (composited onto black)")
    if scene["photometric"]["value"] == "linear_raw":
        decisions.append("linear RAW: trained on linear values; previews are sRGB-encoded")
    noise = density_noise(params, scene)
    if noise:
        decisions.append(f"noise of std {noise:g} on raw density while training")
    info = {"layout": layout, "photometric": scene["photometric"]["value"], "to_sfm": bounds["to_sfm"]}
    return RadianceModel(coarse, fine, sampling, ray_space, background, info, occupancy, marching), decisions


class ImageLoader:
    """Training targets and cameras of frames, from the ingest / undistort images."""

    def __init__(self, inputs: StageInputs, world: CameraSet, bounds: dict[str, Any], scene: dict[str, Any]) -> None:
        self.inputs = inputs
        self.world = world
        self.bounds = bounds
        self.scene = scene
        self.roots = CameraSet.load(inputs["pinhole"]).extra.get("image_roots", {})
        self.near_far = {f["name"]: (f["near"], f["far"]) for f in bounds["frames"]}
        self.use_alpha = scene["background"]["value"] == "alpha"
        color = scene["background_color"]["value"]
        self.background = np.array(color if color is not None else (0.0, 0.0, 0.0), dtype=np.float32)

    @staticmethod
    def from_inputs(inputs: StageInputs) -> "ImageLoader":
        """The loader of the train stage's inputs: the normalized world, its bounds and the scene decisions."""
        return ImageLoader(
            inputs, CameraSet.load(inputs["world"]), json.loads(inputs["bounds"].read_text(encoding="utf-8")),
            json.loads(inputs["scene"].read_text(encoding="utf-8")),
        )

    def image(self, frame: Frame) -> np.ndarray:
        """(H, W, 3) float32 in [0, 1]; alpha composited onto the background colour when the scene uses it."""
        path = frame_image_path(frame.name, self.roots.get(frame.name, "ingest"), self.inputs["images"],
                                self.inputs["undistorted_images"])
        pixels = read_png(path)
        scale = 65535.0 if pixels.dtype == np.uint16 else 255.0
        pixels = pixels.astype(np.float32) / scale
        if pixels.ndim == 2:
            pixels = np.repeat(pixels[..., None], 3, axis=-1)
        if pixels.shape[-1] == 4:
            rgb, alpha = pixels[..., :3], pixels[..., 3:]
            pixels = rgb * alpha + self.background * (1.0 - alpha) if self.use_alpha else rgb
        camera = self.world.camera_of(frame)
        if pixels.shape[:2] != (camera.height, camera.width):
            raise StageError(f"train: {path} is {pixels.shape[1]}x{pixels.shape[0]} but its camera is "
                             f"{camera.width}x{camera.height}; rerun with --force undistort")
        return pixels

    def intrinsics(self, frame: Frame) -> tuple[float, float, float, float]:
        c = self.world.camera_of(frame)
        return (c.fx, c.fy, c.cx, c.cy)

    def pixel_set(self, frames: list[Frame]):
        import torch

        from nerfpipe.nerf.rays import pixel_centers
        from nerfpipe.nerf.trainer import PixelSet

        rgb, image, uv = [], [], []
        for i, frame in enumerate(frames):
            pixels = self.image(frame)
            h, w = pixels.shape[:2]
            rgb.append(torch.from_numpy(np.ascontiguousarray(pixels.reshape(-1, 3))))
            uv.append(pixel_centers(w, h))
            image.append(torch.full((h * w,), i, dtype=torch.int64))
        return PixelSet(
            rgb=torch.cat(rgb), image=torch.cat(image), uv=torch.cat(uv),
            intrinsics=torch.tensor([self.intrinsics(f) for f in frames], dtype=torch.float32),
            c2w=torch.tensor(np.array([f.c2w for f in frames]), dtype=torch.float32),
            near=torch.tensor([self.near_far[f.name][0] for f in frames], dtype=torch.float32),
            far=torch.tensor([self.near_far[f.name][1] for f in frames], dtype=torch.float32),
        )


def evaluate(model, loader: ImageLoader, frames: list[Frame], folder: Path | None, chunk: int,
             ctx: StageContext | None = None) -> dict[str, Any]:
    """Render each held-out view; PSNR and SSIM (kornia.metrics, 11x11 Gaussian window) against its image,
    averaged over views as the paper does; with a ``folder``, ``<view>.render.png`` beside ``<view>.gt.png``."""
    import kornia
    import torch

    from nerfpipe.imaging.png import write_png

    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    linear = model.info.get("photometric") == "linear_raw"
    views = []
    bar = ctx.progress(len(frames), "evaluate") if ctx is not None else contextlib.nullcontext(lambda n=1, info=None: None)
    with bar as advance:
        for frame in frames:
            gt = loader.image(frame)
            camera = loader.world.camera_of(frame)
            near, far = loader.near_far[frame.name]
            out = model.render_image(loader.intrinsics(frame), frame.c2w, camera.width, camera.height, near, far, chunk)
            render = out["rgb"].clamp(0.0, 1.0)
            target = torch.from_numpy(gt)
            psnr = float(kornia.metrics.psnr(render, target, 1.0))
            ssim = float(kornia.metrics.ssim(render.permute(2, 0, 1)[None], target.permute(2, 0, 1)[None], 11).mean())
            if folder is not None:
                stem = view_file_stem(frame.name)
                for suffix, pixels in (("render", render.numpy()), ("gt", gt)):
                    shown = srgb_encode(pixels) if linear else pixels
                    write_png(folder / f"{stem}.{suffix}.png", np.round(np.clip(shown, 0, 1) * 255).astype(np.uint8))
            views.append({"name": frame.name, "psnr": round(psnr, 4), "ssim": round(ssim, 5)})
            advance(1, info=f"{frame.name}: {psnr:.2f} dB")
    if not views:
        return {"psnr": None, "ssim": None, "views": [], "seconds": 0.0}
    return {
        "psnr": round(float(np.mean([v["psnr"] for v in views])), 4),
        "ssim": round(float(np.mean([v["ssim"] for v in views])), 5),
        "views": views,
        "seconds": round(time.perf_counter() - started, 2),
    }
