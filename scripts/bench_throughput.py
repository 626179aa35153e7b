"""Throughput of one model three ways: training, held-out evaluation and the render stage, in rays a second.

Run by hand from the repository root, with ../shared beside it:

    python scripts/bench_throughput.py                                   # lego at 100 px, the default preset
    python scripts/bench_throughput.py --capture samples/templeSparseRing --size 640
    python scripts/bench_throughput.py --set train.field.max_resolution=128

It trains the train stage's model (as ``nerfpipe run`` builds it) for ``--seconds`` of training, then measures,
on that same model: training for ``--window`` more seconds (rays and samples a second: forward, backward and
the optimizer step), evaluation of the held-out views (``nerf.evaluation.evaluate``, the train stage's chunk),
and the render stage's orbit (``stages.render.render_frames`` at the render stage's size and chunk), after one
small render that warms up what a process does once (compiling rendering's functions, ``nerfpipe.nerf.kernels``;
its time is printed apart). A model
that has trained a while is measured, because empty-space skipping depends on what the occupancy grid learned.
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LEGO = REPO.parent / "shared" / "data" / "nerf_synthetic_lego_400"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--capture", type=Path, default=LEGO)
    parser.add_argument("--size", type=int, default=100, help="ingest.max_size")
    parser.add_argument("--seconds", type=float, default=60.0, help="training before the measurements")
    parser.add_argument("--window", type=float, default=15.0, help="seconds of training measured")
    parser.add_argument("--frames", type=int, default=8, help="render-stage frames measured")
    parser.add_argument("--eval-views", type=int, default=0, help="held-out views evaluated (0: all)")
    parser.add_argument("--preset", default="fast", help="the train preset the settings start from (gpu: a CUDA device's)")
    parser.add_argument("--set", dest="sets", action="append", default=[], help="stage.param=value, as for run")
    parser.add_argument("--out", type=Path, default=None, help="run directory for the stages up to scene")
    args = parser.parse_args()

    from nerfpipe.nerf.cpu import flush_denormals, keep_freed_memory

    keep_freed_memory()
    with flush_denormals():
        measure(args)


def measure(args: argparse.Namespace) -> None:
    import numpy as np

    from nerfpipe.bench.worker import prepare_capture
    from nerfpipe.export.paths import path_for_scene
    from nerfpipe.nerf.train.evaluation import evaluate
    from nerfpipe.nerf.train.trainer import Trainer
    from nerfpipe.pipeline.stage import StageContext
    from nerfpipe.stages.render import RenderParams, render_frames, render_size

    run_dir = args.out or Path(tempfile.mkdtemp(prefix="nerfpipe-throughput-"))
    setup = prepare_capture(args.capture, run_dir, args.size, args.sets, args.seconds + args.window + 60, args.preset)
    model = setup.model
    with tempfile.TemporaryDirectory() as scratch:
        trainer = Trainer(model, setup.loader.pixel_set(setup.views.train), setup.config, Path(scratch), setup.device,
                          density_noise=setup.density_noise)
        trainer.run(after_step=lambda t: t.elapsed >= args.seconds)
        step0, elapsed0, rays0, samples0 = trainer.step, trainer.elapsed, trainer.total_rays, trainer.total_samples
        trainer.run(after_step=lambda t: t.elapsed >= elapsed0 + args.window)
        seconds = trainer.elapsed - elapsed0
        train_rays = (trainer.total_rays - rays0) / seconds
        train_samples = (trainer.total_samples - samples0) / seconds
        steps = trainer.step - step0

    heldout = setup.heldout[:args.eval_views] if args.eval_views > 0 else setup.heldout
    # the first render of a process compiles rendering's functions (nerfpipe.nerf.kernels), once: timed apart
    started = time.perf_counter()
    evaluate(model, setup.loader, heldout[:1], None, setup.chunk, scale=0.1)
    warm_up = time.perf_counter() - started
    started = time.perf_counter()
    result = evaluate(model, setup.loader, heldout, None, setup.chunk)
    eval_seconds = time.perf_counter() - started
    eval_rays = sum(setup.loader.world.camera_of(f).width * setup.loader.world.camera_of(f).height for f in heldout)

    bounds, layout = setup.loader.bounds, setup.loader.scene.layout.value
    render = RenderParams()
    world = setup.loader.world
    c2ws = np.array([f.c2w for f in world.frames])
    lo, hi = bounds.box()
    poses, _ = path_for_scene(layout, c2ws, bounds.near, bounds.far, (lo + hi) / 2.0, args.frames)
    camera = world.camera_of(world.frames[0])
    width, height = render_size(camera, render.scale, render.max_side, render.short_side)
    scaled = camera.scaled(width / camera.width, height / camera.height)
    ctx = StageContext(log=logging.getLogger("bench"))
    with tempfile.TemporaryDirectory() as frames:
        started = time.perf_counter()
        render_frames(model, poses, [scaled] * len(poses), [(bounds.near, bounds.far)] * len(poses), Path(frames),
                      render.chunk, ctx)
        render_seconds = time.perf_counter() - started
    render_rays = len(poses) * width * height

    print(f"{args.capture.name} at {args.size} px, {setup.device}, model after {elapsed0:.0f} s ({step0} steps) of "
          f"training; held-out PSNR {result['psnr']:.2f} dB")
    print("| pass | rays/s | notes |")
    print("|---|---:|---|")
    print(f"| train (forward, backward, Adam) | {train_rays:,.0f} | {steps} steps in {seconds:.1f} s, "
          f"{train_samples:,.0f} samples/s, {train_samples / train_rays:.1f} samples a ray |")
    print(f"| evaluate ({len(heldout)} held-out views, chunk {setup.chunk}) | {eval_rays / eval_seconds:,.0f} | "
          f"{eval_rays:,} rays in {eval_seconds:.1f} s |")
    print(f"| render stage ({len(poses)} frames of {width}x{height}, chunk {render.chunk}, PNGs written) | "
          f"{render_rays / render_seconds:,.0f} | {render_rays:,} rays in {render_seconds:.1f} s |")
    print(f"| first render of the process (one held-out view at a tenth of its side; compiles, NERFPIPE_COMPILE) | | "
          f"{warm_up:.1f} s |")


if __name__ == "__main__":
    main()
