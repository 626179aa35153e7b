"""Batch benchmark: the wall time of one batch of captures with the local executor and with Ray.

Run by hand from the repository root, with Ray installed (`pip install -e ".[ray]"`):

    python scripts/bench_batch.py [--captures 4] [--preset draft] [--set train.steps=300]

The captures are windows of 8 consecutive views of the bundled temple ring (its calibration imported, no
SfM), so the benchmark needs nothing outside the repository. Each executor runs the same batch into a
fresh runs root: the local executor one stage at a time in this process (`nerfpipe batch`'s default),
Ray with as many CPUs as this machine has, one per task, so stages of different captures overlap. It
prints the wall times, Ray's start-up, and the mean time of each stage, from the manifests.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

from nerfpipe.pipeline import parse_assignments
from nerfpipe.pipeline.batch import Batch, BatchSettings, find_captures
from nerfpipe.pipeline.executors import LocalExecutor, RayExecutor

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "templeSparseRing"


def make_captures(root: Path, count: int, views: int = 8) -> None:
    """``count`` captures of ``views`` consecutive temple views each, starting 4 views apart round the ring."""
    rows = (SAMPLE / "templeSR_par.txt").read_text().splitlines()[1:]
    for c in range(count):
        picked = [(4 * c + k) % len(rows) for k in range(views)]
        folder = root / f"temple{c:02d}"
        folder.mkdir(parents=True)
        for i in picked:
            shutil.copy2(SAMPLE / rows[i].split()[0], folder)
        (folder / "templeSR_par.txt").write_text("\n".join([str(views), *(rows[i] for i in picked)]) + "\n")


def stage_seconds(runs: Path) -> dict[str, list[float]]:
    """Each stage's running time in every run directory under ``runs``, from its manifest."""
    seconds: dict[str, list[float]] = {}
    for manifest in sorted(runs.glob("*/stages/*/*/manifest.json")):
        doc = json.loads(manifest.read_text())
        seconds.setdefault(doc["stage"], []).append(doc["timings"]["seconds"])
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", type=int, default=4)
    parser.add_argument("--preset", default="draft")
    parser.add_argument("--set", action="append", default=["ingest.max_size=160"], dest="sets")
    args = parser.parse_args()
    settings = BatchSettings(preset=args.preset, overrides=parse_assignments(args.sets))
    cpus = len(os.sched_getaffinity(0))
    print(f"machine: {cpus} CPU cores, Python {sys.version.split()[0]}; {args.captures} captures of 8 temple views, "
          f"preset {args.preset}, {' '.join(args.sets)}\n")
    with tempfile.TemporaryDirectory() as tmp:
        make_captures(Path(tmp) / "captures", args.captures)
        sources = find_captures(Path(tmp) / "captures")
        rows = []
        started = time.perf_counter()
        with LocalExecutor() as local:
            states = Batch(sources, Path(tmp) / "local", local, settings).run()
        rows.append(("local, 1 process", time.perf_counter() - started, 0.0, states))
        started = time.perf_counter()
        with RayExecutor(num_cpus=cpus) as ray_executor:
            ready = time.perf_counter()
            states = Batch(sources, Path(tmp) / "ray", ray_executor, settings).run()
            finished = time.perf_counter()
        rows.append((f"Ray, {cpus} CPUs", finished - started, ready - started, states))

        print("| executor | batch wall time | of which Ray start-up | captures done |")
        print("|---|---|---|---|")
        for name, wall, startup, states in rows:
            done = sum(c.state == "done" for c in states)
            print(f"| {name} | {wall:.1f} s | {startup:.1f} s | {done} of {len(states)} |")
        print("\nmean seconds of each stage per capture (local / Ray; under Ray each task has 1 CPU thread):\n")
        local_s, ray_s = stage_seconds(Path(tmp) / "local"), stage_seconds(Path(tmp) / "ray")
        print("| stage | local | Ray |")
        print("|---|---|---|")
        for stage in local_s:
            print(f"| {stage} | {statistics.mean(local_s[stage]):.2f} s | {statistics.mean(ray_s.get(stage, [0])):.2f} s |")
        print(f"| total | {sum(map(statistics.mean, local_s.values())):.1f} s | "
              f"{sum(statistics.mean(v) for v in ray_s.values()):.1f} s |")


if __name__ == "__main__":
    main()
