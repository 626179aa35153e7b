"""The optimization of Section 5.3: random rays from all training pixels, the coarse + fine loss of
Eq. 6, Adam with an exponentially decaying learning rate; checkpoints that a killed run resumes from."""

from __future__ import annotations

import json
import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import torch
from torch import Tensor

from nerfpipe.nerf.field import NerfField
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.renderer import render_rays

log = logging.getLogger("nerfpipe.nerf.trainer")
CHECKPOINT_GLOB = "step_*.pt"


@dataclass(frozen=True)
class TrainConfig:
    steps: int = 3000
    batch_rays: int = 1024
    lr: float = 5e-4
    lr_final: float = 5e-5
    adam_eps: float = 1e-7
    density_noise: float = 0.0
    seed: int = 0
    checkpoint_every: int = 500
    keep_checkpoints: int = 2  # 0: keep all
    log_every: int = 25
    autocast: str = "none"  # "none", "bf16", "fp16"


@dataclass
class PixelSet:
    """Every training pixel. rgb: (P, 3) targets in [0, 1]; image: (P,) int64 image index; uv: (P, 2) pixel
    centres; intrinsics: (I, 4) (fx, fy, cx, cy); c2w: (I, 4, 4); near, far: (I,)."""

    rgb: Tensor
    image: Tensor
    uv: Tensor
    intrinsics: Tensor
    c2w: Tensor
    near: Tensor
    far: Tensor

    def to(self, device: torch.device) -> "PixelSet":
        return PixelSet(*(getattr(self, k).to(device) for k in ("rgb", "image", "uv", "intrinsics", "c2w", "near", "far")))


def mse_to_psnr(mse: float) -> float:
    """PSNR in dB of images in [0, 1] from their mean squared error."""
    return -10.0 * math.log10(max(mse, 1e-12))


def learning_rate(config: TrainConfig, step: int) -> float:
    """lr * (lr_final / lr)^(step / steps): exponential decay from lr to lr_final (Section 5.3)."""
    return config.lr * (config.lr_final / config.lr) ** (min(step, config.steps) / max(config.steps, 1))


def checkpoints(folder: Path) -> list[Path]:
    return sorted(folder.glob(CHECKPOINT_GLOB), key=lambda p: int(p.stem.split("_")[1]))


def save_checkpoint(folder: Path, step: int, elapsed: float, model: RadianceModel, optimizer: torch.optim.Optimizer,
                    keep: int) -> Path:
    """Write ``step_<n>.pt`` atomically (a killed write leaves only a temp file), then prune old ones."""
    folder.mkdir(parents=True, exist_ok=True)
    state = {"step": step, "elapsed": elapsed, "coarse": model.coarse.state_dict(), "optimizer": optimizer.state_dict()}
    if model.fine is not None:
        state["fine"] = model.fine.state_dict()
    path = folder / f"step_{step:07d}.pt"
    tmp = folder / f".{path.name}.tmp"
    torch.save(state, tmp)
    with open(tmp, "rb") as f:
        os.fsync(f.fileno())
    os.replace(tmp, path)
    if keep > 0:
        for old in checkpoints(folder)[:-keep]:
            old.unlink()
    return path


def load_latest_checkpoint(folder: Path, device: torch.device) -> dict | None:
    """The newest checkpoint that loads (tensors only: ``weights_only=True``), or None."""
    for path in reversed(checkpoints(folder)):
        try:
            return torch.load(path, map_location=device, weights_only=True)
        except Exception as err:  # a damaged file: fall back to the one before
            log.warning("checkpoint %s is unreadable (%s); trying the one before", path.name, err)
    return None


def _autocast(device: torch.device, mode: str):
    if mode == "none":
        return torch.autocast(device.type, enabled=False)
    return torch.autocast(device.type, dtype=torch.bfloat16 if mode == "bf16" else torch.float16)


class Trainer:
    """Optimizes a ``RadianceModel`` on a ``PixelSet``; writes checkpoints and ``metrics.jsonl`` in ``out``."""

    def __init__(self, model: RadianceModel, pixels: PixelSet, config: TrainConfig, out: Path, device: torch.device) -> None:
        self.model, self.pixels, self.config, self.out, self.device = model, pixels.to(device), config, out, device
        params = list(model.coarse.parameters()) + (list(model.fine.parameters()) if model.fine is not None else [])
        self.optimizer = torch.optim.Adam(params, lr=config.lr, betas=(0.9, 0.999), eps=config.adam_eps)
        self.scaler = torch.amp.GradScaler(device.type, enabled=config.autocast == "fp16")
        self.step = 0
        self.elapsed = 0.0
        self.resumed_from: int | None = None
        self.background = model.background_tensor()

    @property
    def checkpoint_dir(self) -> Path:
        return self.out / "checkpoints"

    def resume(self) -> int | None:
        """Load the newest checkpoint in ``out``, if any; returns its step."""
        state = load_latest_checkpoint(self.checkpoint_dir, self.device)
        if state is None:
            return None
        self.model.coarse.load_state_dict(state["coarse"])
        if self.model.fine is not None:
            self.model.fine.load_state_dict(state["fine"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.step, self.elapsed = int(state["step"]), float(state["elapsed"])
        self.resumed_from = self.step
        self._truncate_metrics(self.step)
        return self.step

    def _truncate_metrics(self, step: int) -> None:
        """Drop log lines written after the checkpoint we resume from: they will be written again."""
        path = self.out / "metrics.jsonl"
        if path.exists():
            kept = [line for line in path.read_text().splitlines() if line.strip() and json.loads(line)["step"] <= step]
            path.write_text("".join(line + "\n" for line in kept))

    def batch(self, step: int) -> tuple[Tensor, Tensor]:
        """Ray indices and target colours of ``step``: a function of (seed, step) only, so a resumed run
        draws exactly the batches an uninterrupted one would."""
        generator = torch.Generator(device=self.device).manual_seed(self.config.seed * 1_000_003 + step)
        index = torch.randint(self.pixels.rgb.shape[0], (self.config.batch_rays,), generator=generator, device=self.device)
        return index, generator

    def train_step(self, step: int) -> tuple[float, float]:
        """One optimization step; returns (loss, PSNR of the final rendering on this batch)."""
        px = self.pixels
        index, generator = self.batch(step)
        image = px.image[index]
        rays = self.model.ray_space.rays(px.uv[index], px.intrinsics[image], px.c2w[image], px.near[image], px.far[image])
        target = px.rgb[index]
        noise = self.config.density_noise

        def field(fn: NerfField) -> Callable[[Tensor, Tensor], tuple[Tensor, Tensor]]:
            return lambda x, d: fn(x, d, noise)

        if noise > 0:  # the noise, too, is a function of (seed, step): resuming does not change it
            torch.manual_seed(self.config.seed * 1_000_003 + step)
        for group in self.optimizer.param_groups:
            group["lr"] = learning_rate(self.config, step)
        with _autocast(self.device, self.config.autocast):
            out = render_rays(field(self.model.coarse), None if self.model.fine is None else field(self.model.fine),
                              rays, self.model.sampling, self.background, randomized=True, generator=generator)
        # Eq. 6: squared error of the coarse and the fine rendering (a mean rather than a sum over the batch)
        losses = {name: torch.mean((c.rgb - target) ** 2) for name, c in out.items()}
        loss = sum(losses.values())
        self.optimizer.zero_grad(set_to_none=True)
        self.scaler.scale(loss).backward()
        self.scaler.step(self.optimizer)
        self.scaler.update()
        final = losses.get("fine", losses["coarse"])
        return float(loss.detach()), mse_to_psnr(float(final.detach()))

    def samples_per_step(self) -> int:
        s = self.model.sampling
        coarse = s.n_coarse
        fine = s.n_coarse + s.n_fine if s.n_fine > 0 else 0
        return self.config.batch_rays * (coarse + fine)

    def run(self, advance: Callable[..., None] = lambda n=1, info=None: None) -> None:
        """Train from ``self.step`` to ``config.steps``."""
        config = self.config
        self.model.coarse.train()
        if self.model.fine is not None:
            self.model.fine.train()
        started = time.perf_counter() - self.elapsed
        window_start, window_steps = time.perf_counter(), 0
        with open(self.out / "metrics.jsonl", "a", encoding="utf-8") as metrics:
            while self.step < config.steps:
                loss, psnr = self.train_step(self.step)
                if not math.isfinite(loss):
                    raise FloatingPointError(f"training loss became {loss} at step {self.step}")
                self.step += 1
                window_steps += 1
                self.elapsed = time.perf_counter() - started
                if self.step % config.log_every == 0 or self.step == config.steps:
                    now = time.perf_counter()
                    rate = window_steps / max(now - window_start, 1e-9)
                    window_start, window_steps = now, 0
                    record = {"step": self.step, "wall": round(self.elapsed, 3), "loss": loss, "psnr": round(psnr, 4),
                              "lr": learning_rate(config, self.step), "steps_per_s": round(rate, 3),
                              "samples_per_s": round(rate * self.samples_per_step())}
                    metrics.write(json.dumps(record) + "\n")
                    metrics.flush()
                    advance(config.log_every if self.step % config.log_every == 0 else self.step % config.log_every,
                            info=f"loss {loss:.4f}  PSNR {psnr:.2f} dB  {rate:.1f} steps/s")
                if self.step % config.checkpoint_every == 0 or self.step == config.steps:
                    save_checkpoint(self.checkpoint_dir, self.step, self.elapsed, self.model, self.optimizer,
                                    config.keep_checkpoints)
                    log.info("train: step %d/%d, loss %.5f, batch PSNR %.2f dB, %.0f s", self.step, config.steps,
                             loss, psnr, self.elapsed)
