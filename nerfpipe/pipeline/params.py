"""Typed stage parameters: frozen dataclasses, named presets, and ``stage.param=value`` overrides.

A stage's parameters are a frozen dataclass. Each field may carry ``metadata={"help": "..."}``; a
``Literal[...]`` annotation lists the allowed values; ``__post_init__`` may raise ``ValueError`` for
values out of range. Overrides arrive as text from the command line or as Python values from the API,
and are checked and converted here, so a stage only ever sees valid, typed values.
"""

from __future__ import annotations

import dataclasses
import difflib
import types
import typing
from dataclasses import dataclass
from typing import Any, Literal, Mapping

from nerfpipe.pipeline.errors import ParamError

_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}
_NONE = {"none", "null"}


@dataclass(frozen=True)
class ParamSpec:
    """One parameter as the CLI and ``nerfpipe stages`` show it."""

    name: str
    type: Any
    default: Any
    help: str

    @property
    def choices(self) -> tuple[Any, ...] | None:
        inner = _strip_optional(self.type)[0]
        return typing.get_args(inner) if typing.get_origin(inner) is Literal else None

    @property
    def type_name(self) -> str:
        inner, optional = _strip_optional(self.type)
        if typing.get_origin(inner) is Literal:
            name = "|".join(str(c) for c in typing.get_args(inner))
        else:
            name = getattr(inner, "__name__", str(inner))
        return f"{name} or none" if optional else name


def param_specs(params_cls: type) -> list[ParamSpec]:
    hints = typing.get_type_hints(params_cls)
    specs = []
    for f in dataclasses.fields(params_cls):
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        specs.append(ParamSpec(f.name, hints[f.name], default, f.metadata.get("help", "")))
    return specs


def params_to_dict(params: Any) -> dict[str, Any]:
    return dataclasses.asdict(params)


def _strip_optional(tp: Any) -> tuple[Any, bool]:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return args[0], True
    return tp, False


def coerce(value: Any, tp: Any, qualname: str) -> Any:
    """Convert ``value`` (text from the CLI, or a Python value) to ``tp``, or raise ``ParamError``."""
    inner, optional = _strip_optional(tp)
    if optional and (value is None or (isinstance(value, str) and value.strip().lower() in _NONE)):
        return None
    if typing.get_origin(inner) is Literal:
        choices = typing.get_args(inner)
        for choice in choices:
            if value == choice or (isinstance(value, str) and value.strip() == str(choice)):
                return choice
        allowed = ", ".join(str(c) for c in choices)
        raise ParamError(f"{qualname}: {value!r} is not one of {allowed}")
    if inner is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.strip().lower() in _TRUE | _FALSE:
            return value.strip().lower() in _TRUE
        raise ParamError(f"{qualname}: expected true or false, got {value!r}")
    if inner is int:
        if isinstance(value, bool):
            raise ParamError(f"{qualname}: expected an integer, got {value!r}")
        if isinstance(value, int):
            return value
        try:
            return int(str(value).strip())
        except ValueError:
            raise ParamError(f"{qualname}: expected an integer, got {value!r}") from None
    if inner is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        try:
            return float(str(value).strip())
        except ValueError:
            raise ParamError(f"{qualname}: expected a number, got {value!r}") from None
    if inner is str:
        return str(value)
    raise TypeError(f"{qualname}: unsupported parameter type {tp!r}")  # a bug in the stage, not user error


def build_params(
    stage: str,
    params_cls: type,
    presets: Mapping[str, Mapping[str, Any]],
    preset: str | None,
    overrides: Mapping[str, Any],
) -> Any:
    """Defaults, then the named preset (if this stage has it), then overrides; checked and typed."""
    specs = {s.name: s for s in param_specs(params_cls)}
    values: dict[str, Any] = {}
    if preset is not None and preset in presets:
        values.update(presets[preset])
    for name, raw in overrides.items():
        if name not in specs:
            close = difflib.get_close_matches(name, list(specs), n=1)
            hint = f"did you mean {stage}.{close[0]}?" if close else f"{stage} has: {', '.join(specs)}"
            raise ParamError(f"unknown parameter {stage}.{name}; {hint}")
        values[name] = raw
    typed = {name: coerce(v, specs[name].type, f"{stage}.{name}") for name, v in values.items()}
    try:
        return params_cls(**typed)
    except ValueError as err:
        raise ParamError(f"{stage}: {err}") from None


def parse_assignments(assignments: list[str]) -> dict[str, dict[str, str]]:
    """``["ingest.max_size=800", ...]`` -> ``{"ingest": {"max_size": "800"}}``."""
    parsed: dict[str, dict[str, str]] = {}
    for text in assignments:
        target, sep, value = text.partition("=")
        stage, dot, name = target.strip().partition(".")
        if not sep or not dot or not stage or not name:
            raise ParamError(f"--set {text!r}: expected STAGE.PARAM=VALUE, e.g. ingest.max_size=800")
        parsed.setdefault(stage, {})[name] = value
    return parsed


def describe_changes(stage: str, old: Mapping[str, Any], new: Mapping[str, Any]) -> list[str]:
    """``["ingest.max_size 1600 -> 800", ...]`` for every parameter whose value differs."""
    changes = []
    for name in sorted(set(old) | set(new)):
        if old.get(name, "<unset>") != new.get(name, "<unset>"):
            changes.append(f"{stage}.{name} {_show(old.get(name, '<unset>'))} -> {_show(new.get(name, '<unset>'))}")
    return changes


def _show(value: Any) -> str:
    return "none" if value is None else str(value).lower() if isinstance(value, bool) else str(value)
