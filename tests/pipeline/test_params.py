from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Optional

import pytest

from nerfpipe.pipeline.errors import ParamError
from nerfpipe.pipeline.params import build_params, coerce, describe_changes, param_specs, parse_assignments


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
