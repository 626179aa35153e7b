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
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from nerfpipe.artifacts import ViewSplit
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs
from nerfpipe.pipeline.store import write_json_atomic

param = field  # TrainParams has a parameter named ``field``, which shadows dataclasses.field in its body


@dataclass(frozen=True)
class TrainParams:
    """The defaults are the ``fast`` preset: the grid field with empty-space skipping."""

    steps: int = param(default=0, metadata={"help": "optimization steps (the paper: 100-300k, Section 5.3); 0: as many as fit in train.seconds"})
    seconds: float = param(default=120.0, metadata={"help": "with steps=0: seconds of training, the learning rate decaying over them (Instant-NGP trains by time too)"})
    field: Literal["grid", "mlp"] = param(default="grid", metadata={"help": "grid: dense feature grids + a small MLP (fast); mlp: the paper's MLP (Fig. 7)"})
    batch_rays: int = param(default=4096, metadata={"help": "rays per batch (the paper: 4096); with batch_samples, the starting and largest / 16 batch"})
    batch_samples: int = param(default=16384, metadata={"help": "while marching, adapt the rays per batch to about this many samples (Instant-NGP), and evaluate at most twice as many a step; 0: fixed batch_rays"})
    occupancy: Literal["auto", "true", "false"] = param(default="auto", metadata={"help": "empty-space skipping with an occupancy grid; auto: with the grid field"})
    occupancy_resolution: int = param(default=64, metadata={"help": "cells a side of the occupancy grid"})
    march_steps: int = param(default=128, metadata={"help": "marching steps along the field box's diagonal (about one per image pixel at 100 px lego)"})
    early_stop: float = param(default=1e-4, metadata={"help": "stop a marched ray once its transmittance is below this (0: never)"})
    occupancy_threshold: float = param(default=0.01, metadata={"help": "a cell is occupied when one step through it is this optically thick"})
    hull: Literal["auto", "off"] = param(default="auto", metadata={"help": "auto: for inward 360 photos with silhouettes (alpha or a backdrop), shrink the scene box to the box of their visual hull, where the grids then spend their cells"})
    hull_tolerance: float = param(default=0.05, metadata={"help": "carve a cell only when more than this share of the photos seeing it call it backdrop (mask errors)"})
    grid_levels: int = param(default=3, metadata={"help": "grid field: levels of the multiresolution grid"})
    grid_min_resolution: int = param(default=32, metadata={"help": "grid field: cells a side of the coarsest level"})
    grid_max_resolution: int = param(default=128, metadata={"help": "grid field: cells a side of the finest level"})
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
    lr: float = param(default=2e-2, metadata={"help": "initial Adam learning rate (the paper: 5e-4)"})
    lr_final: float = param(default=1e-3, metadata={"help": "learning rate at the last step, reached by exponential decay (the paper: 5e-5)"})
    adam_eps: float = param(default=1e-15, metadata={"help": "Adam epsilon (the paper: 1e-7)"})
    adam_beta2: float = param(default=0.99, metadata={"help": "Adam beta2 (the paper: 0.999; Instant-NGP: 0.99)"})
    density_noise: str = param(default="auto", metadata={"help": "std of noise on raw density: auto (1.0 for forward-facing real captures, else 0) or a number"})
    lindisp: Literal["auto", "true", "false"] = param(default="auto", metadata={"help": "sample linearly in disparity; auto: for unbounded scenes"})
    clip_to_box: bool = param(default=True, metadata={"help": "inward 360 with a backdrop: clip each ray to the scene box"})
    contract: Literal["auto", "true", "false"] = param(default="auto", metadata={"help": "contract the space beyond the scene box (mip-NeRF 360); auto: unbounded scenes and inward 360 ones without a backdrop"})
    appearance: Literal["auto", "on", "off"] = param(default="auto", metadata={"help": "learn each photo's exposure and white balance (3 gains on linear light); auto: when the scene finds exposure varying"})
    appearance_lr: float = param(default=1e-2, metadata={"help": "learning rate of the per-image exposure gains (decays as lr does)"})
    refine_poses: Literal["auto", "on", "off"] = param(default="auto", metadata={"help": "refine each training camera's pose with the field; auto: for photos, not for rendered captures with alpha"})
    pose_lr: float = param(default=3e-3, metadata={"help": "learning rate of the camera corrections (decays as lr does)"})
    pose_penalty: float = param(default=1e-3, metadata={"help": "weight of the camera corrections' mean squared size in the loss"})
    train_images: int = param(default=0, metadata={"help": "train on this many images, evenly spaced (Table 2 rows 5-6); 0: all"})
    holdout_every: int = param(default=8, metadata={"help": "without a val/test split, hold out every n-th image (the paper: 8)"})
    eval_stride: int = param(default=1, metadata={"help": "evaluate every n-th held-out view"})
    checkpoint_every: int = param(default=500, metadata={"help": "write a checkpoint every n steps (a killed run resumes from the last)"})
    keep_checkpoints: int = param(default=2, metadata={"help": "checkpoints kept (0: all)"})
    seed: int = param(default=0, metadata={"help": "seed of initialization, batches and samples"})
    device: Literal["auto", "cpu", "cuda"] = param(default="auto", metadata={"help": "auto: CUDA when present, else CPU"})
    tf32: bool = param(default=False, metadata={"help": "CUDA: TF32 matmuls"})
    autocast: Literal["none", "bf16", "fp16"] = param(default="none", metadata={"help": "mixed precision for the MLP (compositing stays float32)"})
    chunk: int = param(default=4096, metadata={"help": "rays per chunk when rendering whole views"})

    def __post_init__(self) -> None:
        for name in ("batch_rays", "n_coarse", "depth", "width", "view_width", "holdout_every", "eval_stride",
                     "checkpoint_every", "chunk", "occupancy_resolution", "march_steps", "grid_levels",
                     "grid_min_resolution", "grid_max_resolution", "grid_features", "grid_hidden"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.steps < 0 or (self.steps == 0 and not self.seconds > 0):
            raise ValueError(f"need steps >= 1, or steps = 0 and seconds > 0; got steps={self.steps}, seconds={self.seconds}")
        for name in ("n_fine", "pos_freqs", "dir_freqs", "train_images", "keep_checkpoints", "skip_after", "batch_samples",
                     "occupancy_threshold", "appearance_lr", "pose_lr", "pose_penalty", "hull_tolerance"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.skip_after > self.depth - 1:
            raise ValueError(f"skip_after must be below depth ({self.depth}), got {self.skip_after}")
        if not (0 < self.lr_final <= self.lr) or self.adam_eps <= 0 or not (0 < self.adam_beta2 < 1):
            raise ValueError("need 0 < lr_final <= lr, adam_eps > 0 and 0 < adam_beta2 < 1")
        if not self.hull_tolerance < 1:
            raise ValueError(f"hull_tolerance must be below 1 (1 carves nothing), got {self.hull_tolerance}")
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
    "draft": {"steps": 500, "grid_levels": 1, "grid_max_resolution": 64, "occupancy_resolution": 32,
              "batch_samples": 32768, "lr": 1e-2},
    # the default: 32^3, 64^3 and 128^3 grids, trained for train.seconds (120 s) as fast as the machine goes
    "fast": {},
    # the 4x128 MLP (Fig. 7's shape, smaller) marching the occupancy grid: 6000 steps, about half an hour there
    "balanced": {**MLP_CPU, "occupancy": "true", "steps": 6000, "batch_rays": 1024, "batch_samples": 32768,
                 "lr_final": 1e-4},
    # one to two days on a V100 (Section 5.3), out of reach on a CPU
    "paper": PAPER,
}


class TrainStage(Stage):
    """Train the NeRF (positional encoding, coarse + fine MLPs, hierarchical sampling) and evaluate it."""

    name = "train"
    version = 6  # 6: the scene box shrinks to the silhouettes' visual hull
    Params = TrainParams
    presets = PRESETS
    requires = ("images", "undistorted_images", "pinhole", "world", "bounds", "scene")
    provides = {"model": "model.pt", "model_json": "model.json", "metrics": "metrics.json", "eval": "eval",
                "views": "views.json", "cameras": "cameras"}
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
                 f"PSNR {s['psnr']:.2f} dB, SSIM {s['ssim']:.3f}"
                 + (f" against the masked photos ({s['psnr_photo']:.2f} dB against the photos as taken)"
                    if s.get("psnr_photo") is not None else "")]
        if s.get("protocol"):
            lines.append(f"held-out protocol: {s['protocol']}")
        if s.get("psnr_mean_appearance") is not None:
            lines.append(f"at the training photos' mean exposure, whole views: PSNR {s['psnr_mean_appearance']:.2f} dB")
        if s.get("appearance"):
            a = s["appearance"]
            lines.append(f"per-image exposure learned for {a['images']} photos: they span {a['spread_stops']:.2f} stops "
                         f"(darkest {a['darkest']}, brightest {a['brightest']})")
        if s.get("pose_refinement"):
            p = s["pose_refinement"]
            lines.append(f"{p['cameras']} training cameras refined: median {p['median_rotation_deg']:.2f} deg and "
                         f"{100 * p['median_translation_share']:.2f}% of the camera distance, at most "
                         f"{p['max_rotation_deg']:.2f} deg ({p['largest']}); exports and renders use the refined poses")
        if s.get("resumed_from"):
            lines.append(f"resumed from the checkpoint at step {s['resumed_from']}")
        guard = s.get("stall_guard") or {}
        if guard.get("restarted_at"):
            lines.append(f"batch PSNR stalled at the mean-colour level ({guard['mean_colour_psnr']:.1f} dB); restarted "
                         f"at step {guard['restarted_at']} at half the learning rate")
        if guard.get("stalled"):
            lines.append(f"STALLED: batch PSNR {guard['batch_psnr_ema']:.1f} dB stayed at the mean-colour level "
                         f"({guard['mean_colour_psnr']:.1f} dB); the renders are close to one flat colour")
        return lines

    def run(self, inputs: StageInputs, out: Path, params: TrainParams, ctx: StageContext) -> dict[str, Any]:
        # torch is imported here, not at the top: the CPU settings of training must come before its first use
        from nerfpipe.nerf.cpu import flush_denormals, keep_freed_memory
        from nerfpipe.nerf.device import resolve_device

        device = resolve_device(params.device, "train.device")
        with contextlib.ExitStack() as cpu_settings:
            if device.type == "cpu":
                keep_freed_memory()
                if not cpu_settings.enter_context(flush_denormals()):
                    ctx.log.warning("train: torch ran in this process before training, so its CPU threads do not flush "
                                    "denormal numbers; training on dark backgrounds may slow down (the CLI avoids this)")
            return self._run(inputs, out, params, ctx, device)

    def _run(self, inputs: StageInputs, out: Path, params: TrainParams, ctx: StageContext, device) -> dict[str, Any]:
        from nerfpipe.nerf.assembly import build_model, training_config
        from nerfpipe.nerf.evaluation import evaluate
        from nerfpipe.nerf.images import ImageLoader, describe_masks, split_views, trained_cameras
        from nerfpipe.nerf.trainer import Trainer

        loader = ImageLoader.from_inputs(inputs)
        layout = loader.scene.layout.value
        views = split_views(loader.world, params.holdout_every, params.train_images, params.eval_stride)
        model, decisions = build_model(params, loader.scene, loader.world, loader.bounds, device,
                                       [f.name for f in views.train], loader.silhouettes(views.train))
        for line in decisions:
            ctx.log.info("train: %s", line)
        ctx.log.info("train: %d training images, %d held out (%s)", len(views.train), len(views.heldout), views.rule)
        ViewSplit([f.name for f in views.train], [f.name for f in views.heldout], views.rule).save(out / "views.json")

        trainer = Trainer(model, loader.pixel_set(views.train), training_config(params, layout), out, device)
        masks = describe_masks(trainer.pixels)
        if masks is not None:
            decisions.append(masks)
            ctx.log.info("train: %s", masks)
        resumed = trainer.resume()
        if resumed is not None:
            ctx.log.info("train: resuming from the checkpoint at step %d (%.0f s of training)", resumed, trainer.elapsed)
        ctx.log.info("train: %s", f"{params.steps} steps" if params.steps > 0 else
                     f"{params.seconds:g} s of training (train.seconds; as many steps as fit, the learning rate "
                     "decaying over the time)")
        with _watching(ctx, loader, model):
            with ctx.progress(trainer.total - trainer.done_units(), "train") as advance:
                trainer.run(advance)
            model.save(out)
            cameras, per_image = trained_cameras(model, loader.world, views.train)
            (out / "cameras").mkdir(exist_ok=True)
            cameras.save(out / "cameras")
            with ctx.progress(len(views.heldout), "evaluate") as advance:
                evaluation = evaluate(model, loader, views.heldout, out / "eval", params.chunk, advance)
        summary = {
            "steps": trainer.step,
            "budget_seconds": params.seconds if params.steps == 0 else None,
            "train_seconds": round(trainer.elapsed, 2),
            "samples_per_s": round(trainer.total_samples / max(trainer.elapsed, 1e-9)),
            "samples_per_ray": round(trainer.total_samples / max(trainer.total_rays, 1), 2),
            "field": model.field_kind,
            "occupancy": None if model.occupancy is None else round(model.occupancy.occupancy(), 4),
            "device": str(device),
            "train_images": len(views.train),
            "heldout": len(views.heldout),
            "heldout_rule": views.rule,
            "psnr": evaluation["psnr"],
            "ssim": evaluation["ssim"],
            **{key: evaluation[key] for key in ("psnr_photo", "psnr_mean_appearance") if key in evaluation},
            **per_image,
            "resumed_from": resumed,
            "stall_guard": trainer.guard.report(),
            "decisions": decisions,
            "protocol": evaluation["protocol"],
        }
        write_json_atomic(out / "metrics.json", {**summary, "views": evaluation["views"], "eval_seconds": evaluation["seconds"]})
        if evaluation["psnr"] is not None:
            photo = f" (against the photos as taken, backdrop included: {evaluation['psnr_photo']:.2f} dB)" \
                if "psnr_photo" in evaluation else ""
            ctx.log.info("train: held-out PSNR %.2f dB, SSIM %.3f over %d views%s", evaluation["psnr"], evaluation["ssim"],
                         len(views.heldout), photo)
        return summary


# While training, the web viewer renders the view at rest every this many seconds, this many pixels across: a
# 160 x 120 frame of the demo's model renders in 0.2 s on a 2-core CPU, so watching costs training about 7%.
WATCH_REFRESH_SECONDS, WATCH_WIDTH = 3.0, 160


@contextlib.contextmanager
def _watching(ctx: StageContext, loader: Any, model: Any) -> Iterator[None]:
    """Serve the web viewer of the model being trained while the block runs, when the caller asked for one
    (``ctx.extra["watch_port"]``, from ``nerfpipe run --view``)."""
    port = ctx.extra.get("watch_port")
    if port is None:
        yield
        return
    from nerfpipe.export.web import WebScene, serve, web_frames

    scene = WebScene(web_frames(loader.world, loader.images), model=model, near=loader.bounds.near,
                     far=loader.bounds.far, sharp_width=WATCH_WIDTH, refresh_seconds=WATCH_REFRESH_SECONDS)
    viewer = serve(scene, port=port)
    ctx.log.info("train: watch the field learn at %s (the view at rest is rendered again every %.0f s)",
                 viewer.url, WATCH_REFRESH_SECONDS)
    try:
        yield
    finally:
        viewer.stop()
        ctx.log.info("train: the training viewer stopped; `nerfpipe view RUN_DIR --web` shows the finished run")
