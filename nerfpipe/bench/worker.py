"""One benchmark configuration, in a process of its own (``python -m nerfpipe.bench.worker SPEC OUT``).

A fresh process per configuration: its peak memory is its own, and the CPU settings of training
(``nerfpipe.nerf.cpu``) are made before torch computes anything, as in ``nerfpipe run``.

Trains with the train stage's model and trainer for at most ``budget`` seconds of training, keeps a copy
of the model at each wall-clock checkpoint (copying is off the clock), then evaluates every copy on the
held-out views: PSNR and SSIM against training time.
"""

from __future__ import annotations

import dataclasses
import json
import resource
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # torch is imported once the CPU settings are made (``run``)
    import torch

    from nerfpipe.geometry.cameras import Frame
    from nerfpipe.nerf.train.images import ImageLoader, Views
    from nerfpipe.nerf.model import RadianceModel
    from nerfpipe.nerf.config import TrainSettings
    from nerfpipe.nerf.train.trainer import Trainer


def run(spec: dict[str, Any]) -> dict[str, Any]:
    from nerfpipe.nerf.cpu import flush_denormals, keep_freed_memory

    keep_freed_memory()
    with flush_denormals():
        return _run(spec)


@dataclass
class Setup:
    """What the train stage would train for the spec's settings: its model, images, views and config."""

    device: torch.device
    loader: ImageLoader
    views: Views
    heldout: list[Frame]  # the held-out views evaluated: ``eval_views`` of them, evenly spaced (0: all)
    model: RadianceModel
    decisions: list[str]
    config: TrainSettings  # the train stage's parameters, checkpoints off and a budget's seconds in
    chunk: int
    density_noise: float = 0.0
    eval_scale: float = 1.0  # the share of the photos' side the held-out views are scored at, as the train stage does


def prepare(spec: dict[str, Any]) -> Setup:
    """The train stage's model and training configuration for the spec's settings, from the pipeline's
    results up to ``scene``; no checkpoints (the bench keeps its copies of the model in memory)."""
    import numpy as np

    from nerfpipe import Pipeline, default_stages
    from nerfpipe.nerf.policy import build_model, density_noise
    from nerfpipe.nerf.device import resolve_device
    from nerfpipe.nerf.train.evaluation import evaluated_scale
    from nerfpipe.nerf.train.images import ImageLoader, split_views

    # "": each configuration is exactly its own settings, whatever machine a preset would be sized for
    pipe = Pipeline(default_stages(), Path(spec["capture"]), Path(spec["run_dir"]), "", spec["overrides"])
    params = pipe.plan()["train"].params
    device = resolve_device(params.device, "train.device")
    loader = ImageLoader.from_inputs(pipe.stage_inputs("train"))
    views = split_views(loader.world, params.holdout_every, params.train_images, params.eval_stride)
    heldout = views.heldout
    if spec["eval_views"] and spec["eval_views"] < len(heldout):
        pick = np.unique(np.linspace(0, len(heldout) - 1, spec["eval_views"]).round().astype(int))
        heldout = [heldout[i] for i in pick]
    model, decisions = build_model(params, loader.scene, loader.world, loader.bounds, device, [f.name for f in views.train],
                                   loader.silhouettes(views.train))
    config = dataclasses.replace(params, checkpoint_every=10**9, keep_checkpoints=1)
    if config.steps == 0 and "seconds" not in spec["overrides"].get("train", {}):
        # a time-budgeted preset trains for the benchmark's budget: its learning rate decays over that time
        config = dataclasses.replace(config, seconds=float(spec["budget"]))
    return Setup(device, loader, views, heldout, model, decisions, config, params.chunk,
                 density_noise(params, loader.scene.layout.value), evaluated_scale(params.eval_scale))


def prepare_capture(capture: Path, run_dir: Path, size: int, sets: list[str], budget: float,
                    preset: str = "fast") -> Setup:
    """``prepare`` for the scripts: the train ``preset``'s settings, then ``--set`` assignments and
    ``ingest.max_size`` as overrides, the stages up to scene run (or reused) in ``run_dir`` first."""
    from nerfpipe import Pipeline, default_stages
    from nerfpipe.nerf.presets import PRESETS
    from nerfpipe.pipeline.params import parse_assignments

    overrides = parse_assignments(sets)
    overrides["train"] = {**{k: str(v) for k, v in PRESETS[preset].items()}, **overrides.get("train", {})}
    overrides.setdefault("ingest", {})["max_size"] = str(size)
    Pipeline(default_stages(), capture, run_dir, "", {k: v for k, v in overrides.items() if k != "train"}).run(
        until="scene")
    return prepare({"capture": str(capture), "run_dir": str(run_dir), "overrides": overrides, "eval_views": 0,
                    "budget": budget})


def train(setup: Setup, budget: float, marks: list[float]) -> tuple[Trainer, list[dict[str, Any]], int]:
    """Train for at most ``budget`` seconds, copying the model at each of ``marks`` (seconds of training) and
    where training ended. Returns the trainer, the copies and the peak memory in bytes."""
    import torch

    from nerfpipe.nerf.train.trainer import Trainer

    marks = sorted(marks)
    snapshots: list[dict[str, Any]] = []
    device = setup.device
    with tempfile.TemporaryDirectory() as scratch:
        trainer = Trainer(setup.model, setup.loader.pixel_set(setup.views.train), setup.config, Path(scratch), device,
                          density_noise=setup.density_noise)
        if device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(device)

        def snapshot(t: Trainer, mark: float | None) -> None:
            state = {k: {n: v.detach().to("cpu", copy=True) for n, v in d.items()} for k, d in t.model.state().items()}
            snapshots.append({"mark": mark, "seconds": t.elapsed, "step": t.step, "state": state})

        def after_step(t: Trainer) -> bool:
            while marks and t.elapsed >= marks[0]:
                snapshot(t, marks.pop(0))
            return t.elapsed >= budget

        trainer.run(after_step=after_step)
        if not snapshots or snapshots[-1]["step"] != trainer.step:
            snapshot(trainer, None)  # where training ended: the last steps, or the budget
    peak = (torch.cuda.max_memory_allocated(device) if device.type == "cuda"
            else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
    return trainer, snapshots, int(peak)


def evaluate_snapshots(setup: Setup, snapshots: list[dict[str, Any]], name: str) -> tuple[list[dict[str, Any]], float | None]:
    """Each copy's held-out PSNR and SSIM; and the seconds to render a held-out view (of the last copy)."""
    from nerfpipe.nerf.train.evaluation import evaluate

    points = []
    render_seconds = None
    for snap in snapshots:
        setup.model.load_state({k: {n: v.to(setup.device) for n, v in d.items()} for k, d in snap["state"].items()})
        started = time.perf_counter()
        result = evaluate(setup.model, setup.loader, setup.heldout, None, setup.chunk, scale=setup.eval_scale)
        render_seconds = (time.perf_counter() - started) / max(len(setup.heldout), 1)
        points.append({"mark": snap["mark"], "seconds": round(snap["seconds"], 2), "step": snap["step"],
                       "psnr": result["psnr"], "ssim": result["ssim"]})
        print(f"  {name}: {snap['seconds']:.0f} s, step {snap['step']}: PSNR {result['psnr']:.2f} dB", flush=True)
    return points, render_seconds


def _run(spec: dict[str, Any]) -> dict[str, Any]:
    import torch

    from nerfpipe.nerf.train.evaluation import scaled_size

    setup = prepare(spec)
    budget = float(spec["budget"])
    trainer, snapshots, peak = train(setup, budget, [float(m) for m in spec["checkpoints"] if m <= budget])
    points, render_seconds = evaluate_snapshots(setup, snapshots, spec["name"])
    device, heldout = setup.device, setup.heldout
    camera = setup.loader.world.camera_of(heldout[0]) if heldout else None
    return {
        "name": spec["name"],
        "group": spec["group"],
        "note": spec.get("note", ""),
        "train": spec["overrides"].get("train", {}),
        "device": torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU ({torch.get_num_threads()} threads)",
        "steps": trainer.step,
        "steps_planned": setup.config.steps,
        "finished": trainer.finished(),
        "train_seconds": round(trainer.elapsed, 2),
        "samples_per_s": round(trainer.total_samples / max(trainer.elapsed, 1e-9)),
        "samples_per_ray": round(trainer.total_samples / max(trainer.total_rays, 1), 2),
        "render_seconds_per_image": None if render_seconds is None else round(render_seconds, 3),
        "image_size": None if camera is None else list(scaled_size(camera.width, camera.height, setup.eval_scale)),
        "peak_memory_bytes": peak,
        "train_images": len(setup.views.train),
        "heldout": len(heldout),
        "decisions": setup.decisions,
        "points": points,
    }


def main() -> None:
    spec = json.loads(Path(sys.argv[1]).read_text())
    result = run(spec)
    Path(sys.argv[2]).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
