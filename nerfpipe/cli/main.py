"""`nerfpipe` commands. Parsing and formatting only: every action is a ``Pipeline`` call."""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional

import typer
from rich.table import Table

from nerfpipe.cli import tools
from nerfpipe.cli.config import one_preset
from nerfpipe.cli.console import (
    STATE_STYLE,
    escape,
    out_console,
    print_outcomes,
    progress_factory,
    serve_web,
    setup_logging,
    status_json,
    user_errors,
)
from nerfpipe.cli.options import (
    DebugOption,
    ForceOption,
    HostOption,
    OnlyOption,
    PresetOption,
    SetOption,
    UntilOption,
    examples,
)
from nerfpipe.pipeline import ParamError, Pipeline, parse_assignments
from nerfpipe.pipeline.budget import parse_duration
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


@app.command(epilog=examples(
    "every stage, into runs/photos: nerfpipe run photos/",
    "a video, the whole job in 10 minutes: nerfpipe run clip.mp4 --out runs/clip --budget 10m",
    "stop after structure from motion: nerfpipe run photos/ --until sfm",
    "a preset, and one setting on top: nerfpipe run photos/ --preset hash --set train.seconds=600",
    "the mesh again, printing only warnings: nerfpipe run photos/ --force export_mesh --quiet"))
def run(
    photos_dir: Path = typer.Argument(..., help="Folder of photos (or a capture folder with images/), or a video."),
    out: Optional[str] = typer.Option(None, "--out", "-o", help="Run directory \\[default: runs/<photos folder name>]."),
    presets: List[str] = PresetOption,
    set_: List[str] = SetOption,
    until: Optional[str] = UntilOption,
    only: Optional[str] = OnlyOption,
    force: List[str] = ForceOption,
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
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print only warnings and errors: no progress, no table."),
    debug: bool = DebugOption,
) -> None:
    """Run the pipeline on a folder of photos or a video, recomputing only what changed."""
    setup_logging(debug, quiet)
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
        from nerfpipe.nerf.compiling import choice

        choice()  # a wrong NERFPIPE_COMPILE fails now, not when the first render starts after training
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
        pipe = Pipeline(default_stages(), photos_dir, run_dir, preset, overrides, progress=progress_factory(quiet), debug=debug,
                        extra={"watch_port": port, "watch_host": host} if view else None, budget=job_budget,
                        budget_rule=auto_budget)
        try:
            outcomes = pipe.run(until=until, only=only, force=force)
        finally:
            if (run_dir / "run.json").is_file():  # the run got as far as recording its settings
                write_config(run_dir, pipe.plan(), job_budget)
    print_outcomes(run_dir, outcomes, view, quiet)
    with user_errors(debug):
        from nerfpipe.cli.exports import refresh_exports

        exported = refresh_exports(pipe)
    with user_errors(debug):
        from nerfpipe.report import write_report

        page = write_report(run_dir)
    if not quiet:
        out_console.print(f"exports: {escape(str(exported.folder))} ({', '.join(exported.names) or 'nothing yet'})"
                          f"\nreport: {escape(str(page))}", highlight=False, soft_wrap=True)


@app.command(epilog=examples(
    "what is fresh, and why not: nerfpipe status runs/photos",
    "what would rerun if ...?: nerfpipe status runs/photos --set train.seconds=600",
    "hash every output, and move damaged ones aside: nerfpipe status runs/photos --verify",
    "for scripts: nerfpipe status runs/photos --json"))
def status(
    run_dir: Path = typer.Argument(..., help="Run directory of an earlier `nerfpipe run`."),
    presets: List[str] = PresetOption,
    set_: List[str] = SetOption,
    verify: bool = typer.Option(False, "--verify", help="Hash every output (sha256) instead of checking sizes and "
                                "times; move damaged results aside, for the next run to compute again."),
    as_json: bool = typer.Option(False, "--json", help="Machine-readable: one JSON object, the photos and each stage's "
                                 "state, reasons, key, folder and summary."),
    debug: bool = DebugOption,
) -> None:
    """Each stage fresh / stale / broken / missing, with the reason. --preset/--set ask "what if"."""
    setup_logging(debug)
    with user_errors(debug):
        pipe = Pipeline.from_run_dir(default_stages(), run_dir, one_preset(presets), parse_assignments(set_))
        moved = pipe.verify() if verify else []
        statuses = pipe.status()
    if as_json:
        print(json.dumps(status_json(pipe, statuses, moved), indent=1))
        return
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


@app.command(epilog=examples(
    "the mesh and cameras (a screenshot without a display): nerfpipe view runs/photos",
    "the point cloud: nerfpipe view runs/photos points",
    "in the browser, with a live render of the field: nerfpipe view runs/photos --web",
    "with viser's share button (a public URL, photos included): nerfpipe view runs/photos --web --share"))
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
                         title=f"nerfpipe {kind}: {run_dir}", frame_cameras=kind == "cameras")
    if path is not None:
        out_console.print(f"no display: wrote a screenshot to {escape(str(path))}", highlight=False, soft_wrap=True)


@app.command(epilog=examples("then open runs/photos/report/index.html: nerfpipe report runs/photos"))
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


app.command(epilog=examples(
    "the presets, 5 minutes of training each: nerfpipe bench photos/ --out runs/bench",
    "two configurations, 2 minutes each: nerfpipe bench photos/ --out runs/bench -c grid -c hash --budget 120",
))(tools.bench)
app.command(epilog=examples(
    "one capture after another, here: nerfpipe batch captures/ --out runs/",
    "on a Ray cluster: nerfpipe batch captures/ --out runs/ -e ray --address auto"))(tools.batch)
app.command(epilog=examples("every stage: nerfpipe stages", "for scripts: nerfpipe stages train --json"))(tools.stages)
app.command(epilog=examples("nerfpipe export runs/photos --to ~/photos-3d"))(tools.export)
app.command(epilog=examples("keep each stage's latest result only: nerfpipe clean runs/photos"))(tools.clean)


def main() -> None:
    app(prog_name="nerfpipe")


if __name__ == "__main__":
    main()
