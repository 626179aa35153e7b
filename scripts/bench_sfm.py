"""SfM benchmark: wall time and registered fraction on real captures (poses in the captures ignored).

Run by hand from the repository root, with ../shared beside it:

    python scripts/bench_sfm.py [--only temple|cup|cup_small]

Prints one Markdown row per capture; the figures go into the README's results table.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from nerfpipe import NerfpipeError, Pipeline
from nerfpipe.stages import IngestStage, SfmStage

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
CAPTURES = {
    "temple": ("Middlebury temple, 16 PNG 640x480", REPO / "samples" / "templeSparseRing"),
    "cup": ("LLFF cup, 77 JPEG 800x600", SHARED / "llff_cup_kwrous"),
    "cup_small": ("LLFF cup images_4, 77 JPEG 200x150 (hard case)", SHARED / "llff_cup_kwrous" / "images_4"),
}


def bench(label: str, capture: Path, run_dir: Path) -> str:
    pipe = Pipeline([IngestStage(), SfmStage()], capture, run_dir, overrides={"sfm": {"poses": "sfm"}})
    pipe.run(until="ingest")
    start = time.perf_counter()
    try:
        sfm = pipe.run(until="sfm")[-1]
    except NerfpipeError as err:
        return f"| {label} | failed: {err} | {time.perf_counter() - start:.1f} s | | |"
    seconds = time.perf_counter() - start
    s = sfm.summary
    return (f"| {label} | {s['registered']}/{s['total']} ({100 * s['registered'] / s['total']:.0f} %) | {seconds:.1f} s "
            f"| {s['mean_reprojection_error_px']:.3f} px | {s['matcher']}{', relaxed retry' if s['relaxed_retry_used'] else ''} |")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--only", choices=sorted(CAPTURES))
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} CPU cores, Python {sys.version.split()[0]}\n")
    print("| capture | registered | SfM wall time | mean reprojection error | matching |")
    print("|---|---:|---:|---:|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for key, (label, capture) in CAPTURES.items():
            if args.only and key != args.only:
                continue
            if capture.is_dir():
                print(bench(label, capture, Path(tmp) / key), flush=True)


if __name__ == "__main__":
    main()
