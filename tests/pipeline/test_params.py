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


# -- tagged unions and settings kept out of the cache key ----------------------------------------------------
@dataclass(frozen=True)
class Dense:
    kind: str = "dense"
    cells: int = param(8, "cells a side", bounds=(1, 64))
    shared: float = param(0.5, "a setting both kinds have")


@dataclass(frozen=True)
class Sparse:
    kind: str = "sparse"
    rows: int = param(100, "rows of its table", bounds=(1, 1000))
    shared: float = param(0.5, "a setting both kinds have")


@dataclass(frozen=True)
class Walker:
    kind: str = "walker"
    steps: int = param(4, "steps")


@dataclass(frozen=True)
class Chooser:
    kind: str = "chooser"


def part_kinds() -> dict[str, type]:
    return {"dense": Dense, "sparse": Sparse}


@dataclass(frozen=True)
class Job:
    part: Dense = param(Dense(), "the part", union=part_kinds)
    walk: Walker = param(Walker(), "how it walks", union=lambda: {"walker": Walker, "chooser": Chooser},
                         auto=lambda built: "chooser" if built["part"].kind == "sparse" else "walker")
    chunk: int = param(64, "rows at a time: cannot change a result", bounds=(1, 4096), keyed=False)


def test_a_union_lists_each_kinds_settings_once_with_its_kinds() -> None:
    specs = {s.name: s for s in param_specs(Job)}
    assert list(specs) == ["part.kind", "part.cells", "part.shared", "part.rows", "walk.kind", "walk.steps", "chunk"]
    assert specs["part.kind"].choices == ("dense", "sparse") and specs["part.kind"].default == "dense"
    assert specs["part.shared"].kinds == ("dense", "sparse") and specs["part.rows"].kinds == ("sparse",)
    assert specs["walk.kind"].choices == ("auto", "walker", "chooser") and specs["walk.kind"].default == "auto"
    assert specs["chunk"].keyed is False and specs["part.cells"].keyed is True


def test_the_kind_picks_the_class_and_another_kinds_setting_is_refused_by_name() -> None:
    job = build_params("job", Job, {}, None, {"part.kind": "sparse", "part.rows": "7"})
    assert job.part == Sparse(rows=7) and job.walk == Chooser()  # auto: the rule, from the part built before it
    assert build_params("job", Job, {}, None, {}).walk == Walker()
    assert build_params("job", Job, {}, None, {"walk.kind": "walker", "part.kind": "sparse"}).walk == Walker()
    with pytest.raises(ParamError, match=r"^job: part.rows is a setting of the sparse part kind, and part.kind is "
                                         r"dense: set part.kind too$"):
        build_params("job", Job, {}, None, {"part.rows": "7"})
    with pytest.raises(ParamError, match=r"job.part.rows: 5000 is outside its bounds \[1, 1000\]"):
        build_params("job", Job, {}, None, {"part.kind": "sparse", "part.rows": "5000"})
    with pytest.raises(ParamError, match=r"job.part.kind: 'tree' is not one of dense, sparse"):
        build_params("job", Job, {}, None, {"part.kind": "tree"})
    # override switches kinds from the new kind's own defaults
    assert override(Job(), {"part.kind": "sparse", "part.shared": 0.25}).part == Sparse(shared=0.25)
    assert override(Job(), {"part.cells": 16}).part == Dense(cells=16)


def test_a_setting_declared_unkeyed_stays_out_of_the_cache_view() -> None:
    from nerfpipe.pipeline.params import cache_view

    job = build_params("job", Job, {}, None, {"chunk": "8"})
    assert cache_view(job) == {"part": {"kind": "dense", "cells": 8, "shared": 0.5},
                               "walk": {"kind": "walker", "steps": 4}}
    assert cache_view(job) == cache_view(Job())
