from __future__ import annotations

from dataclasses import dataclass

import pytest

from nerfpipe.pipeline import Dag, ParamError, Stage


@dataclass(frozen=True)
class NoParams:
    pass


def make(name, requires=(), provides=()):
    return type(name, (Stage,), {"name": name, "version": 1, "Params": NoParams,
                                 "requires": tuple(requires), "provides": {p: p for p in provides}})()


def test_order_follows_artifacts_not_declaration():
    stages = [make("train", ["rays"], ["field"]), make("ingest", [], ["images"]), make("sfm", ["images"], ["rays"]),
              make("export", ["field", "images"], ["mesh"])]
    dag = Dag(stages)
    assert dag.order == ["ingest", "sfm", "train", "export"]
    assert dag.upstream["export"] == ["ingest", "train"]
    assert dag.ancestors("export") == {"ingest", "sfm", "train"}
    assert dag.descendants("sfm") == {"train", "export"}
    assert dag.select(until="sfm") == ["ingest", "sfm"]
    assert dag.select(only="train") == ["train"]


def test_invalid_graphs_are_refused():
    with pytest.raises(ValueError, match="cycle"):
        Dag([make("a", ["y"], ["x"]), make("b", ["x"], ["y"])])
    with pytest.raises(ValueError, match="which no stage provides"):
        Dag([make("a", ["nothing"], ["x"])])
    with pytest.raises(ValueError, match="provided by a and b"):
        Dag([make("a", [], ["x"]), make("b", [], ["x"])])
    with pytest.raises(ParamError, match="unknown stage 'zzz'; stages are: a"):
        Dag([make("a", [], ["x"])]).check_name("zzz")
