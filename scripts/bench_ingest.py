"""Ingest benchmark: the cost of a no-op rerun, and ingest throughput in megapixels per second.

Run by hand from the repository root (with ../shared beside it for the larger captures):

    python scripts/bench_ingest.py

It prints a Markdown table; copy its figures into the README's results table.
"""

from __future__ import annotations

import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from nerfpipe import Pipeline, default_stages

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "samples" / "templeSparseRing"
SHARED = REPO.parent / "shared" / "data"


def noop_rerun_seconds(run_dir: Path, repeats: int = 7) -> list[float]:
    """Wall time of `nerfpipe run SAMPLE --until ingest` when ingest is already fresh, interpreter start included."""
    exe = shutil.which("nerfpipe") or sys.executable
    cmd = [exe] if exe.endswith("nerfpipe") else [exe, "-m", "nerfpipe"]
    cmd += ["run", str(SAMPLE), "--out", str(run_dir), "--until", "ingest"]
    subprocess.run(cmd, check=True, capture_output=True)  # the first run computes ingest
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = subprocess.run(cmd, check=True, capture_output=True, text=True)
        times.append(time.perf_counter() - start)
        assert "fresh, nothing to do" in result.stderr, result.stderr
    return times


def ingest_throughput(capture: Path, run_dir: Path, repeats: int = 3, **overrides: str) -> tuple[int, float, float]:
    """(images, source megapixels, best ingest seconds) over ``repeats`` forced runs, full size output."""
    pipe = Pipeline(default_stages(), capture, run_dir, overrides={"ingest": {"max_size": "0", **overrides}})
    best = float("inf")
    summary: dict = {}
    for _ in range(repeats):
        outcome = pipe.run(until="ingest", force=["ingest"])[0]
        best = min(best, outcome.seconds)
        summary = dict(outcome.summary)
    return summary["images"], summary["source_megapixels"], best


def main() -> None:
    print(f"machine: {os.cpu_count()} CPU cores, Python {sys.version.split()[0]}\n")
    with tempfile.TemporaryDirectory() as tmp:
        times = noop_rerun_seconds(Path(tmp) / "noop")
        print(f"no-op `nerfpipe run {SAMPLE.relative_to(REPO)} --until ingest`: median {statistics.median(times):.2f} s, "
              f"min {min(times):.2f} s over {len(times)} runs (target <= 2 s)\n")

        captures = [("bundled temple (PNG, 640x480)", SAMPLE, {})]
        optional = [
            ("lego train (RGBA PNG, 400x400)", SHARED / "nerf_synthetic_lego_400" / "train", {}),
            ("cup (JPEG, 800x600)", SHARED / "llff_cup_kwrous" / "images", {}),
            ("beer (JPEG, 720x1280)", SHARED / "colmap_beer_yhuoyuh" / "images", {}),
        ]
        captures += [c for c in optional if c[1].is_dir()]
        raw = SHARED / "raw_samples" / "blackmagic.dng"
        if raw.is_file():
            raw_dir = Path(tmp) / "raw"
            raw_dir.mkdir()
            shutil.copy(raw, raw_dir)
            captures.append(("Blackmagic DNG (RAW, 4128x2176, 16-bit out)", raw_dir, {}))

        print("| capture | images | megapixels | ingest s | MP/s |")
        print("|---|---:|---:|---:|---:|")
        for label, folder, overrides in captures:
            images, mp, seconds = ingest_throughput(folder, Path(tmp) / label.split()[0], **overrides)
            print(f"| {label} | {images} | {mp:.1f} | {seconds:.2f} | {mp / seconds:.1f} |")


if __name__ == "__main__":
    main()
