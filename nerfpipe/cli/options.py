"""The options the commands share, with the values each takes listed in its help and offered by shell
completion (``nerfpipe --install-completion``): stage names for ``--until``, ``--only`` and ``--force``,
preset names for ``--preset``, ``STAGE.PARAM=`` for ``--set``. A wrong value is still refused by the
pipeline, in one line that names it and the choices (a ``click.Choice`` would print a usage box instead)."""

from __future__ import annotations

from functools import lru_cache

import typer

from nerfpipe.pipeline import Dag, param_specs
from nerfpipe.stages import default_stages


@lru_cache(maxsize=1)
def _dag() -> Dag:
    return Dag(default_stages())


def stage_names() -> tuple[str, ...]:
    """The stages in the order they run."""
    return tuple(_dag().order)


def preset_names() -> tuple[str, ...]:
    """Every preset some stage has, sorted."""
    return tuple(sorted({p for stage in _dag().stages.values() for p in stage.presets}))


def parameter_keys() -> tuple[str, ...]:
    """Every ``STAGE.PARAM`` that ``--set`` takes, in the stages' order."""
    dag = _dag()
    return tuple(f"{name}.{spec.name}" for name in dag.order for spec in param_specs(dag.stages[name].Params))


def complete_stage(incomplete: str) -> list[str]:
    return [name for name in stage_names() if name.startswith(incomplete)]


def complete_preset(incomplete: str) -> list[str]:
    return [name for name in preset_names() if name.startswith(incomplete)]


def complete_set(incomplete: str) -> list[str]:
    """``STAGE.`` while no stage is complete, then ``STAGE.PARAM=`` for the parameters that start so."""
    if "=" in incomplete:
        return []
    if "." not in incomplete:
        return [f"{name}." for name in stage_names() if name.startswith(incomplete)]
    return [f"{key}=" for key in parameter_keys() if key.startswith(incomplete)]


def examples(*lines: str) -> str:
    """A command's ``--help`` epilog: its examples, each ``"what it does: command"``, written as a comment
    line and the command under it (``\\b`` keeps the lines apart; each fits an 80-column terminal)."""
    shown = []
    for line in lines:
        what, _, command = line.rpartition(": nerfpipe ")
        shown += [f"  # {what}", f"  nerfpipe {command}"] if what else [f"  {line}"]
    return "[bold]Examples[/]\n\n\b\n" + "\n".join(shown)


def _stages_help(what: str) -> str:
    return f"{what} One of: {', '.join(stage_names())}."


DebugOption = typer.Option(False, "--debug", help="Show tracebacks and debug logs.")
PresetOption = typer.Option([], "--preset", "-p", metavar="PRESET", autocompletion=complete_preset,
                            help=f"Named preset applied to every stage that has it (one: presets do not combine; use "
                                 f"--set on top). One of: {', '.join(preset_names())}.")
SetOption = typer.Option([], "--set", "-s", metavar="STAGE.PARAM=VALUE", autocompletion=complete_set,
                         help="Override one parameter (repeatable); `nerfpipe stages` lists them.")
HostOption = typer.Option("127.0.0.1", "--host", show_default=True, help="The web viewer's address: this machine only "
                          "by default; 0.0.0.0 shows the run's photos to anyone on the network who has the printed "
                          "URL (its token).")
UntilOption = typer.Option(None, "--until", metavar="STAGE", autocompletion=complete_stage,
                           help=_stages_help("Run the stages up to and including this one."))
OnlyOption = typer.Option(None, "--only", metavar="STAGE", autocompletion=complete_stage,
                          help=_stages_help("Run only this stage; its upstream must be fresh."))
ForceOption = typer.Option([], "--force", metavar="STAGE", autocompletion=complete_stage,
                           help=_stages_help("Rerun this stage even if cached (repeatable); its downstream reruns only "
                                             "if its outputs change."))
