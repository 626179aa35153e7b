"""train: fit a radiance field (Mildenhall et al. 2020's volume rendering; by default a grid field, the paper's
MLPs with ``--preset paper``) to the posed images, then evaluate it on held-out views.

Reads the normalized world, per-image near/far and the scene decisions, and models what they call for:
rays in NDC for forward-facing captures (Section 6.1's real scenes), rays clipped to the scene box for
inward 360° captures, depth sampling linear in disparity for unbounded ones; compositing onto the
background colour for photos with alpha or a constant backdrop; sRGB previews of linear RAW renders.

Writes ``model.pt`` / ``model.json`` (``nerfpipe.nerf.model.RadianceModel``), ``views.json`` (which frames
trained it and which were held out), ``checkpoints/``, ``metrics.jsonl`` (loss and PSNR against wall time),
``metrics.json`` (PSNR and SSIM on held-out views) and ``eval/`` (each held-out view rendered, beside its
ground truth and, where a backdrop mask made that ground truth, the photo as taken), ``masks/`` (the masks it
trained with, where the scene has any).

Held-out views: the capture's test (else val) split, else every 8th image (the paper's 1/8, Section 6.1).
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar, Literal, Mapping

from nerfpipe.artifacts import ViewSplit
from nerfpipe.nerf.config import (OptimParams, PerImageParams, SpaceParams, auto_sampler, field_configs,
                                  sampler_configs, step_bytes)
from nerfpipe.nerf.fields.configs import FieldConfig, GridConfig
from nerfpipe.nerf.presets import PRESETS, gpu_preset
from nerfpipe.nerf.samplers.configs import MarchingConfig, SamplerConfig
from nerfpipe.pipeline.params import param
from nerfpipe.pipeline.resources import check_memory
from nerfpipe.pipeline.summary import Summary
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs
from nerfpipe.pipeline.store import write_json_atomic

_SWITCH = {"true": "on", "false": "off", "yes": "on", "no": "off", "1": "on", "0": "off"}
_SAMPLER = {"true": "marching", "on": "marching", "false": "hierarchical", "off": "hierarchical", "auto": "auto",
            "yes": "marching", "no": "hierarchical"}


@dataclass(frozen=True)
class TrainParams:
    """The defaults are the ``fast`` preset: the grid field with empty-space skipping. The model's parts are
    configured in groups: ``field`` and ``sampler`` (each kind's own config, ``nerfpipe.nerf.fields.configs`` and
    ``nerfpipe.nerf.samplers.configs``), ``space``, ``optim`` and ``per_image`` (``nerfpipe.nerf.config``)."""

    steps: int = param(0, "optimization steps (the paper: 100-300k, Section 5.3); 0: as many as fit in train.seconds", bounds=(0, 10_000_000))
    seconds: float = param(120.0, "with steps=0: seconds of training, the learning rate decaying over them "
                                  "(Instant-NGP trains by time too)", bounds=(1.0, 604800.0))
    field: FieldConfig = param(GridConfig(), "the radiance field: grid (dense feature grids and a small MLP, fast), "
                                             "hash (its fine levels hashed, Instant-NGP), planes (three factorized "
                                             "planes a level, K-Planes), mlp (the paper's MLP, Fig. 7), or any field "
                                             "in nerfpipe.nerf.registry.FIELDS", union=field_configs)
    sampler: SamplerConfig = param(MarchingConfig(), "where along each ray the field is evaluated: marching "
                                                     "(empty-space skipping through an occupancy grid, Instant-NGP), "
                                                     "hierarchical (Section 5.2's N_c + N_f samples), auto (the one the "
                                                     "field asks for: marching a grid field, hierarchical along the "
                                                     "MLP), or any sampler in nerfpipe.nerf.registry.SAMPLERS",
                                   union=sampler_configs, auto=auto_sampler)
    space: SpaceParams = param(SpaceParams(), "the ray space and the scene box")
    optim: OptimParams = param(OptimParams(), "batches, optimizer and schedule")
    per_image: PerImageParams = param(PerImageParams(), "what is learned for each training photo")
    train_images: int = param(0, "train on this many images, evenly spaced (Table 2 rows 5-6); 0: all", bounds=(0, 100_000))
    holdout_every: int = param(8, "without a val/test split, hold out every n-th image (the paper: 8)", bounds=(1, 10_000))
    eval_stride: int = param(1, "evaluate every n-th held-out view", bounds=(1, 10_000))
    eval_scale: str = param("auto", "render and score the held-out views at this share of their size (1: full "
                                    "resolution); auto: half, the same for every run of a capture")
    eval_budget: float = param(0.1, "under a job budget, the time kept for the held-out evaluation, as a share of the "
                                    "training time (an evaluation that takes longer makes the job longer)", bounds=(0.001, 10.0))
    checkpoint_every: int = param(500, "write a checkpoint every n steps (a killed run resumes from the last)", bounds=(1, 10_000_000))
    keep_checkpoints: int = param(2, "checkpoints kept (0: all)", bounds=(0, 1000), keyed=False)
    seed: int = param(0, "seed of initialization, batches and samples", bounds=(0, 2_147_483_647))
    device: Literal["auto", "cpu", "cuda"] = param("auto", "auto: CUDA when present, else CPU", keyed=False)
    tf32: bool = param(False, "CUDA: TF32 matmuls")
    autocast: Literal["none", "bf16", "fp16"] = param("none", "mixed precision for the MLP (compositing stays float32)")
    compile: Literal["auto", "off", "kernels", "graphs"] = param("auto", "torch.compile the training step at fixed shapes "
        "(samples padded to optim.batch_samples): kernels (fused), graphs (and replayed as CUDA graphs); auto: kernels on CUDA, off on the CPU")
    chunk: int = param(4096, "rays per chunk when rendering whole views", bounds=(1, 1_048_576), keyed=False)

    # the flat names before the parameters were grouped: still accepted, with a deprecation message
    ALIASES: ClassVar[dict[str, Any]] = {
        "field": "field.kind", **{f"grid_{n}": f"field.{n}" for n in ("levels", "min_resolution", "max_resolution",
                                                                       "features", "hidden")},
        **{n: f"field.{n}" for n in ("depth", "width", "view_width", "skip_after", "positional_encoding", "pos_freqs",
                                     "dir_freqs", "include_input", "view_dependence", "density_activation",
                                     "fine_network")},
        "occupancy": ("sampler.kind", _SAMPLER), "march_steps": "sampler.steps", "lindisp": ("sampler.lindisp", _SWITCH),
        **{n: f"sampler.{n}" for n in ("occupancy_resolution", "early_stop", "occupancy_threshold", "n_coarse",
                                       "n_fine", "hierarchical")},
        "contract": ("space.contract", _SWITCH), "clip_to_box": "space.clip_to_box", "hull": "space.hull",
        "hull_tolerance": "space.hull_tolerance",
        **{n: f"optim.{n}" for n in ("batch_rays", "batch_samples", "lr", "lr_final", "adam_eps", "adam_beta2",
                                     "density_noise")},
        **{n: f"per_image.{n}" for n in ("appearance", "appearance_lr", "refine_poses", "pose_lr", "pose_penalty")},
    }

    def __post_init__(self) -> None:
        check_memory("optim.batch_rays, optim.batch_samples, sampler.steps (or n_coarse and n_fine)",
                     "a training step's samples",
                     step_bytes(self.field, self.sampler, self.optim), share=1.0)
        for name in ("holdout_every", "eval_stride", "checkpoint_every", "chunk"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("train_images", "keep_checkpoints"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.eval_scale != "auto":
            try:
                scale = float(self.eval_scale)
            except ValueError:
                raise ValueError(f"eval_scale must be auto or a number in (0, 1], got {self.eval_scale!r}") from None
            if not 0 < scale <= 1:
                raise ValueError(f"eval_scale must be in (0, 1], got {scale}")
        if not self.eval_budget > 0:
            raise ValueError(f"eval_budget must be > 0, got {self.eval_budget}")
        if self.steps < 0 or (self.steps == 0 and not self.seconds > 0):
            raise ValueError(f"need steps >= 1, or steps = 0 and seconds > 0; got steps={self.steps}, seconds={self.seconds}")


@dataclass(frozen=True)
class Throughput(Summary):
    """What training drew: evaluations and rays a second, samples a ray, draws of each training pixel."""

    samples_per_s: float = 0.0
    samples_per_ray: float = 0.0
    rays: int | None = None
    rays_per_s: float | None = None
    rays_per_pixel: float | None = None


@dataclass(frozen=True)
class HeldoutScores(Summary):
    """The held-out views and how they scored, at which size, against what (``protocol``)."""

    heldout: int = 0
    heldout_rule: str = ""
    eval_scale: float | None = None
    eval_size: list[int] | None = None  # width, height
    psnr: float | None = None
    ssim: float | None = None
    psnr_photo: float | None = None  # against the photos as taken, where the scores are against masked ones
    psnr_mean_appearance: float | None = None  # whole views at the training photos' mean exposure
    protocol: str | None = None


@dataclass(frozen=True)
class TrainSummary(Summary):
    """The train stage's figures (also the head of ``metrics.json``, written flat)."""

    steps: int = 0
    budget_seconds: float | None = None
    train_seconds: float = 0.0
    given_seconds: float = 0.0  # of a job budget's training, given to the outputs at their floors (``floors.floor_hook``)
    throughput: Throughput = Throughput()
    field: str = ""
    occupancy: float | None = None
    device: str = ""
    train_images: int = 0
    scores: HeldoutScores = HeldoutScores()
    appearance: dict[str, Any] | None = None  # {"images", "spread_stops", "darkest", "brightest"}
    pose_refinement: dict[str, Any] | None = None  # {"cameras", "median_rotation_deg", ...}
    resumed_from: int | None = None
    stall_guard: dict[str, Any] = dataclasses.field(default_factory=dict)
    decisions: list[str] = dataclasses.field(default_factory=list)

    def describe(self) -> list[str]:
        if not self.steps:
            return []
        s, x = self.scores, self.throughput
        if s.psnr is None:
            return [f"{self.steps} steps in {self.train_seconds:.0f} s on {self.device}; no held-out views to evaluate"]
        size = f" at {s.eval_size[0]}x{s.eval_size[1]}" if s.eval_size else ""
        seen = (f", {x.rays:,} rays ({x.rays_per_s:,.0f} a second, {x.rays_per_pixel:.3g} a training pixel)"
                if x.rays is not None else "")
        lines = [f"{self.steps} steps in {self.train_seconds:.0f} s on {self.device} "
                 f"({x.samples_per_s:.0f} samples/s{seen}); {s.heldout} held-out views ({s.heldout_rule}){size}: "
                 f"PSNR {s.psnr:.2f} dB, SSIM {s.ssim:.3f}"
                 + (f" against the masked photos ({s.psnr_photo:.2f} dB against the photos as taken)"
                    if s.psnr_photo is not None else "")]
        if s.protocol:
            lines.append(f"held-out protocol: {s.protocol}")
        if s.psnr_mean_appearance is not None:
            lines.append(f"at the training photos' mean exposure, whole views: PSNR {s.psnr_mean_appearance:.2f} dB")
        if self.appearance:
            a = self.appearance
            lines.append(f"per-image exposure learned for {a['images']} photos: they span {a['spread_stops']:.2f} stops "
                         f"(darkest {a['darkest']}, brightest {a['brightest']})")
        if self.pose_refinement:
            p = self.pose_refinement
            lines.append(f"{p['cameras']} training cameras refined: median {p['median_rotation_deg']:.2f} deg and "
                         f"{100 * p['median_translation_share']:.2f}% of the camera distance, at most "
                         f"{p['max_rotation_deg']:.2f} deg ({p['largest']}); exports and renders use the refined poses")
        if self.given_seconds >= 1:
            lines.append(f"training stopped {self.given_seconds:.0f} s early: the outputs at their floors needed more of "
                         "the job's budget than it kept for them")
        if self.resumed_from:
            lines.append(f"resumed from the checkpoint at step {self.resumed_from}")
        guard = self.stall_guard
        if guard.get("restarted_at"):
            lines.append(f"batch PSNR stalled at the mean-colour level ({guard['mean_colour_psnr']:.1f} dB); restarted "
                         f"at step {guard['restarted_at']} at half the learning rate")
        if guard.get("stalled"):
            lines.append(f"STALLED: batch PSNR {guard['batch_psnr_ema']:.1f} dB stayed at the mean-colour level "
                         f"({guard['mean_colour_psnr']:.1f} dB); the renders are close to one flat colour")
        return lines


class TrainStage(Stage):
    """Train the radiance field the scene calls for (by default a grid field with occupancy marching; the paper's MLPs with `--preset paper`) and score it on held-out views."""

    name = "train"
    version = 13  # 13: masks/ (what it trained with) and eval/ photos as taken; 12: model.json holds the parts' configs; 11: directions into the colour MLP as they are (L = 0; 4 before); 10: poses refined beyond 2 px
    Params = TrainParams
    Summary = TrainSummary
    presets = PRESETS
    requires = ("images", "undistorted_images", "pinhole", "world", "bounds", "scene")
    provides = {"model": "model.pt", "model_json": "model.json", "metrics": "metrics.json", "eval": "eval",
                "views": "views.json", "cameras": "cameras", "masks": "masks"}
    libraries = ("torch", "kornia", "numpy")
    accelerated = True
    resumable = True
    elastic = ("seconds", "steps")  # under a job budget, train.seconds is what the other stages leave

    def least_seconds(self, params: TrainParams) -> tuple[float, str] | None:
        if params.steps:
            return params.steps * FASTEST_STEP_SECONDS, f"steps={params.steps}"
        return params.seconds, f"seconds={params.seconds:g}"

    def machine_preset(self, overrides: Mapping[str, Any]) -> tuple[str, str] | None:
        """``gpu`` where training runs on a CUDA device, unless the user chose the field."""
        if "field.kind" in overrides:
            return None
        return gpu_preset(overrides, "2^18 samples a step, the hash field to 2048 cells a side, the step compiled, "
                                     "held-out views at full size (--preset fast: the CPU's sizes)")

    def run(self, inputs: StageInputs, out: Path, params: TrainParams, ctx: StageContext) -> TrainSummary:
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

    def _run(self, inputs: StageInputs, out: Path, params: TrainParams, ctx: StageContext, device) -> TrainSummary:
        started = time.monotonic()
        from nerfpipe.export.web import watching
        from nerfpipe.nerf.policy import build_model, density_noise
        from nerfpipe.nerf.train.evaluation import evaluate, evaluated_scale, evaluation_scale, scaled_size
        from nerfpipe.nerf.train.floors import floor_hook
        from nerfpipe.nerf.train.images import ImageLoader, describe_masks, split_views, trained_cameras, write_masks
        from nerfpipe.nerf.samplers.marching import describe_carving
        from nerfpipe.nerf.train.sampling import DRAWS
        from nerfpipe.nerf.train.trainer import Trainer

        loader = ImageLoader.from_inputs(inputs)
        layout = loader.scene.layout.value
        views = split_views(loader.world, params.holdout_every, params.train_images, params.eval_stride)
        model, decisions = build_model(params, loader.scene, loader.world, loader.bounds, device,
                                       [f.name for f in views.train], loader.silhouettes(views.train))
        for line in decisions:
            ctx.log.info("train: %s", line)
        ctx.log.info("train: %d training images, %d held out (%s)", len(views.train), len(views.heldout), views.rule)
        ViewSplit([f.name for f in views.train], [f.name for f in views.heldout], views.rule).save(out / "views.json")

        pixels = loader.pixel_set(views.train)
        if ctx.allotment is not None and params.steps == 0:
            left = ctx.allotment.seconds - (time.monotonic() - started)
            params = replace(params, seconds=training_seconds(left, params.eval_budget))
            ctx.log.info("train: %g s of training (as many steps as fit, the learning rate decaying over the time) "
                         "fit its %s, with evaluation", params.seconds, ctx.allotment.describe())
            if left < params.seconds:
                ctx.log.warning("train: the budget leaves %.0f s for training; training %g s anyway (give a larger "
                                "--budget, or --budget off and train.seconds)", max(left, 0.0), params.seconds)
        trainer = Trainer(model, pixels, params, out, device, density_noise=density_noise(params, layout))
        for decision in (params.optim.distortion > 0 and f"mip-NeRF 360's distortion loss (Eq. 15) at weight "
                         f"{params.optim.distortion:g} against floaters", params.optim.pixels == "error" and DRAWS,
                         describe_masks(trainer.pixels), describe_carving(model.sampler)):
            if decision:
                decisions.append(decision)
                ctx.log.info("train: %s", decision)
        resumed = trainer.resume()
        if resumed is not None:
            ctx.log.info("train: resuming from the checkpoint at step %d (%.0f s of training)", resumed, trainer.elapsed)
        if ctx.allotment is None or params.steps > 0:
            ctx.log.info("train: %s", f"{params.steps} steps" if params.steps > 0 else
                         f"{params.seconds:g} s of training (train.seconds; as many steps as fit, the learning rate "
                         "decaying over the time)")
        with watching(model, loader.world, loader.images, loader.bounds, ctx.extra.get("watch_port"),
                      ctx.extra.get("watch_host", "127.0.0.1"), ctx.log):
            with ctx.progress(trainer.total - trainer.done_units(), "train") as advance:
                trainer.run(advance, None if ctx.allotment is None or params.steps > 0 else floor_hook(
                    ctx.log, ctx.allotment.budget, ctx.later, model, loader, views, params.seconds, params.chunk,
                    (evaluated_scale(params.eval_scale), params.eval_budget * params.seconds)))
            ctx.log.info("train: %d steps drew %s rays, %.0f a second, %.3g per training pixel, at %.1f samples a ray%s",
                         trainer.step, f"{trainer.total_rays:,}", trainer.total_rays / max(trainer.elapsed, 1e-9),
                         trainer.total_rays / max(int(pixels.rgb.shape[0]), 1),
                         trainer.total_samples / max(trainer.total_rays, 1),
                         f"; it stopped {trainer.given:.0f} s early for the outputs' floors" if trainer.given >= 1 else "")
            model.save(out)
            cameras, per_image = trained_cameras(model, loader.world, views.train)
            (out / "cameras").mkdir(exist_ok=True)
            cameras.save(out / "cameras")
            scale, predicted = evaluation_scale(params.eval_scale, model, loader, views.heldout, params.chunk)
            if views.heldout:
                first = loader.world.camera_of(views.heldout[0])
                ctx.log.info("train: evaluation: %d views at %dx%d (%s of their size), about %.0f s",
                             len(views.heldout), *scaled_size(first.width, first.height, scale), f"{scale:g}", predicted)
                # what the budget keeps for scoring, and what training gave the outputs' floors (``floor_hook``)
                kept = params.eval_budget * trainer.elapsed + trainer.given
                if ctx.allotment is not None and params.steps == 0 and predicted > kept + 1.0:
                    ctx.log.warning("train: the evaluation at %dx%d takes about %.0f s, %.0f s more than the %.0f s kept "
                                    "for it: the job takes that much longer rather than score the views smaller (a "
                                    "larger --budget, or --budget off, runs it as set)",
                                    *scaled_size(first.width, first.height, scale), predicted, predicted - kept, kept)
            with ctx.progress(len(views.heldout), "evaluate") as advance:
                evaluation = evaluate(model, loader, views.heldout, out / "eval", params.chunk, advance, scale=scale)
        write_masks(out / "masks", loader, loader.world.frames)  # as trained and scored, for the exports
        summary = TrainSummary(
            steps=trainer.step,
            budget_seconds=round(trainer.config.seconds, 2) if params.steps == 0 else None,
            train_seconds=round(trainer.elapsed, 2),
            given_seconds=round(trainer.given, 2),
            throughput=Throughput(
                samples_per_s=round(trainer.total_samples / max(trainer.elapsed, 1e-9)),
                samples_per_ray=round(trainer.total_samples / max(trainer.total_rays, 1), 2),
                # what a step is spent on: the rays drawn, and how often each training pixel was drawn on average
                rays=trainer.total_rays,
                rays_per_s=round(trainer.total_rays / max(trainer.elapsed, 1e-9)),
                rays_per_pixel=round(trainer.total_rays / max(int(pixels.rgb.shape[0]), 1), 4),
            ),
            field=model.field_kind,
            occupancy=model.sampler.stats().get("occupancy"),
            device=str(device),
            train_images=len(views.train),
            scores=HeldoutScores(
                heldout=len(views.heldout), heldout_rule=views.rule, eval_scale=evaluation["scale"],
                eval_size=evaluation["views"][0]["size"] if evaluation["views"] else None,
                psnr=evaluation["psnr"], ssim=evaluation["ssim"], psnr_photo=evaluation.get("psnr_photo"),
                psnr_mean_appearance=evaluation.get("psnr_mean_appearance"), protocol=evaluation["protocol"],
            ),
            **per_image,
            resumed_from=resumed,
            stall_guard=trainer.guard.report(),
            decisions=decisions,
        )
        write_json_atomic(out / "metrics.json", {**summary.to_json(), "views": evaluation["views"],
                                                 "eval_seconds": evaluation["seconds"]})
        if evaluation["psnr"] is not None:
            photo = f" (against the photos as taken, backdrop included: {evaluation['psnr_photo']:.2f} dB)" \
                if "psnr_photo" in evaluation else ""
            ctx.log.info("train: held-out PSNR %.2f dB, SSIM %.3f over %d views at %dx%d%s", evaluation["psnr"],
                         evaluation["ssim"], len(views.heldout), *evaluation["views"][0]["size"], photo)
        return summary


# What the train stage keeps of its allotment for saving the model and timing the evaluation, and the least
# training a budget can leave it (a budget smaller than the stages before training need still trains this long).
SAVE_RESERVE_SECONDS = 3.0
MIN_TRAIN_SECONDS = 20.0
FASTEST_STEP_SECONDS = 1e-3  # no machine trains a step faster (an H200 runs 45-110 a second): a floor, for refusing


def training_seconds(allotted: float, eval_budget: float) -> float:
    """Seconds of training that, with the evaluation after it (at most ``eval_budget`` of the training time)
    and saving, fit in ``allotted`` seconds; at least ``MIN_TRAIN_SECONDS``, whole seconds."""
    return float(max(MIN_TRAIN_SECONDS, int((allotted - SAVE_RESERVE_SECONDS) / (1.0 + eval_budget))))
