"""What verifying the cache costs: the cheap check every `run` and `status` makes, and `status --verify`.

Run by hand from the repository root on a finished run directory, e.g. after
`nerfpipe run samples/templeSparseRing --out runs/templeSparseRing`:

    python scripts/bench_cache_check.py runs/templeSparseRing

It prints a Markdown table; copy its figures into the README's "What can go wrong" section.
"""

from __future__ import annotations

import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from nerfpipe import Pipeline, default_stages


def seconds(action, repeats: int) -> float:
    """Median wall time of ``action()`` over ``repeats`` calls (the page cache warm after the first)."""
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        action()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def main(run_dir: Path) -> None:
    pipe = Pipeline.from_run_dir(default_stages(), run_dir)
    statuses = pipe.status()
    fresh = [s for s in statuses if s.state == "fresh"]
    if len(fresh) != len(statuses):
        sys.exit(f"{run_dir}: not every stage is fresh ({', '.join(s.name for s in statuses if s.state != 'fresh')})")
    outputs = [meta for s in fresh for meta in s.result.manifest["outputs"].values()]
    megabytes = sum(meta["size"] for meta in outputs) / 1e6

    cheap = seconds(lambda: Pipeline.from_run_dir(default_stages(), run_dir).status(), 7)
    full = seconds(lambda: Pipeline.from_run_dir(default_stages(), run_dir).status(verify=True), 3)
    check_cheap = seconds(lambda: [pipe.store.inspect(s.name, s.key) for s in fresh], 7)
    check_full = seconds(lambda: [pipe.store.inspect(s.name, s.key, full=True) for s in fresh], 3)
    exe = shutil.which("nerfpipe") or sys.executable
    prefix = [exe] if exe.endswith("nerfpipe") else [exe, "-m", "nerfpipe"]

    def cli(*extra: str) -> None:
        subprocess.run([*prefix, "status", str(run_dir), *extra], check=True, capture_output=True)

    cli_cheap, cli_full = seconds(cli, 5), seconds(lambda: cli("--verify"), 3)
    print(f"{len(fresh)} stages, {len(outputs)} output files, {megabytes:.1f} MB\n")
    print("| check | the check alone | `Pipeline.status()` | `nerfpipe status` (interpreter start included) |")
    print("|---|---:|---:|---:|")
    print(f"| sizes and times (every `run` and `status`) | {check_cheap * 1000:.1f} ms | {cheap * 1000:.0f} ms "
          f"| {cli_cheap:.2f} s |")
    print(f"| sha256 of every output (`status --verify`) | {check_full * 1000:.0f} ms | {full * 1000:.0f} ms "
          f"| {cli_full:.2f} s |")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(Path(sys.argv[1]))
