"""One benchmark configuration, in a process of its own (``python -m nerfpipe.bench.worker SPEC OUT``).

A fresh process per configuration: its peak memory is its own, and the CPU settings of training
(``nerfpipe.nerf.cpu``) are made before torch computes anything, as in ``nerfpipe run``.

Trains with the train stage's model and trainer for at most ``budget`` seconds of training, keeps a copy
of the model at each wall-clock checkpoint (copying is off the clock), then evaluates every copy on the
held-out views: PSNR and SSIM against training time.
"""

from __future__ import annotations

import json
import resource
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def run(spec: dict[str, Any]) -> dict[str, Any]:
    from nerfpipe.nerf.cpu import flush_denormals, keep_freed_memory

    keep_freed_memory()
    with flush_denormals():
        return _run(spec)


def _run(spec: dict[str, Any]) -> dict[str, Any]:
    import numpy as np
    import torch

    from nerfpipe import Pipeline, default_stages
    from nerfpipe.nerf.trainer import TrainConfig, Trainer
    from nerfpipe.stages.train import ImageLoader, build_model, density_noise, evaluate, resolve_device, split_views

    pipe = Pipeline(default_stages(), Path(spec["capture"]), Path(spec["run_dir"]), None, spec["overrides"])
    planned = pipe.plan()["train"]
    params = planned.params
    device = resolve_device(params.device)
    loader = ImageLoader.from_inputs(pipe.stage_inputs("train"))
    views = split_views(loader.world, params)
    heldout = views.heldout
    if spec["eval_views"] and spec["eval_views"] < len(heldout):
        pick = np.unique(np.linspace(0, len(heldout) - 1, spec["eval_views"]).round().astype(int))
        heldout = [heldout[i] for i in pick]
    model, decisions = build_model(params, loader.scene, loader.world, loader.bounds, device)
    pixels = loader.pixel_set(views.train)
    config = TrainConfig(
        steps=params.steps, batch_rays=params.batch_rays, lr=params.lr, lr_final=params.lr_final,
        adam_eps=params.adam_eps, adam_beta2=params.adam_beta2, batch_samples=params.batch_samples,
        density_noise=density_noise(params, loader.scene), seed=params.seed, checkpoint_every=10**9,
        keep_checkpoints=1, log_every=25, autocast=params.autocast,
    )
    budget, marks = float(spec["budget"]), sorted(float(m) for m in spec["checkpoints"] if m <= spec["budget"])
    snapshots: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as scratch:
        trainer = Trainer(model, pixels, config, Path(scratch), device)
        if device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(device)

        def snapshot(t: Trainer, mark: float | None) -> None:
            state = {k: {n: v.detach().to("cpu", copy=True) for n, v in d.items()} for k, d in t.model.state().items()}
            snapshots.append({"mark": mark, "seconds": t.elapsed, "step": t.step, "state": state,
                              "samples_per_ray": t.total_samples / max(t.total_rays, 1)})

        def after_step(t: Trainer) -> bool:
            while marks and t.elapsed >= marks[0]:
                snapshot(t, marks.pop(0))
            return t.elapsed >= budget

        trainer.run(after_step=after_step)
        if not snapshots or snapshots[-1]["step"] != trainer.step:
            snapshot(trainer, None)  # where training ended: the last steps, or the budget
        finished = trainer.step >= config.steps
        peak = (torch.cuda.max_memory_allocated(device) if device.type == "cuda"
                else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
        samples_per_s = trainer.total_samples / max(trainer.elapsed, 1e-9)
        samples_per_ray = trainer.total_samples / max(trainer.total_rays, 1)

    points = []
    render_seconds = None
    for snap in snapshots:
        model.load_state({k: {n: v.to(device) for n, v in d.items()} for k, d in snap["state"].items()})
        started = time.perf_counter()
        result = evaluate(model, loader, heldout, None, params.chunk)
        render_seconds = (time.perf_counter() - started) / max(len(heldout), 1)
        points.append({"mark": snap["mark"], "seconds": round(snap["seconds"], 2), "step": snap["step"],
                       "psnr": result["psnr"], "ssim": result["ssim"]})
        print(f"  {spec['name']}: {snap['seconds']:.0f} s, step {snap['step']}: PSNR {result['psnr']:.2f} dB", flush=True)
    camera = loader.world.camera_of(heldout[0]) if heldout else None
    return {
        "name": spec["name"],
        "group": spec["group"],
        "note": spec.get("note", ""),
        "train": spec["overrides"].get("train", {}),
        "device": torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU ({torch.get_num_threads()} threads)",
        "steps": trainer.step,
        "steps_planned": config.steps,
        "finished": finished,
        "train_seconds": round(trainer.elapsed, 2),
        "samples_per_s": round(samples_per_s),
        "samples_per_ray": round(samples_per_ray, 2),
        "render_seconds_per_image": None if render_seconds is None else round(render_seconds, 3),
        "image_size": None if camera is None else [camera.width, camera.height],
        "peak_memory_bytes": int(peak),
        "train_images": len(views.train),
        "heldout": len(heldout),
        "decisions": decisions,
        "points": points,
    }


def main() -> None:
    spec = json.loads(Path(sys.argv[1]).read_text())
    result = run(spec)
    Path(sys.argv[2]).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
