"""Per-image appearance and camera refinement, each switched on and off: four trainings of one capture with
the same steps, and a table of their held-out PSNR.

Run by hand from the repository root:

    python scripts/bench_per_image.py ../shared/data/colmap_beer_yhuoyuh /tmp/beer4 \\
        --set ingest.max_size=160 --set train.steps=1000

The four runs share one run directory, so every stage before train runs once (the cache keeps each
training under its own parameters' hash). Prints, per run: the scene's exposure decision, held-out PSNR / SSIM (with
appearance on, NeRF-W's protocol: gains fitted on each held-out photo's left half, scored on its right half;
the whole view at the photos' mean exposure beside it), how far the cameras moved, and the training time.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from nerfpipe import default_stages
from nerfpipe.pipeline import Pipeline, parse_assignments


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--set", dest="assignments", action="append", default=[], help="stage.param=value, as nerfpipe run")
    parser.add_argument("--preset", default=None)
    args = parser.parse_args()
    base = parse_assignments(args.assignments)
    rows = []
    for appearance in ("off", "on"):
        for refine in ("off", "on"):
            overrides = {**base, "train": {**base.get("train", {}), "per_image.appearance": appearance,
                                           "per_image.refine_poses": refine}}
            outcomes = Pipeline(default_stages(), args.capture, args.out, args.preset, overrides).run(until="train")
            paths = {o.name: o.path for o in outcomes}
            m = json.loads((paths["train"] / "metrics.json").read_text())
            exposure = json.loads((paths["scene"] / "scene.json").read_text())["exposure_varies"]
            moved = m.get("pose_refinement") or {}
            rows.append((appearance, refine, m["psnr"], m["ssim"], m.get("psnr_mean_appearance"),
                         moved.get("median_rotation_deg"), moved.get("median_translation_share"), m["train_seconds"],
                         m["eval_seconds"] if "eval_seconds" in m else None))
            print(f"scene: exposure varies {exposure['value']}: {exposure['evidence']}", flush=True)
            print(rows[-1], flush=True)
    print("| appearance | camera refinement | held-out PSNR / SSIM | whole views at the mean exposure | cameras moved "
          "(median) | training |")
    print("|---|---|---:|---:|---:|---:|")
    for appearance, refine, psnr, ssim, mean, rotation, share, seconds, _ in rows:
        mean_text = f"{mean:.2f} dB" if mean is not None else "-"
        moved_text = f"{rotation:.2f} deg, {100 * share:.2f} %" if rotation is not None else "-"
        print(f"| {appearance} | {refine} | {psnr:.2f} dB / {ssim:.3f} | {mean_text} | {moved_text} | {seconds:.0f} s |")


if __name__ == "__main__":
    main()
