"""A training step at fixed shapes, compiled by ``torch.compile``: on a GPU the eager step waits on Python and on
the launch of a few hundred small kernels a step (docs/benchmarks.md, "On a GPU").

The sampler marches eagerly and without gradients, since how many samples it keeps is the data's to say. Its
samples are then padded to a fixed count (``pad_samples``) and the rays to a fixed count (``pad_rays``), so the
rest of the step -- the field at the samples, compositing (Eq. 3), the loss (Eq. 6) and their backward pass -- is
one graph of fixed shapes, compiled once: fused kernels (inductor: Triton on CUDA, C++ on the CPU) with
``kernels``, and those replayed as CUDA graphs, without Python between them, with ``graphs``. The optimizer's
step, the occupancy grid's refresh and evaluation stay outside the graph.

Padding changes nothing in the result: a padding sample is a stretch of length zero (its weight, Eq. 5, is 0
whatever the field says there, and so is its gradient) on a padding ray, whose share of the loss is 0.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Callable

import torch
from torch import Tensor

from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.render.volume import RaySamples
from nerfpipe.nerf.spaces.rays import RayBatch
from nerfpipe.nerf.train.loss import step_loss

log = logging.getLogger("nerfpipe.nerf.train.compiled")

MODES = {"kernels": "default", "graphs": "reduce-overhead"}  # train.compile -> torch.compile's mode
BACKEND: str | Callable = "inductor"  # torch.compile's backend (a test's may count graphs, or fail, instead)


def compile_mode(choice: str, device: torch.device) -> str:
    """What ``train.compile`` asks for on ``device``: off, kernels or graphs; auto is kernels on CUDA and off on
    the CPU, where the compiled step measured no faster than the eager one (docs/benchmarks.md)."""
    if choice == "auto":
        return "kernels" if device.type == "cuda" else "off"
    return choice


def pad_rows(x: Tensor, count: int) -> Tensor:
    """(R, ...) rows, R >= 1, followed by ``count - R`` copies of the first: (count, ...)."""
    return torch.cat([x, x[:1].expand(count - len(x), *x.shape[1:])])


def pad_rays(rays: RayBatch, count: int) -> RayBatch:
    """``rays`` (R <= count of them, R >= 1) followed by copies of the first: finite rays to pad with."""
    return RayBatch(*(pad_rows(x, count) for x in (rays.origins, rays.directions, rays.viewdirs, rays.near, rays.far)))


def pad_samples(samples: RaySamples, count: int, ray: int) -> RaySamples:
    """Exactly ``count`` samples of ``ray + 1`` rays: the first ``count`` of ``samples`` (every one of whose rays
    comes before ``ray``), then stretches of length zero at t = 0 on ray ``ray``, which weigh nothing."""
    if len(samples) >= count:  # one ray with more samples than the budget: its leading ones
        return dataclasses.replace(samples.select(slice(0, count)), n_rays=ray + 1)
    extra = count - len(samples)

    def grow(x: Tensor, fill: float | int) -> Tensor:
        return torch.cat([x, x.new_full((extra,), fill)])

    spans = None if samples.spans is None else (grow(samples.spans[0], 0.0), grow(samples.spans[1], 0.0))
    return RaySamples(grow(samples.ray, ray), grow(samples.t, 0.0), grow(samples.starts, 0.0), grow(samples.ends, 0.0),
                      ray + 1, spans)


class StaticStep:
    """The samples, render and loss of a training step of ``model``, at ``rays`` x ``samples`` fixed shapes.

    ``mode``: kernels or graphs (``MODES``); ``distortion`` and ``density_noise`` as the trainer's; compiled by
    ``BACKEND``; ``clock``: the trainer's, which times the first call (``take_compile_seconds``). If compiling
    fails, the step says so once and runs the same function eagerly: no machine loses training to a missing
    compiler.
    """

    def __init__(self, model: RadianceModel, rays: int, samples: int, mode: str, distortion: float = 0.0,
                 density_noise: float = 0.0, clock: Callable[[], float] = time.perf_counter) -> None:
        if rays < 2 or samples < 1:
            raise ValueError(f"a fixed-shape step needs at least 2 rays and 1 sample, got {rays} and {samples}")
        self.model, self.rays, self.samples, self.mode = model, rays, samples, mode
        self.distortion, self.density_noise = distortion, density_noise
        options = {"mode": MODES[mode]} if BACKEND == "inductor" else {}
        self.compiled: Callable = torch.compile(self.loss, backend=BACKEND, dynamic=False, **options)
        self.first = True  # the next call compiles
        self.clock, self.compile_seconds = clock, 0.0  # the first call's time, until the trainer takes it

    def loss(self, origins: Tensor, directions: Tensor, viewdirs: Tensor, near: Tensor, far: Tensor, ray: Tensor,
             t: Tensor, starts: Tensor, ends: Tensor, span_starts: Tensor | None, span_ends: Tensor | None,
             target: Tensor, share: Tensor, weight: Tensor | None, backdrop: Tensor | None,
             images: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``step_loss`` of the model's rendering of padded rays (R,) at padded samples (N,): the graph that
        compiles. Returns the loss, the mean squared error and the squared error per ray (R,)."""
        rays = RayBatch(origins, directions, viewdirs, near, far)
        spans = None if span_starts is None else (span_starts, span_ends)
        samples = RaySamples(ray, t, starts, ends, len(origins), spans)
        out = self.model.shade(rays, samples, 0, background="model" if backdrop is None else backdrop, images=images,
                               density_noise=self.density_noise)
        return step_loss(out, target, share, weight, self.distortion)

    def __call__(self, rays: RayBatch, target: Tensor, weight: Tensor | None, backdrop: Tensor | None,
                 images: Tensor, generator: torch.Generator) -> tuple[Tensor, Tensor, Tensor, int, int]:
        """One step's forward pass on ``rays`` (R, at most ``self.rays - 1``) with their targets (R, 3), loss
        weights (R,) or None, backdrop colours (R, 3) or None and training images (R,).

        Returns the loss, the mean squared error, the kept rays' squared errors (K,), the rays kept K (the
        leading rays whose samples fit ``self.samples``) and the samples evaluated, padding left out.
        """
        samples, _, _ = self.model.sample(rays, train=True, generator=generator, max_samples=self.samples,
                                          density_noise=self.density_noise)
        kept, real = samples.n_rays, min(len(samples), self.samples)
        padded = pad_samples(samples, self.samples, self.rays - 1)
        full = pad_rays(rays.slice(0, kept), self.rays)
        share = torch.zeros(self.rays, device=target.device)
        share[:kept] = 1.0 / kept

        def pad(x: Tensor | None) -> Tensor | None:
            return None if x is None else pad_rows(x[:kept], self.rays)

        spans = padded.spans or (None, None)
        # where the samples lie is the sampler's, held fixed (nerfacc's too): a camera being refined learns through
        # its rays' origins and directions. (Whether the march kept a gradient would otherwise change the graph.)
        inputs = (full.origins, full.directions, full.viewdirs, full.near, full.far, padded.ray, padded.t.detach(),
                  padded.starts.detach(), padded.ends.detach(), *spans, pad(target), share, pad(weight), pad(backdrop),
                  pad(images))
        loss, mse, errors = self._run(inputs)
        return loss, mse, errors[:kept], kept, real

    def _run(self, inputs: tuple) -> tuple[Tensor, Tensor, Tensor]:
        if not self.first:
            return self.compiled(*inputs)
        self.first, started = False, self.clock()
        try:  # the first call compiles
            result = self.compiled(*inputs)
            self.compile_seconds = self.clock() - started
            log.info("train: the first step, compiling it, took %.1f s (not counted as training time)",
                     self.compile_seconds)
            return result
        except Exception as err:  # a missing compiler, an operator inductor lacks: the same function, eagerly
            cause = getattr(err, "inner_exception", None) or err.__cause__ or err  # what the backend raised
            first = (str(cause).strip().splitlines() or [""])[0]
            log.warning("train: compiling the training step failed (%s: %s); training without compiling "
                        "(train.compile=off skips the attempt)", type(cause).__name__, first)
            self.compiled = self.loss
            self.compile_seconds = self.clock() - started
            return self.loss(*inputs)

    def take_compile_seconds(self) -> float:
        """The seconds the first call spent compiling (and the step it ran), once; 0 after."""
        seconds, self.compile_seconds = self.compile_seconds, 0.0
        return seconds
