"""Settings compared at equal training time: held-out PSNR and SSIM at half the photos' side, rays a second.

Run by hand from the repository root, with ../shared beside it, one setting per run:

    python scripts/bench_equal_time.py --name default
    python scripts/bench_equal_time.py --name distortion --set train.optim.distortion=0.002
    python scripts/bench_equal_time.py --capture ../shared/data/llff_cup_kwrous --name hash --set train.field.kind=hash

It trains the train stage's model for ``--seconds`` of training (the learning rate decaying over that time),
scores every held-out view at half its side (the train stage's default), writes the renders beside the photos
into ``--out``/NAME_eval, and appends one JSON line to ``--out``/results.jsonl: steps, rays a second, samples a
ray, PSNR, SSIM, the seconds the evaluation took and the sampler's statistics.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BEER = REPO.parent / "shared" / "data" / "colmap_beer_yhuoyuh"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--capture", type=Path, default=BEER)
    parser.add_argument("--name", required=True, help="what the setting is called in the results")
    parser.add_argument("--size", type=int, default=1600, help="ingest.max_size")
    parser.add_argument("--seconds", type=float, default=120.0, help="seconds of training")
    parser.add_argument("--set", dest="sets", action="append", default=[], help="stage.param=value, as for run")
    parser.add_argument("--out", type=Path, default=Path("runs/equal_time"), help="results, renders and the run "
                                                                                  "directory for the stages up to scene")
    args = parser.parse_args()

    from nerfpipe.nerf.cpu import flush_denormals, keep_freed_memory

    keep_freed_memory()
    with flush_denormals():
        compare(args)


def compare(args: argparse.Namespace) -> None:
    from nerfpipe.bench.worker import prepare_capture, train
    from nerfpipe.nerf.train.evaluation import evaluate

    setup = prepare_capture(args.capture, args.out / f"run_{args.capture.name}", args.size, args.sets, args.seconds)
    setup.config = dataclasses.replace(setup.config, seconds=args.seconds)
    trainer, _, _ = train(setup, args.seconds, [])
    started = time.perf_counter()
    result = evaluate(setup.model, setup.loader, setup.heldout, args.out / f"{args.name}_eval", setup.chunk, scale=0.5)
    line = {"name": args.name, "capture": args.capture.name, "sets": args.sets, "seconds": args.seconds,
            "steps": trainer.step, "rays_per_s": round(trainer.total_rays / max(trainer.elapsed, 1e-9)),
            "samples_per_ray": round(trainer.total_samples / max(trainer.total_rays, 1), 2),
            "psnr": round(result["psnr"], 3), "ssim": round(result["ssim"], 4),
            "eval_seconds": round(time.perf_counter() - started, 1), "views": len(setup.heldout),
            **setup.model.sampler.stats()}
    print(json.dumps(line))
    with open(args.out / "results.jsonl", "a", encoding="utf-8") as results:
        results.write(json.dumps(line) + "\n")


if __name__ == "__main__":
    main()
