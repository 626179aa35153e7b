from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Literal, Optional

import pytest

from nerfpipe.pipeline.errors import ParamError
from nerfpipe.pipeline.params import (
    Auto,
    build_params,
    coerce,
    describe_changes,
    flatten,
    override,
    param,
    param_specs,
    params_to_dict,
    parse_assignments,
)


@dataclass(frozen=True)
class P:
    size: int = field(default=1600, metadata={"help": "longest side"})
    ratio: float = 0.5
    linear: bool = False
    mode: Literal["clip", "blend"] = "clip"
    label: Optional[str] = None

    def __post_init__(self) -> None:
        if self.size < 0:
            raise ValueError("size must be >= 0")


PRESETS = {"draft": {"size": 400}, "hdr": {"linear": True}}


def test_defaults_preset_then_overrides_in_that_order():
    assert build_params("s", P, PRESETS, None, {}) == P()
    assert build_params("s", P, PRESETS, "draft", {}).size == 400
    assert build_params("s", P, PRESETS, "draft", {"size": "800"}).size == 800
    # a preset this stage does not define leaves it at its defaults
    assert build_params("s", P, PRESETS, "paper", {}) == P()


@pytest.mark.parametrize(
    "text, tp, expected",
    [("800", int, 800), (" 2.5 ", float, 2.5), ("3", float, 3.0), ("yes", bool, True), ("OFF", bool, False),
     ("blend", Literal["clip", "blend"], "blend"), ("none", Optional[str], None), ("x", Optional[str], "x")],
)
def test_coerce_text(text, tp, expected):
    assert coerce(text, tp, "s.p") == expected
    assert type(coerce(text, tp, "s.p")) is type(expected)


@pytest.mark.parametrize(
    "text, tp, message",
    [("abc", int, "s.p: expected an integer, got 'abc'"), ("1.5", int, "expected an integer"),
     ("maybe", bool, "expected true or false"), ("x", float, "expected a number"),
     ("soft", Literal["clip", "blend"], "'soft' is not one of clip, blend")],
)
def test_coerce_rejects_with_the_parameter_named(text, tp, message):
    with pytest.raises(ParamError, match=message):
        coerce(text, tp, "s.p")


def test_unknown_parameter_suggests_the_close_one():
    with pytest.raises(ParamError, match=r"unknown parameter s.sise; did you mean s.size\?"):
        build_params("s", P, PRESETS, None, {"sise": "1"})
    with pytest.raises(ParamError, match="s has: size, ratio, linear, mode, label"):
        build_params("s", P, PRESETS, None, {"zzz": "1"})


def test_range_check_becomes_param_error():
    with pytest.raises(ParamError, match="s: size must be >= 0"):
        build_params("s", P, PRESETS, None, {"size": "-1"})


def test_parse_assignments():
    assert parse_assignments(["ingest.max_size=800", "ingest.alpha=mask", "train.lr=1e-3"]) == {
        "ingest": {"max_size": "800", "alpha": "mask"},
        "train": {"lr": "1e-3"},
    }
    assert parse_assignments(["a.b=x=y"]) == {"a": {"b": "x=y"}}
    for bad in ("max_size=800", "ingest.max_size", ".x=1", "ingest.=1"):
        with pytest.raises(ParamError, match="expected STAGE.PARAM=VALUE"):
            parse_assignments([bad])


def test_describe_changes_and_specs():
    assert describe_changes("ingest", {"max_size": 1600, "x": True}, {"max_size": 800, "x": True}) == [
        "ingest.max_size 1600 -> 800"
    ]
    assert describe_changes("s", {"linear": False}, {"linear": True}) == ["s.linear false -> true"]
    specs = {s.name: s for s in param_specs(P)}
    assert specs["size"].help == "longest side" and specs["size"].default == 1600
    assert specs["mode"].choices == ("clip", "blend") and specs["mode"].type_name == "clip|blend"
    assert specs["label"].type_name == "str or none"


@dataclass(frozen=True)
class Inner:
    levels: int = param(3, "levels of the grid")
    switch: Auto = param("auto", "a switch")

    def __post_init__(self) -> None:
        if self.levels < 1:
            raise ValueError(f"levels must be >= 1, got {self.levels}")


@dataclass(frozen=True)
class Outer:
    steps: int = param(10, "steps")
    rate: float = param(0.5, "a rate")
    inner: Inner = param(Inner(), "a group")

    ALIASES: ClassVar[dict] = {"grid_levels": "inner.levels", "old_switch": ("inner.switch", {"true": "on", "false": "off"})}


def test_groups_are_named_with_dots_and_built_nested():
    specs = [s.name for s in param_specs(Outer)]
    assert specs == ["steps", "rate", "inner.levels", "inner.switch"]
    built = build_params("s", Outer, {"p": {"inner.levels": 5}}, "p", {"inner.switch": "on", "steps": "4"})
    assert built == Outer(steps=4, inner=Inner(levels=5, switch="on"))
    assert params_to_dict(built) == {"steps": 4, "rate": 0.5, "inner": {"levels": 5, "switch": "on"}}
    assert flatten(params_to_dict(built)) == {"steps": 4, "rate": 0.5, "inner.levels": 5, "inner.switch": "on"}
    assert override(Outer(), {"inner.levels": 2, "rate": 0.25}) == Outer(rate=0.25, inner=Inner(levels=2))
    # a group's own check is named with its path
    with pytest.raises(ParamError, match=r"^s: inner.levels must be >= 1, got 0$"):
        build_params("s", Outer, {}, None, {"inner.levels": "0"})
    with pytest.raises(ParamError, match="unknown parameter s.inner.level; did you mean s.inner.levels?"):
        build_params("s", Outer, {}, None, {"inner.level": "2"})
    assert describe_changes("s", {"inner": {"levels": 3}}, {"inner": {"levels": 4}}) == ["s.inner.levels 3 -> 4"]


def test_retired_names_and_switch_spellings_still_work_and_say_so(caplog):
    with caplog.at_level("WARNING", logger="nerfpipe"):
        built = build_params("s", Outer, {}, None, {"grid_levels": "7", "old_switch": "true"})
    assert built.inner == Inner(levels=7, switch="on")
    assert "s.grid_levels is now s.inner.levels; the old name still works for now" in caplog.text
    assert "s.old_switch is now s.inner.switch=on" in caplog.text
    assert coerce("false", Auto, "s.x") == "off" and coerce("yes", Auto, "s.y") == "on"
    assert "s.x=false: the switches now read auto, on or off; taken as s.x=off" in caplog.text
    assert coerce(True, Auto, "s.yaml") == "on" and coerce(False, Auto, "s.yaml") == "off"  # YAML's on / off
    assert "s.yaml" not in caplog.text  # nothing to deprecate there
    with pytest.raises(ParamError, match="s.z: 'maybe' is not one of auto, on, off"):
        coerce("maybe", Auto, "s.z")


@pytest.mark.parametrize("text", ["nan", "inf", "-inf", "NaN"])
def test_numbers_must_be_finite(text):
    with pytest.raises(ParamError, match=f"s.rate: expected a finite number, got '{text}'"):
        build_params("s", Outer, {}, None, {"rate": text})
    with pytest.raises(ParamError, match="expected a finite number"):
        coerce(float(text), float, "s.rate")
