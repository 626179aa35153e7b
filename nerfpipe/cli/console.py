"""What the CLI shows in the terminal: log lines, progress bars, user errors as one line (tracebacks with
--debug), and the states of stages."""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path
from typing import Callable, Iterator

import typer
from rich.console import Console
from rich.markup import escape as escape_markup
from rich.table import Table

from nerfpipe.pipeline import NerfpipeError, Pipeline
from nerfpipe.pipeline.errors import os_error_to_user_error

err_console = Console(stderr=True)
out_console = Console()

def escape(text: str) -> str:
    """``text`` safe to print: control characters (a newline or terminal escape codes in a file name) shown as
    ``\\n`` or ``\\x1b`` rather than acted on, and Rich markup shown as written."""
    return escape_markup(text if text.isprintable() else "".join(c if c.isprintable() else repr(c)[1:-1] for c in text))


STATE_STYLE = {"fresh": "green", "stale": "yellow", "broken": "red", "missing": "red"}


class ConsoleHandler(logging.Handler):
    """Concise terminal logs: plain info lines, labelled warnings; the run's log file has everything."""

    PREFIX = {logging.DEBUG: "[dim]debug:[/] ", logging.WARNING: "[yellow]warning:[/] ", logging.ERROR: "[red]error:[/] "}

    def emit(self, record: logging.LogRecord) -> None:
        prefix = self.PREFIX.get(record.levelno, "")
        err_console.print(prefix + escape(self.format(record)), highlight=False, soft_wrap=True)


def setup_logging(debug: bool, quiet: bool = False) -> None:
    """nerfpipe's log on the terminal: info lines, or only warnings and errors (``quiet``), or everything
    (``debug``, which wins). Open3D's own log follows it (``nerfpipe.export.o3d``)."""
    handler = ConsoleHandler()
    handler.setLevel(logging.DEBUG if debug else logging.WARNING if quiet else logging.INFO)
    handler.setFormatter(logging.Formatter("%(message)s"))
    root = logging.getLogger("nerfpipe")
    root.handlers[:] = [handler]
    root.setLevel(logging.DEBUG if debug else logging.INFO)
    root.propagate = False


@contextlib.contextmanager
def user_errors(debug: bool) -> Iterator[None]:
    """User errors become one line and a non-zero exit; ``--debug`` shows the traceback as well.

    So does a full disk or a read-only filesystem met outside a stage (writing the report, say).
    """
    try:
        yield
    except (NerfpipeError, OSError) as err:
        user_error = err if isinstance(err, NerfpipeError) else os_error_to_user_error(err, err.filename or ".")
        if user_error is None:
            raise
        if debug:
            err_console.print_exception()
        err_console.print(f"[bold red]error:[/] {escape(str(user_error))}", highlight=False, soft_wrap=True)
        raise typer.Exit(user_error.exit_code) from None
    except KeyboardInterrupt:
        err_console.print("[bold red]interrupted[/]: the stage that was running was not committed", highlight=False)
        raise typer.Exit(130) from None


def progress_factory(quiet: bool = False) -> Callable:
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    @contextlib.contextmanager
    def progress(total: int, description: str) -> Iterator[Callable[..., None]]:
        if quiet or not err_console.is_terminal:
            yield lambda n=1, info=None: None
            return
        columns = (
            TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
            TextColumn("left"), TimeRemainingColumn(), TextColumn("{task.fields[info]}"),
        )
        with Progress(*columns, console=err_console, transient=True) as bar:
            task = bar.add_task(description, total=total, info="")

            def advance(n: int = 1, info: str | None = None) -> None:
                bar.update(task, advance=n, **({} if info is None else {"info": info}))

            yield advance

    return progress


def bench_line(result: dict, with_seed: bool) -> str:
    seed = f" (seed {result['seed']})" if with_seed else ""
    return (f"{result['name']}{seed}: {result['points'][-1]['psnr']:.2f} dB after {result['train_seconds']:.0f} s "
            f"({result['samples_per_ray']:.1f} samples/ray, {result['samples_per_s']:,} samples/s)")


@contextlib.contextmanager
def batch_progress(total: int) -> Iterator[Callable]:
    """One line per capture (state, current stage, time) and the totals: a live table on a terminal,
    else a line whenever a capture moves on."""
    def totals(states) -> str:
        counts = {k: sum(1 for c in states if c.state == k) for k in ("running", "done", "failed", "queued")}
        return ", ".join(f"{v} {k}" for k, v in counts.items()) + f" of {total}"

    if not err_console.is_terminal:
        seen: dict[str, tuple] = {}

        def on_change(states) -> None:
            for c in states:
                now = (c.state, c.stage)
                if seen.get(c.name) != now and c.state != "queued":
                    seen[c.name] = now
                    where = c.stage or ""
                    err_console.print(f"batch: {c.name}: {c.state} {where} ({totals(states)})".replace("  ", " "),
                                      highlight=False, soft_wrap=True)

        yield on_change
        return
    from rich.live import Live

    def render(states) -> Table:
        table = Table(title=totals(states), title_justify="left", box=None)
        for column in ("capture", "state", "stage", "time"):
            table.add_column(column)
        for c in states:
            table.add_row(escape(c.name), c.state, c.stage or "", f"{c.seconds:.0f} s" if c.started else "")
        return table

    with Live(console=err_console, transient=True, refresh_per_second=4) as live:
        yield lambda states: live.update(render(states))


def serve_web(pipe: Pipeline, host: str, port: int, share: bool = False) -> None:
    """`view --web`: gather the run's results, serve them until Ctrl-C."""
    import time

    from nerfpipe.export.web import serve, web_scene

    scene = web_scene(
        model_dir=pipe.artifact("model", "trained model").parent,
        cameras_dir=pipe.artifact("cameras", "trained model"),
        images_dir=pipe.artifact("images", "photos"),
        bounds_json=pipe.artifact("bounds", "bounds"),
        mesh_ply=pipe.optional_artifact("mesh"),
        points_ply=pipe.optional_artifact("points"),
        run_dir=pipe.run_dir,
    )
    viewer = serve(scene, host=host, port=port, share=share)
    held = [f"{len(scene.frames)} cameras with their photos"]
    held += [f"a mesh of {scene.mesh.faces:,} triangles"] if scene.mesh is not None else []
    held += [f"{len(scene.points.xyz):,} points"] if scene.points is not None else []
    out_console.print(f"web viewer: {viewer.url} ({', '.join(held)}, and a live render of the field); "
                      "Ctrl-C stops it", highlight=False, soft_wrap=True)
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        viewer.stop()
        out_console.print("web viewer stopped", highlight=False)


def short_path(run_dir: Path, path: Path) -> str:
    """A stage's result folder as the table shows it: inside the run directory, its 64-hex key cut to 12
    characters (as ``status`` shows keys), so that a row fits an 80-column terminal."""
    try:
        parts = Path(path).relative_to(run_dir).parts
    except ValueError:
        return str(path)
    return "/".join(f"{p[:12]}…" if len(p) == 64 and all(c in "0123456789abcdef" for c in p) else p for p in parts)


def print_outcomes(run_dir, outcomes, view: bool, quiet: bool = False) -> None:
    """`run`'s table of what each stage did (not when ``quiet``), the warnings of a run that finished without
    some exports, and what --view could not show."""
    if not quiet:
        table = Table(title=f"nerfpipe run -> {escape(str(run_dir))}", title_justify="left")
        for column in ("stage", "result", "time"):
            table.add_column(column)
        table.add_column("output", overflow="fold")
        for o in outcomes:
            made = escape(o.reasons[0] if o.action in ("failed", "skipped") else short_path(run_dir, o.path))
            table.add_row(o.name, o.action, f"{o.seconds:.1f} s", made)
        out_console.print(table)
    trouble = [o for o in outcomes if o.action in ("failed", "skipped")]
    if trouble:
        err_console.print("[yellow]warning:[/] finished with warnings: " + "; ".join(f"{o.name} {o.action} ({escape(o.reasons[0])})"
                                                                 for o in trouble), highlight=False, soft_wrap=True)
    if view and not any(o.name == "train" and o.action == "ran" for o in outcomes):
        out_console.print(f"--view: no training ran to watch; `nerfpipe view {escape(str(run_dir))} --web` shows the "
                          "trained field", highlight=False, soft_wrap=True)


def print_batch(states: list, out: Path, executor: str) -> list:
    """`batch`'s table of each capture's state, and its closing line; returns the captures that did not finish."""
    from nerfpipe.pipeline.batch import SUMMARY

    table = Table(title=f"nerfpipe batch -> {escape(str(out))} ({executor})", title_justify="left")
    for column in ("capture", "state", "ran", "cached", "time"):
        table.add_column(column)
    table.add_column("reason", overflow="fold")
    for c in states:
        reason = "" if c.error is None else f"{c.stage or 'plan'}: {c.error}" + (f" (log: {c.log})" if c.log else "")
        style = {"done": "green", "failed": "red"}.get(c.state, "")
        table.add_row(escape(c.name), f"[{style}]{c.state}[/]", str(c.count("ran")),
                      str(c.count("cached") + c.count("restored")), f"{c.seconds:.1f} s", escape(reason))
    out_console.print(table)
    failed = [c for c in states if c.state != "done"]
    out_console.print(f"{len(states) - len(failed)} of {len(states)} captures done, {len(failed)} failed; "
                      f"summary: {escape(str(out / SUMMARY))}", highlight=False, soft_wrap=True)
    return failed


def status_json(pipe: Pipeline, statuses: list, moved: list) -> dict:
    """``status --json``: the run, its photos, and per stage its state, reasons, key, result folder (the
    current one when fresh, else the latest, or none) and the lines its summary gives."""
    aside = {s.name: str(path) for s, path in moved}
    return {
        "run_dir": str(pipe.run_dir), "photos": str(pipe.source),
        "stages": [{"name": s.name, "state": s.state, "reasons": list(s.reasons), "key": s.key,
                    "path": str(s.result.path) if s.result is not None else None,
                    "damage": str(s.damage) if s.damage is not None else None,
                    "moved_to": aside.get(s.name), "summary": list(pipe.describe(s))} for s in statuses],
    }
