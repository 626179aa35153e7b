"""Where a training step's time goes: torch.profiler's table of operators over a window of steps.

Run by hand from the repository root, with ../shared beside it:

    python scripts/profile_train.py --capture ../shared/data/colmap_beer_yhuoyuh --size 1600
    python scripts/profile_train.py --capture ../shared/data/middlebury_templeSparseRing --size 640 --steps 100

or under py-spy, by Python function (``--profiler none`` runs the window in ``profiled_window``, which
``scripts/pyspy_table.py`` roots its table at):

    py-spy record -r 200 -f raw -o beer.raw -- python scripts/profile_train.py --profiler none --steps 200
    python scripts/pyspy_table.py beer.raw --root profiled_window

It trains the train stage's model (as ``nerfpipe run`` builds it) for ``--warm-up`` steps, so the occupancy grid
has learned where the scene is, then profiles ``--steps`` more: the operators by their own CPU time, and the
steps, rays and samples a second of the profiled window (slowed a little by the profiler itself).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BEER = REPO.parent / "shared" / "data" / "colmap_beer_yhuoyuh"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--capture", type=Path, default=BEER)
    parser.add_argument("--size", type=int, default=1600, help="ingest.max_size")
    parser.add_argument("--warm-up", type=int, default=300, help="training steps before the profile")
    parser.add_argument("--steps", type=int, default=60, help="training steps profiled")
    parser.add_argument("--rows", type=int, default=25, help="operators listed")
    parser.add_argument("--profiler", choices=("torch", "none"), default="torch",
                        help="torch: torch.profiler's operator table; none: no profiler (run under py-spy)")
    parser.add_argument("--set", dest="sets", action="append", default=[], help="stage.param=value, as for run")
    parser.add_argument("--out", type=Path, default=None, help="run directory for the stages up to scene")
    args = parser.parse_args()

    from nerfpipe.nerf.cpu import flush_denormals, keep_freed_memory

    keep_freed_memory()
    with flush_denormals():
        profile(args)


def profile(args: argparse.Namespace) -> None:
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    from nerfpipe.bench.worker import prepare_capture
    from nerfpipe.nerf.train.trainer import Trainer

    run_dir = args.out or Path(tempfile.mkdtemp(prefix="nerfpipe-profile-"))
    setup = prepare_capture(args.capture, run_dir, args.size, args.sets, 3600)
    with tempfile.TemporaryDirectory() as scratch:
        trainer = Trainer(setup.model, setup.loader.pixel_set(setup.views.train), setup.config, Path(scratch),
                          setup.device, density_noise=setup.density_noise)
        trainer.run(after_step=lambda t: t.step >= args.warm_up)
        step0, elapsed0, rays0, samples0 = trainer.step, trainer.elapsed, trainer.total_rays, trainer.total_samples
        if args.profiler == "torch":
            with torch_profile(activities=[ProfilerActivity.CPU]) as prof:
                profiled_window(trainer, step0 + args.steps)
            print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=args.rows))
        else:
            profiled_window(trainer, step0 + args.steps)
    seconds = max(trainer.elapsed - elapsed0, 1e-9)
    rays, samples = trainer.total_rays - rays0, trainer.total_samples - samples0
    print(f"{args.capture.name}: {(trainer.step - step0) / seconds:.1f} steps/s, {rays / seconds:.0f} rays/s, "
          f"{samples / seconds:.0f} samples/s, {samples / max(rays, 1):.2f} samples a ray, "
          f"{trainer.model.sampler.stats()}")


def profiled_window(trainer, last: int) -> None:
    """Train until step ``last``: the window a profile looks at."""
    trainer.run(after_step=lambda t: t.step >= last)


if __name__ == "__main__":
    main()
