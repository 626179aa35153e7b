"""``nerfpipe bench``: what accuracy costs in time, measured on a capture with held-out views.

Runs the pipeline up to ``scene`` once (cached in the run directory like any run), then each configuration
in its own process (``nerfpipe.bench.worker``) for at most ``budget`` seconds of training, and writes
``RUN_DIR/bench/``: ``bench.json`` (every figure), ``bench.md`` (the tables) and ``psnr_time.png``
(held-out PSNR against training time, a line per configuration). ``nerfpipe report`` shows them.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable

from nerfpipe.bench.configs import BenchConfig
from nerfpipe.bench.report import write_outputs
from nerfpipe.pipeline.errors import StageError

log = logging.getLogger("nerfpipe.bench")

CHECKPOINTS = (30.0, 60.0, 120.0, 180.0, 300.0, 600.0)
BENCH_DIR = "bench"


def run_bench(capture: Path, run_dir: Path, configs: list[BenchConfig], budget: float, overrides: dict[str, dict[str, Any]],
              eval_views: int = 0, checkpoints: tuple[float, ...] = CHECKPOINTS, seeds: int = 1,
              on_result: Callable[[dict[str, Any]], None] = lambda r: None) -> Path:
    """Benchmark ``configs`` on ``capture``; returns the ``bench`` folder.

    ``overrides`` apply to every configuration (for example ``ingest.max_size``); train parameters among
    them win over each configuration's own, so ``--set train.steps=3000`` lengthens every schedule.
    Results of earlier configurations already in ``bench.json`` for the same settings are kept, so an
    interrupted benchmark resumes with the configuration it was running.

    ``seeds`` > 1 trains each configuration that many times, with ``train.seed`` counting up from its own
    (0 unless set), so the tables can tell a difference between configurations from the spread of one
    configuration over seeds. The first seed's run is the run of ``seeds=1``: it is kept too.
    """
    from nerfpipe import Pipeline, default_stages

    shared = {k: dict(v) for k, v in overrides.items() if k != "train"}
    Pipeline(default_stages(), capture, run_dir, "", shared).run(until="scene")  # makes run_dir nerfpipe's first
    out = run_dir / BENCH_DIR
    out.mkdir(parents=True, exist_ok=True)
    previous = _load(out / "bench.json")
    results: list[dict[str, Any]] = []
    marks = [m for m in checkpoints if m <= budget]
    if budget not in marks:
        marks.append(budget)
    first_seed = int(overrides.get("train", {}).get("seed", 0))
    for config, n in ((c, n) for c in configs for n in range(seeds)):
        seed = first_seed + n
        train = {**config.overrides(), **overrides.get("train", {}), **({"seed": str(seed)} if n else {})}
        spec = {"name": config.name, "group": config.group, "note": config.note, "capture": str(capture.resolve()),
                "run_dir": str(run_dir.resolve()), "overrides": {**shared, "train": train}, "budget": budget,
                "checkpoints": marks, "eval_views": eval_views}
        label = config.name + (f" (seed {seed})" if seeds > 1 else "")
        kept = next((r for r in previous.get("results", []) if r.get("spec") == _comparable(spec)), None)
        if kept is not None:
            log.info("bench: %s: kept from the last benchmark", label)
            results.append({**kept, "seed": seed})
            continue
        log.info("bench: %s (%s) for up to %.0f s of training", label, config.note, budget)
        result = _run_worker(spec)
        result["seed"] = seed
        result["spec"] = _comparable(spec)
        results.append(result)
        on_result(result)
        write_outputs(out, {"capture": str(capture), "budget": budget, "checkpoints": marks, "results": results})
    write_outputs(out, {"capture": str(capture), "budget": budget, "checkpoints": marks, "results": results})
    return out


def _comparable(spec: dict[str, Any]) -> dict[str, Any]:
    return json.loads(json.dumps({k: v for k, v in spec.items() if k not in ("run_dir", "note")}))


def _load(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def _run_worker(spec: dict[str, Any]) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        spec_path, out_path = Path(tmp) / "spec.json", Path(tmp) / "result.json"
        spec_path.write_text(json.dumps(spec))
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        done = subprocess.run([sys.executable, "-m", "nerfpipe.bench.worker", str(spec_path), str(out_path)], env=env)
        if done.returncode != 0 or not out_path.exists():
            raise StageError(f"bench: configuration {spec['name']!r} failed (exit code {done.returncode}); "
                             "its output is above")
        return json.loads(out_path.read_text())
