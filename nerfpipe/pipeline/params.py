"""Typed stage parameters: frozen dataclasses, named presets, and ``stage.param=value`` overrides.

A stage's parameters are a frozen dataclass. Each field may carry ``metadata={"help": "..."}``; a
``Literal[...]`` annotation lists the allowed values; ``__post_init__`` may raise ``ValueError`` for
values out of range. Overrides arrive as text from the command line or as Python values from the API,
and are checked and converted here, so a stage only ever sees valid, typed values.

A field whose type is itself a parameter dataclass is a group, named with dots: ``train.field.levels``
is the ``levels`` of the ``field`` group of ``train``'s parameters. A group declared with ``union=`` is a
tagged union: its ``kind`` picks one of several parameter dataclasses (a field kind's own settings), and
a setting of another kind is refused by name. A parameter declared ``keyed=False`` cannot change a
result (a device, a chunk size): it stays out of the cache key (``cache_view``). Presets and overrides name every
parameter by its dotted path. Every switch is an ``Auto`` (``auto``, ``on`` or ``off``). A params class
may map retired names to their new paths in ``ALIASES`` (``{"grid_levels": "field.levels"}``); they and
the retired switch spellings (``true``, ``false``, ``yes``, ``no``) still work, with a deprecation
message.
"""

from __future__ import annotations

import dataclasses
import difflib
import logging
import math
import types
import typing
from dataclasses import dataclass
from typing import Any, Callable, Literal, Mapping

from nerfpipe.pipeline.errors import ParamError

log = logging.getLogger("nerfpipe")

Auto = Literal["auto", "on", "off"]  # every switch: decided from the data, or forced on or off

_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}
_NONE = {"none", "null"}


def param(default: Any, help: str, bounds: tuple[float, float] | None = None, *,
          union: Callable[[], Mapping[str, type]] | None = None,
          auto: Callable[[Mapping[str, Any]], str] | None = None, keyed: bool = True) -> Any:
    """A parameter field with its default, the help text ``nerfpipe stages`` and docs/parameters.md show, and for
    a number its ``bounds`` (lowest, highest; both allowed), checked before anything runs.

    union: for a group, the parameter dataclasses its ``kind`` chooses from, by kind (called when needed, so
        that a registry may name them lazily); each has a ``kind`` field whose default is its own kind.
    auto: for a union, ``kind=auto`` is allowed and resolved by this function of the groups built before it
        (by name), as is a union group given no kind of its own.
    keyed: False for a setting that cannot change what a stage makes (a device, a chunk size, a thread
        count): a run that changes only such settings reruns nothing (``cache_view``).
    """
    metadata: dict[str, Any] = {"help": help, "keyed": keyed}
    if union is not None:
        metadata.update(union=union, auto=auto)
    if dataclasses.is_dataclass(default):
        return dataclasses.field(default_factory=lambda: default, metadata=metadata)
    if bounds is not None:
        metadata["bounds"] = bounds
    return dataclasses.field(default=default, metadata=metadata)


@dataclass(frozen=True)
class ParamSpec:
    """One parameter as the CLI and ``nerfpipe stages`` show it."""

    name: str
    type: Any
    default: Any
    help: str
    bounds: tuple[float, float] | None = None  # a number's lowest and highest value, both allowed
    kinds: tuple[str, ...] = ()  # in a tagged union: the kinds whose setting it is (empty: every kind)
    keyed: bool = True  # False: it cannot change a result, and stays out of the cache key

    @property
    def is_number(self) -> bool:
        return _strip_optional(self.type)[0] in (int, float)

    def check_bounds(self, value: Any, qualname: str) -> None:
        """Raise ``ParamError`` for a number outside ``bounds``."""
        if self.bounds is None or value is None or not self.is_number:
            return
        low, high = self.bounds
        if not low <= value <= high:
            shown = f"{value:g}" if isinstance(value, float) else (f"{value}" if len(str(value)) < 30 else
                                                                    f"a {len(str(abs(value)))}-digit number")
            low_, high_ = (f"{b:g}" if isinstance(b, float) else str(b) for b in (low, high))
            raise ParamError(f"{qualname}: {shown} is outside its bounds [{low_}, {high_}]")

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


def is_group(tp: Any) -> bool:
    """Whether a field of this type is a group of parameters (a nested parameter dataclass)."""
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def union_members(f: dataclasses.Field) -> dict[str, type] | None:
    """The parameter dataclasses a tagged-union group chooses from, by kind; None for any other field."""
    return None if f.metadata.get("union") is None else dict(f.metadata["union"]())


def kind_of(cls: type) -> str:
    """The kind a union member stands for: the default of its ``kind`` field."""
    return next(f.default for f in dataclasses.fields(cls) if f.name == "kind")


def _default(f: dataclasses.Field) -> Any:
    return f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]


def _union_specs(f: dataclasses.Field, prefix: str) -> list[ParamSpec]:
    """A union group's parameters: its ``kind``, then each kind's settings, a setting two kinds share listed
    once with both (its default is the default kind's)."""
    members, default = union_members(f), _default(f)
    kinds = (*(["auto"] if f.metadata.get("auto") else []), *members)
    shown_kind = "auto" if f.metadata.get("auto") else default.kind
    specs = {"kind": ParamSpec(f"{prefix}kind", Literal[kinds], shown_kind,  # type: ignore[valid-type]
                               f.metadata.get("help", ""))}
    ordered = [type(default), *(cls for cls in members.values() if cls is not type(default))]
    for cls in ordered:
        hints = typing.get_type_hints(cls)
        for g in dataclasses.fields(cls):
            if g.name == "kind":
                continue
            if g.name in specs:
                old = specs[g.name]
                specs[g.name] = dataclasses.replace(old, kinds=(*old.kinds, kind_of(cls)))
                continue
            value = getattr(default, g.name) if isinstance(default, cls) else _default(g)
            specs[g.name] = ParamSpec(prefix + g.name, hints[g.name], value, g.metadata.get("help", ""),
                                      g.metadata.get("bounds"), (kind_of(cls),), g.metadata.get("keyed", True))
    return list(specs.values())


def param_specs(params_cls: type, prefix: str = "") -> list[ParamSpec]:
    """Every parameter of ``params_cls``, groups flattened into dotted names, in declaration order."""
    hints = typing.get_type_hints(params_cls)
    specs = []
    for f in dataclasses.fields(params_cls):
        if union_members(f) is not None:
            specs.extend(_union_specs(f, f"{prefix}{f.name}."))
        elif is_group(hints[f.name]):
            specs.extend(param_specs(hints[f.name], f"{prefix}{f.name}."))
        else:
            specs.append(ParamSpec(prefix + f.name, hints[f.name], _default(f), f.metadata.get("help", ""),
                                   f.metadata.get("bounds"), keyed=f.metadata.get("keyed", True)))
    return specs


def cache_view(params: Any) -> dict[str, Any]:
    """``params_to_dict(params)`` without the parameters declared ``keyed=False``: what a stage's cache key
    hashes, so that a setting that cannot change a result reruns nothing."""
    values = params_to_dict(params)
    for spec in param_specs(type(params)):
        if not spec.keyed:
            *groups, name = spec.name.split(".")
            inner = values
            for group in groups:
                inner = inner.get(group, {})
            inner.pop(name, None)
    return values


def params_to_dict(params: Any) -> dict[str, Any]:
    return dataclasses.asdict(params)


def flatten(values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested parameter dictionary (``params_to_dict``) as dotted names -> values."""
    flat: dict[str, Any] = {}
    for name, value in values.items():
        if isinstance(value, Mapping):
            flat.update(flatten(value, f"{prefix}{name}."))
        else:
            flat[prefix + name] = value
    return flat


def _deprecated(message: str, _said: set[str] = set()) -> None:
    """Say ``message`` once per process (parameters are built more than once in a run)."""
    if message not in _said:
        _said.add(message)
        log.warning("%s", message)


def _union_member(f: dataclasses.Field, inner: dict[str, Any], built: Mapping[str, Any]) -> Any:
    """The union group ``f`` from its typed values ``inner``: the class its ``kind`` names (``auto``, or none
    given with an ``auto`` rule: the rule's, from the groups ``built`` before it), refusing another kind's
    settings by name."""
    members, default, rule = union_members(f), _default(f), f.metadata.get("auto")
    kind = inner.pop("kind", "auto" if rule else default.kind)
    if kind == "auto":
        if rule is None:
            raise ValueError(f"kind must be one of {', '.join(members)}, got 'auto'")
        kind = rule(built)
    cls = members[kind]
    own = {g.name for g in dataclasses.fields(cls)}
    for name in inner:
        if name not in own:
            owners = [k for k, c in members.items() if name in {g.name for g in dataclasses.fields(c)}]
            raise ValueError(f"{name} is a setting of the {' and '.join(owners)} {f.name} kind, and {f.name}.kind "
                             f"is {kind}: set {f.name}.kind too")
    return default if not inner and isinstance(default, cls) else cls(**inner)


def _instantiate(params_cls: type, values: Mapping[str, Any]) -> Any:
    """``params_cls`` from typed dotted values, its groups built from theirs (a group's __post_init__ runs first)."""
    hints = typing.get_type_hints(params_cls)
    kwargs: dict[str, Any] = {}
    fields = dataclasses.fields(params_cls)
    for i, f in enumerate(fields):
        if union_members(f) is not None:
            head = f.name + "."
            inner = {name[len(head):]: v for name, v in values.items() if name.startswith(head)}
            if inner or f.metadata.get("auto"):  # an ``auto`` rule reads the groups before it, as built or default
                built = {g.name: kwargs[g.name] if g.name in kwargs else _default(g) for g in fields[:i]}
                try:
                    kwargs[f.name] = _union_member(f, inner, built)
                except ValueError as err:
                    raise ValueError(f"{f.name}.{err}") from None
        elif is_group(hints[f.name]):
            head = f.name + "."
            inner = {name[len(head):]: v for name, v in values.items() if name.startswith(head)}
            if inner:
                try:
                    kwargs[f.name] = _instantiate(hints[f.name], inner)
                except ValueError as err:  # name the group: "field.levels must be >= 1"
                    raise ValueError(f"{f.name}.{err}") from None
        elif f.name in values:
            kwargs[f.name] = values[f.name]
    return params_cls(**kwargs)


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
        if {"on", "off"} <= set(choices):  # a switch: the spellings it had before Auto
            if isinstance(value, bool):  # YAML reads on / off as booleans
                return "on" if value else "off"
            text = str(value).strip().lower()
            if text in _TRUE | _FALSE:
                new = "on" if text in _TRUE else "off"
                _deprecated(f"{qualname}={value}: the switches now read auto, on or off; taken as {qualname}={new}")
                return new
        allowed = ", ".join(str(c) for c in choices)
        raise ParamError(f"{qualname}: {_clip(value)} is not one of {allowed}")
    if inner is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.strip().lower() in _TRUE | _FALSE:
            return value.strip().lower() in _TRUE
        raise ParamError(f"{qualname}: expected true or false, got {_clip(value)}")
    if inner is int:
        if isinstance(value, bool):
            raise ParamError(f"{qualname}: expected an integer, got {_clip(value)}")
        if isinstance(value, int):
            return value
        try:
            return int(str(value).strip())
        except ValueError:
            raise ParamError(f"{qualname}: expected an integer, got {_clip(value)}") from None
    if inner is float:
        try:
            if isinstance(value, bool):
                raise ValueError
            number = float(value) if isinstance(value, (int, float)) else float(str(value).strip())
        except (ValueError, OverflowError):  # OverflowError: an integer beyond any float
            raise ParamError(f"{qualname}: expected a number, got {_clip(value)}") from None
        if not math.isfinite(number):
            raise ParamError(f"{qualname}: expected a finite number, got {_clip(value)}")
        return number
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
    """Defaults, then the named preset (if this stage has it), then overrides; checked and typed.

    Parameters are named by their dotted paths (``field.levels``); a retired name in the params class's
    ``ALIASES`` is taken as its new path (and, where the alias is ``(path, {old value: new value})``, its
    value translated), with a deprecation message."""
    specs = {s.name: s for s in param_specs(params_cls)}
    aliases: Mapping[str, str] = getattr(params_cls, "ALIASES", {})
    values: dict[str, Any] = {}
    if preset is not None and preset in presets:
        values.update(presets[preset])
    for name, raw in overrides.items():
        if name not in specs and name in aliases:
            new, values_of = aliases[name] if isinstance(aliases[name], tuple) else (aliases[name], {})
            text = str(raw).strip().lower()
            shown = f"{stage}.{new}" + (f"={values_of[text]}" if text in values_of else "")
            _deprecated(f"{stage}.{name} is now {shown}; the old name still works for now")
            name, raw = new, values_of.get(text, raw)
        if name not in specs:
            close = difflib.get_close_matches(name, list(specs), n=1)
            hint = f"did you mean {stage}.{close[0]}?" if close else f"{stage} has: {', '.join(specs)}"
            raise ParamError(f"unknown parameter {stage}.{name}; {hint}")
        values[name] = raw
    typed = {name: coerce(v, specs[name].type, f"{stage}.{name}") for name, v in values.items()}
    for name, value in typed.items():
        specs[name].check_bounds(value, f"{stage}.{name}")
    try:
        return _instantiate(params_cls, typed)
    except ValueError as err:
        raise ParamError(f"{stage}: {err}") from None


def override(params: Any, values: Mapping[str, Any]) -> Any:
    """``params`` with the parameters named by dotted paths in ``values`` replaced (Python values, unchecked
    beyond each dataclass's own ``__post_init__``)."""
    own: dict[str, Any] = {}
    groups: dict[str, dict[str, Any]] = {}
    for name, value in values.items():
        head, dot, rest = name.partition(".")
        if dot:
            groups.setdefault(head, {})[rest] = value
        else:
            own[name] = value
    for head, inner in groups.items():
        member = next(f for f in dataclasses.fields(params) if f.name == head)
        members = union_members(member)
        if members is not None and "kind" in inner and inner["kind"] != getattr(params, head).kind:
            rest = {k: v for k, v in inner.items() if k != "kind"}
            own[head] = members[inner["kind"]](**rest)  # another kind: its own defaults, then these
        else:
            own[head] = override(getattr(params, head), inner)
    return dataclasses.replace(params, **own)


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
    """``["ingest.max_size 1600 -> 800", ...]`` for every parameter whose value differs (groups by dotted name)."""
    old, new = flatten(old), flatten(new)
    changes = []
    for name in sorted(set(old) | set(new)):
        if old.get(name, "<unset>") != new.get(name, "<unset>"):
            changes.append(f"{stage}.{name} {_show(old.get(name, '<unset>'))} -> {_show(new.get(name, '<unset>'))}")
    return changes


def _clip(value: Any, keep: int = 40) -> str:
    """``repr(value)``, a long one cut to its first ``keep`` characters and its length: a 5000-digit number is
    named, not printed."""
    text = repr(value)
    return text if len(text) <= keep else f"{text[:keep]}... ({len(text)} characters)"


def _show(value: Any) -> str:
    if isinstance(value, float) and (abs(value) >= 1e6 or 0 < abs(value) < 1e-3):
        return f"{value:g}"
    return "none" if value is None else str(value).lower() if isinstance(value, bool) else str(value)
