"""The parameter reference, docs/parameters.md, written from the stages' parameter dataclasses and their
help strings (``python scripts/gen_parameters.py``; a test fails when the file is stale)."""

from __future__ import annotations

from typing import Any

from nerfpipe.pipeline import Dag, ParamSpec, Stage, param_specs

HEADER = """# Parameters

Every parameter of every stage, with its type, default and meaning. Set one with
`--set STAGE.NAME=VALUE` (`--set train.field.levels=4`); a preset (`--preset NAME`) sets several at once,
and `--set` wins over it (one preset at a time: two are refused). Switches are `auto|on|off`: `auto` decides
from the data and says why.

Every number has bounds, both allowed, checked before anything runs: a value outside them is one line and
exit 2. Sizes that multiply are checked against the memory this process may use (the machine's, `ulimit -d`
and `-v`, a container's limit): the feature tables (`train.field` levels, resolutions, features), the
occupancy grid, a training step's samples and the texture. A setting whose cost alone exceeds the whole
`--budget` (`train.steps`, `train.seconds`; `export_mesh.resolution` once its first queries are timed) is
refused unless `--budget off`.

Generated from the help strings by `python scripts/gen_parameters.py`; do not edit by hand.

"""


def _shown(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def parameters_markdown(stages: list[Stage]) -> str:
    """The reference: the stage graph, then a table of parameters and the presets for each stage."""
    dag = Dag(stages)
    parts = [HEADER, "Stages in order: " + " -> ".join(f"[{n}](#{n})" for n in dag.order) + ".\n"]
    for name in dag.order:
        stage = dag.stages[name]
        parts.append(f"\n## {name}\n\n{stage.summary()}\n\n| parameter | type | default | bounds | meaning |\n|---|---|---|---|---|\n")
        for spec in param_specs(stage.Params):
            parts.append(f"| `{name}.{spec.name}` | {_cell(spec.type_name)} | `{_shown(spec.default)}` | "
                         f"{_bounds(spec.bounds)} | {_cell(meaning(spec))} |\n")
        if stage.presets:
            parts.append("\nPresets:\n\n")
            for preset, values in stage.presets.items():
                shown = ", ".join(f"`{k}={_shown(v)}`" for k, v in values.items()) or "the defaults"
                parts.append(f"- `{preset}`: {shown}\n")
    return "".join(parts)


def meaning(spec: ParamSpec) -> str:
    """A parameter's help, with the kinds whose setting it is (a tagged union's) and whether it stays out of the
    cache key."""
    kinds = f"({', '.join(spec.kinds)}) " if spec.kinds else ""
    return kinds + spec.help + ("; changing it reruns nothing" if not spec.keyed else "")


def _bounds(bounds: Any) -> str:
    """``[1, 2048]``: a number's declared bounds, both allowed; empty for a parameter that has none."""
    if not bounds:
        return ""
    return "[" + ", ".join(f"{b:g}" if isinstance(b, float) else f"{b:_}" if abs(b) >= 100_000 else str(b)
                           for b in bounds) + "]"


def stage_reference(dag: Dag, names: list[str]) -> dict[str, Any]:
    """Stage name -> version, summary, requires, upstream, provides, parameters (name, type, default, help)
    and presets, for ``nerfpipe stages [--json]``."""
    reference = {}
    for name in names:
        stage = dag.stages[name]
        reference[name] = {
            "version": stage.version, "summary": stage.summary(), "requires": list(stage.requires),
            "upstream": list(dag.upstream[name]), "provides": dict(stage.provides),
            "parameters": [{"name": s.name, "type": s.type_name, "default": s.default, "help": meaning(s),
                            **({"kinds": list(s.kinds)} if s.kinds else {}), **({} if s.keyed else {"keyed": False}),
                            **({"choices": list(s.choices)} if s.choices else {}),
                            **({"bounds": list(s.bounds)} if s.bounds else {})} for s in param_specs(stage.Params)],
            "presets": {k: dict(v) for k, v in stage.presets.items()},
        }
    return reference


def print_reference(reference: dict[str, Any], order: list[str] | None) -> None:
    """`nerfpipe stages` for people: the graph (``order``, when all stages are shown), then each stage."""
    from nerfpipe.cli.console import escape, out_console

    if order:
        out_console.print("[bold]" + " -> ".join(order) + "[/]\n")
    for name, entry in reference.items():
        out_console.print(f"[bold]{name}[/] (version {entry['version']}): {escape(entry['summary'])}")
        if entry["upstream"]:
            out_console.print(f"  needs: {', '.join(entry['requires'])} (from {', '.join(entry['upstream'])})")
        out_console.print(f"  provides: {', '.join(f'{a} ({p})' for a, p in entry['provides'].items())}")
        for spec in entry["parameters"]:
            bounds = f" in {_bounds(spec['bounds'])}" if "bounds" in spec else ""
            out_console.print(f"  [cyan]{name}.{spec['name']}[/] = {escape(str(spec['default']))}  "
                              f"[dim]({escape(spec['type'])}{escape(bounds)})[/]  {escape(spec['help'])}", highlight=False,
                              soft_wrap=True)
        for preset_name, values in entry["presets"].items():
            shown = ", ".join(f"{k}={v}" for k, v in values.items())
            out_console.print(f"  preset [green]{preset_name}[/]: {escape(shown)}", highlight=False)
        out_console.print()
