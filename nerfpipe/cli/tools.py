"""The commands around a run: ``bench``, ``batch``, ``stages``, ``export`` and ``clean`` (``main`` registers
them, with their examples). Parsing and formatting only."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import List, Optional

import typer

from nerfpipe.cli.config import one_preset
from nerfpipe.cli.console import (
    batch_progress,
    bench_line,
    escape,
    out_console,
    print_batch,
    setup_logging,
    user_errors,
)
from nerfpipe.cli.options import DebugOption, PresetOption, SetOption, UntilOption
from nerfpipe.pipeline import Pipeline, parse_assignments
from nerfpipe.pipeline.lock import RunLock
from nerfpipe.stages import default_stages


def bench(
    capture: Path = typer.Argument(..., help="Capture with held-out views (a val/test split, else every 8th image)."),
    out: Path = typer.Option(..., "--out", "-o", help="Run directory; the results go to OUT/bench/."),
    configs: List[str] = typer.Option(["presets"], "--config", "-c",
                                      help="A configuration, or a group: presets, ablations, all (repeatable)."),
    budget: float = typer.Option(300.0, "--budget", help="Seconds of training per configuration, at most."),
    size: Optional[int] = typer.Option(None, "--size", help="Longest image side (sets ingest.max_size)."),
    eval_views: int = typer.Option(0, "--eval-views", help="Evaluate this many held-out views, evenly spaced (0: all)."),
    checkpoints: str = typer.Option("30,60,120,180,300,600", "--checkpoints",
                                    help="Training times in seconds at which to evaluate, comma-separated."),
    seeds: int = typer.Option(1, "--seeds", help="Train each configuration this many times, seeds counting up; "
                              "the tables give mean ± standard deviation."),
    set_: List[str] = SetOption,
    debug: bool = DebugOption,
) -> None:
    """Train each configuration for a time budget; held-out PSNR/SSIM at 30 s, 1, 2, 3, 5, 10 min, speed, memory."""
    setup_logging(debug)
    from nerfpipe.bench.configs import CONFIGS, GROUPS, select
    from nerfpipe.bench.run import run_bench

    with user_errors(debug):
        try:
            chosen = select(configs)
        except KeyError as err:
            raise typer.BadParameter(f"unknown configuration {err.args[0]!r}; choose from {', '.join([*GROUPS, 'all', *CONFIGS])}",
                                     param_hint="--config") from None
        if budget <= 0:
            raise typer.BadParameter(f"must be > 0, got {budget}", param_hint="--budget")
        try:
            marks = tuple(sorted(float(m) for m in checkpoints.split(",") if m.strip()))
        except ValueError:
            raise typer.BadParameter(f"expected seconds separated by commas, got {checkpoints!r}", param_hint="--checkpoints") from None
        if not marks or marks[0] <= 0:
            raise typer.BadParameter(f"expected positive seconds, got {checkpoints!r}", param_hint="--checkpoints")
        if seeds < 1:
            raise typer.BadParameter(f"must be at least 1, got {seeds}", param_hint="--seeds")
        overrides = parse_assignments(set_)
        if size is not None:
            overrides.setdefault("ingest", {})["max_size"] = str(size)
        overrides.setdefault("train", {}).setdefault("eval_stride", "4")
        folder = run_bench(capture, out, chosen, budget, overrides, eval_views, marks, seeds,
                           on_result=lambda r: out_console.print(bench_line(r, seeds > 1), highlight=False))
        from nerfpipe.report import write_report

        page = write_report(out)
    out_console.print((folder / "bench.md").read_text(), highlight=False, soft_wrap=True)
    out_console.print(f"bench: {escape(str(folder))}\nreport: {escape(str(page))}", highlight=False, soft_wrap=True)


def batch(
    captures_root: Path = typer.Argument(..., help="Folder with one folder of photos per capture."),
    out: Path = typer.Option(..., "--out", "-o", help="Runs root: one run directory per capture, OUT/<capture>."),
    executor: str = typer.Option("local", "--executor", "-e", help="local (this machine) or ray (a Ray cluster)."),
    address: Optional[str] = typer.Option(None, "--address", help="Ray cluster address, e.g. 10.0.0.1:6379 or auto "
                                          "\\[default: start Ray on this machine]."),
    max_parallel: int = typer.Option(0, "--max-parallel", "-j", help="Captures in progress at once \\[default: local 1, "
                                     "ray as many as the cluster's resources run]."),
    max_retries: int = typer.Option(2, "--max-retries", help="Restarts of a stage whose worker or node died."),
    presets: List[str] = PresetOption,
    set_: List[str] = SetOption,
    until: Optional[str] = UntilOption,
    debug: bool = DebugOption,
) -> None:
    """Run every capture folder inside CAPTURES_ROOT, each stage a task of the executor; same cache as `run`."""
    setup_logging(debug)
    if not debug:
        logging.getLogger("nerfpipe").handlers[0].setLevel(logging.ERROR)  # each capture's log file has the rest
    from nerfpipe.pipeline.batch import Batch, BatchSettings, find_captures
    from nerfpipe.pipeline import InputError
    from nerfpipe.pipeline.executors import LocalExecutor, RayExecutor

    with user_errors(debug):
        if executor not in ("local", "ray"):
            raise typer.BadParameter(f"expected local or ray, got {executor!r}", param_hint="--executor")
        if max_parallel < 0:
            raise typer.BadParameter(f"must be 0 or more, got {max_parallel}", param_hint="--max-parallel")
        if address is not None and executor != "ray":
            raise typer.BadParameter("only with --executor ray", param_hint="--address")
        if out.exists() and not out.is_dir():
            raise InputError(out, "is a file, not a folder", "pass --out a folder for the run directories")
        root, runs = captures_root.resolve(), out.resolve()
        if runs == root or root in runs.parents:
            raise typer.BadParameter(f"{out} lies inside the captures folder {captures_root}, whose every folder is "
                                     "taken for a capture; choose a folder outside it", param_hint="--out")
        sources = find_captures(captures_root)
        settings = BatchSettings(preset=one_preset(presets), overrides=parse_assignments(set_), until=until, max_parallel=max_parallel)
        runner = LocalExecutor(max_parallel or 1, max_retries) if executor == "local" else RayExecutor(address, max_retries)
        with runner, batch_progress(len(sources)) as on_change:
            states = Batch(sources, out, runner, settings, on_change).run()
    failed = print_batch(states, out, executor)
    if failed:
        raise typer.Exit(1)


def stages(
    names: List[str] = typer.Argument(None, metavar="[STAGE]...", help="Only these stages (default: all)."),
    as_json: bool = typer.Option(False, "--json", help="Machine-readable: one JSON object, stage name -> its "
                                 "version, summary, inputs, outputs, parameters and presets."),
) -> None:
    """The stage graph, with each stage's parameters, defaults and presets."""
    import json

    from nerfpipe.cli.reference import print_reference, stage_reference
    from nerfpipe.pipeline import Dag, ParamError

    dag = Dag(default_stages())
    with user_errors(False):
        for name in names or []:
            if name not in dag.stages:
                raise ParamError(f"unknown stage {name!r}; stages are: {', '.join(dag.order)}")
    chosen = [n for n in dag.order if not names or n in names]
    reference = stage_reference(dag, chosen)
    if as_json:
        print(json.dumps(reference, indent=1))
        return
    print_reference(reference, dag.order if not names else None)


def export(
    run_dir: Path = typer.Argument(..., help="Run directory of an earlier `nerfpipe run`."),
    to: Path = typer.Option(..., "--to", help="Folder to copy the exports into (made if missing)."),
    debug: bool = DebugOption,
) -> None:
    """Copy a run's exports (mesh, points, videos, depth maps, transforms.json, COLMAP cameras) to a folder."""
    setup_logging(debug)
    from nerfpipe.cli.exports import refresh_exports
    from nerfpipe.export.bundle import copy_exports

    with user_errors(debug):
        exported = refresh_exports(Pipeline.from_run_dir(default_stages(), run_dir))
        copied = copy_exports(exported.folder, to, run_dir)
    out_console.print(f"copied {', '.join(exported.names)} ({copied / 1e6:.1f} MB) to {escape(str(to))}"
                      + (f"; not made by this run: {', '.join(exported.missing)}" if exported.missing else ""),
                      highlight=False, soft_wrap=True)


def clean(
    run_dir: Path = typer.Argument(..., help="Run directory to prune."),
    debug: bool = DebugOption,
) -> None:
    """Delete cached results other than each stage's latest, and unfinished work folders."""
    setup_logging(debug)
    from nerfpipe.pipeline import ArtifactStore, InputError

    with user_errors(debug):
        if not (run_dir / "run.json").is_file():
            raise InputError(run_dir, "is not a nerfpipe run directory (no run.json)", "pass the --out folder of a run")
        with RunLock(run_dir):
            removed, freed = ArtifactStore(run_dir).clean()
    out_console.print(f"removed {removed} folders, freed {freed / 1e6:.1f} MB")
