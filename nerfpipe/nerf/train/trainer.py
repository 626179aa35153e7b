"""The optimization of Section 5.3: random rays from all training pixels, the coarse + fine loss of
Eq. 6, Adam with an exponentially decaying learning rate; checkpoints that a killed run resumes from."""

from __future__ import annotations

import copy
import json
import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import torch
from torch import Tensor

from nerfpipe.nerf.train.checkpoints import load_latest_checkpoint, save_checkpoint
from nerfpipe.nerf.train.compiled import StaticStep, compile_mode
from nerfpipe.nerf.train.loss import step_loss
from nerfpipe.nerf.train.sampling import ErrorMap, image_sizes
from nerfpipe.nerf.kernels import eager
from nerfpipe.nerf.device import synchronize
from nerfpipe.nerf.config import OptimParams, TrainSettings
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.train.stall import StallGuard, mean_colour_psnr, mse_to_psnr
from nerfpipe.pipeline.errors import StageError

log = logging.getLogger("nerfpipe.nerf.train.trainer")


LOG_EVERY = 25  # steps between the lines of metrics.jsonl
POSE_DECAY = 0.01  # the camera corrections' rate decays to this share of pose_lr, whatever lr_final is
POSE_WARMUP = 0.1  # the cameras stay put for this share of the steps, then their rate ramps up over as many


@dataclass
class PixelSet:
    """Every training pixel. rgb: (P, 3) targets in [0, 1]; image: (P,) int64 image index; uv: (P, 2) pixel
    centres; intrinsics: (I, 4) (fx, fy, cx, cy); c2w: (I, 4, 4); near, far: (I,).

    Against a constant backdrop (``nerfpipe.imaging.masks``), or None: alpha: (P,) float32, 1 on the
    object, 0 on the backdrop; ``Trainer.backdrop_targets`` says what each teaches.
    """

    rgb: Tensor
    image: Tensor
    uv: Tensor
    intrinsics: Tensor
    c2w: Tensor
    near: Tensor
    far: Tensor
    alpha: Tensor | None = None
    least_depth: Tensor | None = None  # (I, rows, columns) ``nerfpipe.geometry.freespace.frame_least_depths``

    FIELDS = ("rgb", "image", "uv", "intrinsics", "c2w", "near", "far", "alpha", "least_depth")

    def to(self, device: torch.device) -> "PixelSet":
        return PixelSet(*(None if getattr(self, k) is None else getattr(self, k).to(device) for k in self.FIELDS))


def final_lr(optim: OptimParams) -> float:
    """The learning rate at the last step: ``lr_final``, at most ``lr``."""
    return min(optim.lr_final, optim.lr)


def learning_rate(config: TrainSettings, progress: float) -> float:
    """lr * (lr_final / lr)^progress: exponential decay from lr to lr_final (Section 5.3), ``progress`` the share
    of training done (step / steps, or elapsed / seconds for a time budget)."""
    return config.optim.lr * (final_lr(config.optim) / config.optim.lr) ** min(max(progress, 0.0), 1.0)


def parameter_groups(model: RadianceModel, config: TrainSettings) -> list[dict]:
    """Adam's parameter groups: the fields at ``lr`` (a grid field's MLPs at ``mlp_lr_share`` of it); the per-image
    exposure gains at ``appearance_lr`` and camera corrections at ``pose_lr``, when the model has them. Each group's
    ``base_lr`` decays exponentially to ``final`` times itself (the fields' and the gains' to lr_final / lr); a group
    with a ``warmup`` w (a share of training) learns nothing before w and ramps up linearly until 2 w."""
    groups = []
    for f in model.fields():
        tables = list(getattr(f, "feature_tables", list)())  # optional: a field without tables (an MLP) has none
        rest = [p for p in f.parameters() if all(p is not t for t in tables)]
        if tables:  # a table's rows each see a few samples a step, its MLPs' weights every one: they take smaller steps
            groups.append({"params": tables, "base_lr": config.optim.lr, "warmup": 0})
        groups.append({"params": rest, "base_lr": config.optim.lr * (config.optim.mlp_lr_share if tables else 1.0), "warmup": 0})
    if model.appearance is not None:
        groups.append({"params": list(model.appearance.parameters()), "base_lr": config.per_image.appearance_lr, "warmup": 0})
    if model.refinement is not None:  # a field that shows nothing yet would move the cameras anywhere
        # and decays far (to pose_lr / 100, what the draft field's 10-fold decay squared gave): cameras that settle
        # early let the field fit them for the rest of the steps (lego, cameras off by 1 degree and 1 %, 500 steps:
        # 0.6 dB from the clean poses' held-out PSNR, against 1.3 dB when they decayed as the field did)
        groups.append({"params": list(model.refinement.parameters()), "base_lr": config.per_image.pose_lr,
                       "warmup": POSE_WARMUP, "final": POSE_DECAY if config.per_image.pose_lr > 0 else 1.0})  # 0: frozen
    for group in groups:
        group["lr"] = group["base_lr"]
        group.setdefault("final", final_lr(config.optim) / config.optim.lr)
    return groups


def set_precision(config: TrainSettings, device: torch.device) -> None:
    """TF32 matmuls and convolutions on CUDA when ``config.tf32``; nothing otherwise. torch's flags are
    process-wide and stay set, so evaluation after training computes as training did."""
    if device.type == "cuda" and config.tf32:
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True


def _autocast(device: torch.device, mode: str):
    if mode == "none":
        return torch.autocast(device.type, enabled=False)
    return torch.autocast(device.type, dtype=torch.bfloat16 if mode == "bf16" else torch.float16)


class Trainer:
    """Optimizes a ``RadianceModel`` on a ``PixelSet``; writes checkpoints and ``metrics.jsonl`` in ``out``.
    Applies the config's precision settings (``set_precision``)."""

    def __init__(self, model: RadianceModel, pixels: PixelSet, config: TrainSettings, out: Path, device: torch.device,
                 density_noise: float = 0.0, clock: Callable[[], float] = time.perf_counter) -> None:
        """``config``: the train stage's parameters (``steps`` or ``seconds``, ``seed``, checkpoints, precision
        and the ``optim`` and ``per_image`` groups); ``density_noise``: std of the noise on raw density the scene
        calls for (``nerfpipe.nerf.policy.density_noise``); ``clock``: seconds from any start, what a time budget
        is measured by (a test's makes steps take a known time)."""
        set_precision(config, device)
        self.clock = clock
        self.model, self.pixels, self.config, self.out, self.device = model, pixels.to(device), config, out, device
        self.density_noise = density_noise
        groups = parameter_groups(model, config)
        # fused Adam: one pass over each tensor, which matters for grids of millions of values on a CPU
        fused = device.type in ("cpu", "cuda") and all(p.dtype == torch.float32 for g in groups for p in g["params"])
        self.optimizer = torch.optim.Adam(groups, lr=config.optim.lr, betas=(0.9, config.optim.adam_beta2), eps=config.optim.adam_eps,
                                          fused=fused)
        self.scaler = torch.amp.GradScaler(device.type, enabled=config.autocast == "fp16")
        self.error_map = None if config.optim.pixels == "uniform" else ErrorMap(
            image_sizes(self.pixels.image, self.pixels.uv, len(self.pixels.intrinsics))).to(device)
        self.step = 0
        self.elapsed = 0.0
        self.given = 0.0  # seconds of a time budget given to the outputs' floors (``give``)
        self._decay_from: tuple[float, float] | None = None  # (elapsed, progress) where ``give`` last moved the end
        self.resumed_from: int | None = None
        self.background = model.background_tensor()
        self.rays_per_batch = float(config.optim.batch_rays)  # adapted to ``batch_samples`` while marching
        self.samples = 0  # field evaluations of the last step
        self.rays = 0  # rays of the last step
        self.total_samples = 0
        self.total_rays = 0
        self.lr_scale = 1.0  # halved by a restart after a stall
        model.sampler.start(model.ray_space, self.pixels.intrinsics, self.pixels.c2w, self.pixels.least_depth)
        self.static = self.static_step(compile_mode(config.compile, device))
        check = 200 if config.steps <= 0 else min(max(200, config.steps // 8), config.steps)
        self.guard = StallGuard(mean_colour_psnr(self.pixels.rgb), check_step=check)
        self._initial = copy.deepcopy(model.state())

    def static_step(self, mode: str) -> StaticStep | None:
        """The fixed-shape compiled step ``mode`` asks for (``nerfpipe.nerf.train.compiled``), or None: eager. Its
        shapes: every sample of ``optim.batch_samples``, and rays up to the most a step draws (16 ``batch_rays``)."""
        if mode == "off":
            return None
        optim = self.config.optim
        if not (self.model.sampler.adaptive and optim.batch_samples > 0):
            log.info("train: the step stays eager (train.compile=%s): fixed shapes need a sampler that marches to "
                     "optim.batch_samples > 0 samples a step", self.config.compile)
            return None
        log.info("train: the step compiled at fixed shapes (%s): %d samples, %d rays", mode, optim.batch_samples,
                 16 * optim.batch_rays + 1)
        return StaticStep(self.model, 16 * optim.batch_rays + 1, optim.batch_samples, mode, optim.distortion,
                          self.density_noise, self.clock)

    @property
    def checkpoint_dir(self) -> Path:
        return self.out / "checkpoints"

    def resume(self) -> int | None:
        """Load the newest checkpoint in ``out``, if any; returns its step."""
        state = load_latest_checkpoint(self.checkpoint_dir, self.device)
        if state is None:
            return None
        self.model.load_state(state)
        self.optimizer.load_state_dict(state["optimizer"])
        self.step, self.elapsed = int(state["step"]), float(state["elapsed"])
        self.rays_per_batch = float(state.get("rays_per_batch", self.config.optim.batch_rays))
        self.total_samples, self.total_rays = int(state.get("total_samples", 0)), int(state.get("total_rays", 0))
        self.lr_scale = float(state.get("lr_scale", 1.0))
        if self.error_map is not None and "error_map" in state:
            self.error_map.load_state_dict({"error": state["error_map"]})
        if int(state.get("restarted_at", -1)) >= 0:
            self.guard.restarted_at = int(state["restarted_at"])
        if float(state.get("psnr_ema", -1.0)) >= 0:  # the guard goes on as if never stopped
            self.guard.ema = float(state["psnr_ema"])
        self.resumed_from = self.step
        self._truncate_metrics(self.step)
        return self.step

    def _truncate_metrics(self, step: int) -> None:
        """Drop log lines written after the checkpoint we resume from: they will be written again."""
        path = self.out / "metrics.jsonl"
        if path.exists():
            kept = [line for line in path.read_text().splitlines() if line.strip() and json.loads(line)["step"] <= step]
            path.write_text("".join(line + "\n" for line in kept))

    def batch(self, step: int) -> tuple[Tensor, Tensor | None, Tensor | None, torch.Generator]:
        """The pixel indices of ``step``'s rays; with an error map, their tiles and loss weights (else None); and the
        step's generator. A function of (seed, step) and the error map only, so a resumed run draws exactly the
        batches an uninterrupted one would."""
        generator = torch.Generator(device=self.device).manual_seed(self.config.seed * 1_000_003 + step)
        count = int(self.rays_per_batch)
        if self.error_map is not None:
            return (*self.error_map.draw(count, generator), generator)
        index = torch.randint(self.pixels.rgb.shape[0], (count,), generator=generator, device=self.device)
        return index, None, None, generator

    def before_step(self, step: int, generator: torch.Generator) -> None:
        """Let the sampler catch up with the field (an occupancy grid refreshed from its density)."""
        was_training = self.model.coarse.training
        self.model.coarse.eval()
        self.model.sampler.update(step, self.model.coarse.query_density, generator)
        self.model.coarse.train(was_training)

    def train_step(self, step: int) -> tuple[float, float]:
        """One optimization step; returns (loss, PSNR of the final rendering on this batch)."""
        px = self.pixels
        index, tiles, weight, generator = self.batch(step)
        image = px.image[index]
        model = self.model
        c2w = px.c2w if model.refinement is None else model.refinement(px.c2w)  # (I, 4, 4)
        rays = model.ray_space.rays(px.uv[index], px.intrinsics[image], c2w[image], px.near[image], px.far[image])
        target, backdrop = self.backdrop_targets(index, px.rgb[index], generator)
        if self.density_noise > 0:  # the noise, too, is a function of (seed, step): resuming does not change it
            torch.manual_seed(self.config.seed * 1_000_003 + step)
        progress = self.progress(step)
        for group in self.optimizer.param_groups:
            warmup = group.get("warmup", 0)
            ramp = 1.0 if not warmup else min(max((progress - warmup) / warmup, 0.0), 1.0)
            decay = group.get("final", final_lr(self.config.optim) / self.config.optim.lr) ** min(max(progress, 0.0), 1.0)
            group["lr"] = group["base_lr"] * decay * self.lr_scale * ramp
        with _autocast(self.device, self.config.autocast):
            self.before_step(step, generator)
            if self.static is not None:  # the samples' count padded to the fixed budget, the rest compiled
                loss, mse, errors, self.rays, self.samples = self.static(rays, target, weight, backdrop, image, generator)
            else:
                # a grid update can make every ray longer at once: at most twice the samples wanted, whatever the
                # number of rays drawn (a sampler whose cost per ray is fixed ignores the bound)
                out = model.render(rays, train=True, generator=generator, max_samples=2 * self.config.optim.batch_samples,
                                   background="model" if backdrop is None else backdrop, images=image,
                                   density_noise=self.density_noise)
                self.rays, self.samples = len(out), out.evaluated
                share = torch.full((self.rays,), 1.0 / self.rays, device=self.device)
                loss, mse, errors = step_loss(out, target[:self.rays], share, None if weight is None else weight[:self.rays],
                                              self.config.optim.distortion)
            if self.config.optim.batch_samples > 0 and model.sampler.adaptive:  # Instant-NGP: samples per batch about constant
                per_ray = max(self.samples / self.rays, 1.0)
                wanted = min(max(self.config.optim.batch_samples / per_ray, 256.0), 16.0 * self.config.optim.batch_rays)
                # grow smoothly; shrink at once, since a batch too large costs time and memory
                self.rays_per_batch = min(0.8 * self.rays_per_batch + 0.2 * wanted, wanted)
        if self.error_map is not None:  # drawn by the error map: each ray's loss was weighted back to its uniform share
            self.error_map.record(tiles[:self.rays], errors.detach())
        if model.refinement is not None:
            loss = loss + self.config.per_image.pose_penalty * model.refinement.penalty()
        self.optimizer.zero_grad(set_to_none=True)
        self.scaler.scale(loss).backward()
        self.scaler.step(self.optimizer)
        self.scaler.update()
        return float(loss.detach()), mse_to_psnr(float(mse.detach()))

    def backdrop_targets(self, index: Tensor, target: Tensor, generator: torch.Generator) -> tuple[Tensor, Tensor | None]:
        """Targets (R, 3) and the colour (R, 3) each ray's render is composited onto, with backdrop masks
        (``PixelSet.alpha``); without them, ``target`` and None (the model's background, if any).

        Instant-NGP's random background for images with alpha: each ray draws a colour c ~ U[0, 1]^3 (from
        ``generator``: a function of (seed, step)). A backdrop pixel's target is c, which only empty space
        renders whatever c is; an object pixel keeps its photo colour over c, so it must be opaque. A fixed
        colour instead cannot tell empty space from a surface of that colour: trained against black, the
        temple's backdrop may as well be black density.
        """
        px = self.pixels
        if px.alpha is None or self.background is None:
            return target, None
        random = torch.rand((len(index), 3), generator=generator, device=target.device, dtype=target.dtype)
        alpha = px.alpha[index].unsqueeze(-1)
        return alpha * target + (1.0 - alpha) * random, random

    def restart(self) -> None:
        """Back to the initial weights with a fresh occupancy grid and optimizer, at half the learning rate."""
        self.model.load_state(copy.deepcopy(self._initial))
        self.model.sampler.reset()
        self.optimizer.state.clear()
        self.lr_scale *= 0.5
        self.rays_per_batch = float(self.config.optim.batch_rays)
        if self.error_map is not None:
            self.error_map.error.fill_(-1.0)

    def watch(self, psnr: float) -> None:
        """Let the stall guard see this step's batch PSNR, and act on what it says."""
        verdict = self.guard.observe(self.step, psnr, self.finished())
        floor = self.guard.floor_db
        if verdict == "restart":
            log.warning("train: batch PSNR stalled near %.1f dB, the level of a render in the mean colour, at step %d; "
                        "restarting from the initial weights at half the learning rate", floor, self.step)
            self.restart()
        elif verdict == "stalled":
            log.warning("train: batch PSNR %.1f dB is still at the level of a render in the mean colour (%.1f dB) at "
                        "step %d: the renders will be close to one flat colour; check the poses and the scene "
                        "decisions (nerfpipe status)", self.guard.ema, floor, self.step)

    def progress(self, step: int | None = None) -> float:
        """The share of training done: step / steps, or with a time budget elapsed / seconds (after ``give``,
        from where it was then to 1 at the new end)."""
        if self.config.steps > 0:
            return (self.step if step is None else step) / self.config.steps
        if self._decay_from is not None:
            at, done = self._decay_from
            return done + (1.0 - done) * (self.elapsed - at) / max(self.config.seconds - at, 1e-9)
        return self.elapsed / max(self.config.seconds, 1e-9)

    def give(self, seconds: float) -> None:
        """Give the outputs after training ``seconds`` of a time budget's training in all, in place of what it gave
        before: it ends that much before the end it was set (never before now), sooner or later than it was to. The
        learning rate goes on decaying from where it is and reaches its final value at the new end."""
        if self.config.steps > 0 or self.finished():
            return
        end = max(self.config.seconds + self.given - max(seconds, 0.0), self.elapsed)
        if end != self.config.seconds:
            self._decay_from = (self.elapsed, self.progress())
            self.given, self.config = self.config.seconds + self.given - end, replace(self.config, seconds=end)

    def finished(self) -> bool:
        return self.progress() >= 1.0

    @property
    def total(self) -> int:
        """Units of training for a progress bar: steps, or whole seconds of a time budget."""
        return self.config.steps if self.config.steps > 0 else math.ceil(self.config.seconds)

    def done_units(self) -> int:
        return self.step if self.config.steps > 0 else min(int(self.elapsed), self.total)

    def run(self, advance: Callable[..., None] = lambda n=1, info=None: None,
            after_step: Callable[["Trainer"], bool] | None = None) -> None:
        """Train from ``self.step`` to ``config.steps`` (or until ``config.seconds`` of training have passed).

        ``after_step(trainer)`` runs after every step, off the clock (``elapsed`` counts training only), and
        stops training by returning True. ``advance(n, info=...)`` counts ``total`` units: steps, or seconds.
        """
        config = self.config
        for f in self.model.fields():
            f.train()
        window_start, window_steps, window_samples, window_rays = self.elapsed, 0, 0, 0
        reported = self.done_units()
        with open(self.out / "metrics.jsonl", "a", encoding="utf-8") as metrics:
            # the clock runs from here to each step's end, and again from the end of ``after_step``: the
            # bookkeeping after a step (logging, checkpoints) counts towards the next one, so a time budget
            # is judged once a step, right after it, and the step that spends it is the one logged last
            started = self.clock()
            while not self.finished():
                with eager():  # the step's own rendering as its backward pass is: not compiled (``nerf.kernels``)
                    loss, psnr = self.train_step(self.step)
                rays = self.rays
                if not math.isfinite(loss):
                    raise StageError(f"train: the training loss became {loss} at step {self.step}, so the field diverged; "
                                     f"lower train.optim.lr (now {self.config.optim.lr:g}) or the per-image learning rates")
                synchronize(self.device)
                self.step += 1
                now = self.clock()
                # compiling the step is set-up, as building the model is: the time budget is the training's
                self.elapsed += now - started - (self.static.take_compile_seconds() if self.static is not None else 0.0)
                started = now
                last = self.finished()
                self.watch(psnr)
                window_steps += 1
                window_samples += self.samples
                window_rays += rays
                self.total_samples += self.samples
                self.total_rays += rays
                if self.step % LOG_EVERY == 0 or last:
                    span = max(self.elapsed - window_start, 1e-9)
                    rate = window_steps / span
                    record = {"step": self.step, "wall": round(self.elapsed, 3), "loss": loss, "psnr": round(psnr, 4),
                              "lr": learning_rate(config, self.progress()) * self.lr_scale, "steps_per_s": round(rate, 3),
                              "samples_per_s": round(window_samples / span),
                              "samples_per_ray": round(window_samples / max(window_rays, 1), 2),
                              "rays_per_batch": rays}
                    window_start, window_steps, window_samples, window_rays = self.elapsed, 0, 0, 0
                    record.update(self.model.sampler.stats())
                    metrics.write(json.dumps(record) + "\n")
                    metrics.flush()
                    units = self.total if last else self.done_units()
                    advance(units - reported, info=f"loss {loss:.4f}  PSNR {psnr:.2f} dB  {rate:.1f} steps/s")
                    reported = units
                if self.step % config.checkpoint_every == 0 or last:
                    save_checkpoint(self.checkpoint_dir, self.step, self.elapsed, self.model, self.optimizer,
                                    config.keep_checkpoints, {"rays_per_batch": self.rays_per_batch,
                                    "total_samples": self.total_samples, "total_rays": self.total_rays,
                                    "lr_scale": self.lr_scale, "restarted_at": self.guard.restarted_at or -1,
                                    "psnr_ema": -1.0 if self.guard.ema is None else self.guard.ema,
                                    **({} if self.error_map is None else {"error_map": self.error_map.state_dict()["error"]})})
                    log.info("train: step %d%s, loss %.5f, batch PSNR %.2f dB, %.0f s", self.step,
                             f"/{config.steps}" if config.steps > 0 else f" of a {config.seconds:g} s budget", loss,
                             psnr, self.elapsed)
                if after_step is not None and after_step(self):
                    break
                started = self.clock()
