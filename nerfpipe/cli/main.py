"""`nerfpipe` commands. Parsing and formatting only: every action is a ``Pipeline`` call."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import List, Optional

import typer
from rich.table import Table

from nerfpipe.cli.config import one_preset
from nerfpipe.cli.console import (
    STATE_STYLE,
    batch_progress,
    bench_line,
    escape,
    out_console,
    print_batch,
    print_outcomes,
    progress_factory,
    serve_web,
    setup_logging,
    user_errors,
)
from nerfpipe.pipeline import ParamError, Pipeline, parse_assignments
from nerfpipe.pipeline.budget import parse_duration
from nerfpipe.pipeline.lock import RunLock
from nerfpipe.pipeline.plan import check_run_dir
from nerfpipe.stages import auto_budget, default_stages

app = typer.Typer(
    name="nerfpipe",
    help="Photos in, a Neural Radiance Field and its exports out. Each stage is cached in the run directory.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)


def _show_version(value: bool) -> None:
    if value:
        from importlib.metadata import version

        out_console.print(f"nerfpipe {version('nerfpipe')}", highlight=False)
        raise typer.Exit()


@app.callback()
def _main(
    version: bool = typer.Option(False, "--version", callback=_show_version, is_eager=True,
                                 help="Print nerfpipe's version and exit."),
) -> None:
    """Photos in, a Neural Radiance Field and its exports out. Each stage is cached in the run directory."""


DebugOption = typer.Option(False, "--debug", help="Show tracebacks and debug logs.")
PresetOption = typer.Option([], "--preset", "-p", help="Named preset applied to every stage that has it (one: presets do "
                            "not combine; use --set on top).")
SetOption = typer.Option([], "--set", "-s", help="Override one parameter: STAGE.PARAM=VALUE (repeatable).")
HostOption = typer.Option("127.0.0.1", "--host", show_default=True, help="The web viewer's address: this machine only by default; "
                          "0.0.0.0 shows the run's photos to anyone on the network who has the printed URL (its token).")


@app.command()
def run(
    photos_dir: Path = typer.Argument(..., help="Folder of photos (or a capture folder with images/), or a video."),
    out: Optional[str] = typer.Option(None, "--out", "-o", help="Run directory \\[default: runs/<photos folder name>]."),
    presets: List[str] = PresetOption,
    set_: List[str] = SetOption,
    until: Optional[str] = typer.Option(None, "--until", help="Run the stages up to and including this one."),
    only: Optional[str] = typer.Option(None, "--only", help="Run only this stage; its upstream must be fresh."),
    force: List[str] = typer.Option([], "--force", help="Rerun this stage even if cached; its downstream reruns only if its outputs change."),
    skip_bad: bool = typer.Option(False, "--skip-bad", help="Skip unreadable or duplicate photos with a warning."),
    view: bool = typer.Option(False, "--view", help="Serve the web viewer while the field trains, to watch it learn "
                              "(stops when training ends)."),
    port: int = typer.Option(8080, "--port", help="--view: the port to serve on."),
    host: str = HostOption,
    config: Optional[Path] = typer.Option(None, "--config", help="A YAML file of settings, the same keys as --set "
                                          "(STAGE: {PARAM: VALUE}, preset and budget); --set wins. RUN_DIR/config.yaml "
                                          "repeats a run."),
    budget: Optional[str] = typer.Option(None, "--budget", help="Time for the whole job, e.g. 10m, 90s: training takes "
                                         "what the other stages leave, the exports size themselves to their shares. "
                                         "auto sizes it from the photos; off: train.seconds and every size as set "
                                         "\\[default: auto]."),
    debug: bool = DebugOption,
) -> None:
    """Run the pipeline on a folder of photos or a video, recomputing only what changed."""
    setup_logging(debug)
    from nerfpipe.cli.config import merge, read_config, write_config

    with user_errors(debug):
        preset = one_preset(presets)
        overrides = parse_assignments(set_)
        budget_from_file = None
        if config is not None:
            from_file, overrides_from_file, budget_from_file = read_config(config)
            preset = preset or from_file
            overrides = merge(overrides_from_file, overrides)
        job_budget = parse_duration(budget if budget is not None else budget_from_file or "auto")
        if skip_bad:
            if str(overrides.get("ingest", {}).get("skip_bad", "true")).strip().lower() in ("false", "0", "no", "off"):
                raise ParamError("--skip-bad and ingest.skip_bad=false disagree; drop one of them")
            overrides.setdefault("ingest", {})["skip_bad"] = "true"
        if out is not None and not out.strip():
            raise ParamError("--out is empty; pass the run directory, e.g. --out runs/photos")
        run_dir = Path(out) if out is not None else Path("runs") / photos_dir.resolve().name
        check_run_dir(photos_dir, run_dir)
        if view:
            from nerfpipe.export.web import check_address

            check_address(host, port)
        pipe = Pipeline(default_stages(), photos_dir, run_dir, preset, overrides, progress=progress_factory(), debug=debug,
                        extra={"watch_port": port, "watch_host": host} if view else None, budget=job_budget,
                        budget_rule=auto_budget)
        try:
            outcomes = pipe.run(until=until, only=only, force=force)
        finally:
            if (run_dir / "run.json").is_file():  # the run got as far as recording its settings
                write_config(run_dir, pipe.plan(), job_budget)
    print_outcomes(run_dir, outcomes, view)
    with user_errors(debug):
        from nerfpipe.cli.exports import refresh_exports

        exported = refresh_exports(pipe)
    out_console.print(f"exports: {escape(str(exported.folder))} ({', '.join(exported.names) or 'nothing yet'})",
                      highlight=False, soft_wrap=True)
    with user_errors(debug):
        from nerfpipe.report import write_report

        page = write_report(run_dir)
    out_console.print(f"report: {escape(str(page))}", highlight=False, soft_wrap=True)


@app.command()
def status(
    run_dir: Path = typer.Argument(..., help="Run directory of an earlier `nerfpipe run`."),
    presets: List[str] = PresetOption,
    set_: List[str] = SetOption,
    verify: bool = typer.Option(False, "--verify", help="Hash every output (sha256) instead of checking sizes and "
                                "times; move damaged results aside, for the next run to compute again."),
    debug: bool = DebugOption,
) -> None:
    """Each stage fresh / stale / broken / missing, with the reason. --preset/--set ask "what if"."""
    setup_logging(debug)
    with user_errors(debug):
        pipe = Pipeline.from_run_dir(default_stages(), run_dir, one_preset(presets), parse_assignments(set_))
        moved = pipe.verify() if verify else []
        statuses = pipe.status()
    table = Table(title=f"{escape(str(run_dir))} (photos: {escape(str(pipe.source))})", title_justify="left")
    for column in ("stage", "state", "reason", "key"):
        table.add_column(column)
    for s in statuses:
        table.add_row(s.name, f"[{STATE_STYLE[s.state]}]{s.state}[/]", escape("; ".join(s.reasons)), s.key[:12])
    out_console.print(table)
    for s in statuses:
        for line in pipe.describe(s):
            out_console.print(f"{s.name}: {escape(line)}", highlight=False, soft_wrap=True)
    if verify:
        checked = sum(len(s.result.manifest["outputs"]) for s in statuses if s.state == "fresh")
        out_console.print(f"verified: {checked} files of the fresh results match their sha256; "
                          f"{len(moved)} damaged result{'s' * (len(moved) != 1)}"
                          + "".join(f"\n  {s.name}: {escape(str(s.damage))}; moved aside to {escape(str(aside))}"
                                    for s, aside in moved)
                          + (f"\nthe next `{pipe.command()}` computes "
                             f"{'them' if len(moved) > 1 else 'it'} again" if moved else ""),
                          highlight=False, soft_wrap=True)


VIEW_KINDS = ("mesh", "points", "cameras")


@app.command()
def view(
    run_dir: Path = typer.Argument(..., help="Run directory of an earlier `nerfpipe run`."),
    kind: str = typer.Argument(
        "mesh", metavar="mesh|points|cameras",
        help="The exported mesh, the exported point cloud, or the SfM cameras and sparse points; frusta always.",
    ),
    web: bool = typer.Option(False, "--web", help="Serve a web viewer (viser): mesh, points, cameras with their "
                             "photos, and a live render of the field from the browser's viewpoint."),
    port: int = typer.Option(8080, "--port", help="--web: the port to serve on."),
    host: str = HostOption,
    share: bool = typer.Option(False, "--share", help="--web: show viser's share button, which publishes the viewer, "
                               "the run's photos included, on a public URL through viser's tunnel service."),
    debug: bool = DebugOption,
) -> None:
    """Look at a run's mesh, point cloud or cameras; with no display, write RUN_DIR/view_<kind>.png instead."""
    setup_logging(debug)
    import difflib

    with user_errors(debug):
        if kind not in VIEW_KINDS:
            close = difflib.get_close_matches(kind, VIEW_KINDS, n=1)
            hint = f"did you mean {close[0]}?" if close else f"choose one of {', '.join(VIEW_KINDS)}"
            raise ParamError(f"unknown view {kind!r}; {hint}")
        pipe = Pipeline.from_run_dir(default_stages(), run_dir)
        if web:
            from nerfpipe.export.web import check_address

            check_address(host, port)
            serve_web(pipe, host, port, share)
            return
        from nerfpipe.export import screenshot as shot
        from nerfpipe.export.views import cameras_of
        from nerfpipe.geometry.cameras import CameraSet

        sfm = CameraSet.load(pipe.artifact("sfm_model", "SfM cameras"))
        mesh = points = None
        if kind == "mesh":
            mesh = shot.load_mesh(pipe.artifact("mesh", "exported mesh"))
        elif kind == "points":
            points = shot.load_points(pipe.artifact("points", "exported point cloud"))
        else:
            points = shot.sparse_points(sfm)
        path = shot.show(mesh, points, cameras_of(sfm), screenshot_path=run_dir / f"view_{kind}.png",
                         title=f"nerfpipe {kind}: {run_dir}")
    if path is not None:
        out_console.print(f"no display: wrote a screenshot to {escape(str(path))}", highlight=False, soft_wrap=True)


@app.command()
def report(
    run_dir: Path = typer.Argument(..., help="Run directory of an earlier `nerfpipe run`."),
    debug: bool = DebugOption,
) -> None:
    """Write RUN_DIR/report/index.html: capture, SfM, scene decisions, training, depth, mesh, timings."""
    setup_logging(debug)
    from nerfpipe.report import write_report

    with user_errors(debug):
        page = write_report(run_dir)
    out_console.print(f"report: {escape(str(page))}", highlight=False, soft_wrap=True)


@app.command()
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


@app.command()
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
    until: Optional[str] = typer.Option(None, "--until", help="Run the stages up to and including this one."),
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


@app.command()
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


@app.command()
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


@app.command()
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


def main() -> None:
    app(prog_name="nerfpipe")


if __name__ == "__main__":
    main()
