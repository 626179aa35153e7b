"""Declared bounds, memory-aware sizes and costs beyond the budget, by hand: the outside pass's cases 10-25,
each refused in one line before anything runs."""

from __future__ import annotations

import pytest

from nerfpipe.pipeline import ParamError
from nerfpipe.pipeline.budget import Allotment, check_affordable, parse_duration
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.params import build_params, param_specs
from nerfpipe.pipeline.resources import memory_limit
from nerfpipe.pipeline.run_config import run_command
from nerfpipe.stages import default_stages

STAGES = {s.name: s for s in default_stages()}


def build(stage: str, name: str, value: str):
    s = STAGES[stage]
    return build_params(stage, s.Params, s.presets, None, {name: value})


@pytest.mark.parametrize(("stage", "name", "value", "needle"), [
    ("train", "field.levels", "1e20", "train.field.levels: expected an integer, got '1e20'"),  # 10: hung
    ("export_mesh", "resolution", "1e20", "expected an integer"),  # 11: hung, "about 1.7e53 s"
    ("export_mesh", "resolution", "100000", "export_mesh.resolution: 100000 is outside its bounds [8, 2048]"),
    ("export_mesh", "poisson_depth", "30", "poisson_depth: 30 is outside its bounds [1, 11]"),  # 12: segfault
    ("export_mesh", "texture", "100000", "texture: 100000 is outside its bounds [0, 8192]"),  # 13: 6.3 GB
    ("train", "field.max_resolution", "4096", "field.max_resolution, levels, features: the feature tables"),  # 14
    ("train", "field.features", "100000000000000000000", "is outside its bounds [1, 64]"),  # 15
    ("train", "sampler.occupancy_resolution", "100000000000000000000", "outside its bounds [1, 1024]"),  # 16
    ("train", "optim.batch_rays", "100000000000000000000", "outside its bounds [1, 1048576]"),  # 17
    ("train", "field.pos_freqs", "100000", "pos_freqs: 100000 is outside its bounds [0, 24]"),  # 18: 157 GB
    ("train", "optim.lr", "1e12", "train.optim.lr: 1e+12 is outside its bounds [1e-08, 10]"),  # 19
    ("export_points", "outlier_neighbors", "0", "outlier_neighbors: 0 is outside its bounds [1, 1000]"),  # 20
    ("render", "fps", "1e12", "render.fps: 1e+12 is outside its bounds [1, 240]"),  # 21: OverflowError
    ("sfm", "max_features", "-1", "sfm.max_features: -1 is outside"),  # 22
    ("sfm", "max_image_size", "100000000000000000000", "sfm.max_image_size: 100000000000000000000 is outside"),  # 23
    ("sfm", "seed", "-1", "sfm.seed: -1 is outside its bounds [0, 2147483647]"),  # 24
    ("sfm", "exhaustive_max", "-1", "sfm.exhaustive_max: -1 is outside"),  # weak
    ("ingest", "max_megapixels", "1e-7", "is below one pixel; use 0 for no limit"),  # weak: rounded to no limit
    ("train", "optim.lr", "nan", "expected a finite number"),
    ("train", "seconds", str(10**400), "train.seconds: expected a finite number, got '1000000000"),  # beyond any float
])
def test_the_outside_pass_parameter_cases_are_refused_in_one_line(stage, name, value, needle) -> None:
    with pytest.raises(ParamError) as err:
        build(stage, name, value)
    assert needle in str(err.value) and "\n" not in str(err.value)


# a bound that holds only beside another setting's value: each end is refused with the default of the other
PAIRED = {("bounds", "near_percentile"), ("bounds", "far_percentile"), ("train", "field.min_resolution"),
          ("train", "field.max_resolution"), ("train", "field.skip_after"), ("export_points", "agree_views"),
          ("export_points", "neighbours")}


def _ends():
    for s in default_stages():
        for spec in param_specs(s.Params):
            if spec.bounds is not None and spec.is_number:
                group = spec.name.rsplit(".", 1)[0]
                kind = {f"{group}.kind": spec.kinds[0]} if spec.kinds else {}  # a setting of one kind of a union
                for end in spec.bounds:
                    yield s.name, spec.name, {**kind, spec.name: repr(end) if isinstance(end, float) else str(end)}


@pytest.mark.parametrize(("stage", "name", "values"), list(_ends()), ids=lambda v: v if isinstance(v, str) else "")
def test_both_ends_of_every_declared_bound_are_accepted(stage, name, values) -> None:
    """The bounds `nerfpipe stages` and docs/parameters.md show are "both allowed": a stage's own checks must not
    refuse them (margin's [0, 10] was refused above 1). Only a bound paired with another setting, or the memory a
    size takes on this machine, may refuse an end, each in its one line."""
    s = STAGES[stage]
    try:
        build_params(stage, s.Params, s.presets, None, values)
    except ParamError as err:
        assert (stage, name) in PAIRED or "this machine allows" in str(err), str(err)


def test_the_memory_checks_follow_the_process_limit(monkeypatch) -> None:
    """At 2 GB (a cluster job's limit) the finest level that fits is smaller than on the whole machine."""
    import nerfpipe.pipeline.resources as resources

    assert build("train", "field.max_resolution", "512").field.max_resolution == 512 or memory_limit() < 40 << 30
    monkeypatch.setattr(resources, "memory_limit", lambda: 2 << 30)
    with pytest.raises(ParamError, match="more than the 1.1 GB this machine allows them"):
        build("train", "field.max_resolution", "512")  # 3 levels to 512: 2.2 GB of tables while training
    assert build("train", "field.max_resolution", "192").field.max_resolution == 192


def test_a_cost_beyond_the_whole_budget_is_refused_and_none_without_a_budget() -> None:
    with pytest.raises(StageError, match=r"export_mesh: marching cubes would take about 16 min 40 s, more than the "
                                         r"job's whole budget of 4 min; lower it, or pass --budget off"):
        check_affordable(Allotment(30.0, 240.0), 1000.0, "export_mesh: marching cubes", "lower it")
    check_affordable(Allotment(30.0, 240.0), 200.0, "x", "y")  # over its share, within the budget: it fits itself
    check_affordable(None, 1e9, "x", "y")  # --budget off


def test_budgets_past_a_week_are_refused() -> None:
    assert parse_duration("7d".replace("d", "h")) == 7 * 3600.0
    with pytest.raises(ParamError, match="at most 10080 min"):
        parse_duration("99999999999999999999")


def test_the_command_a_message_suggests_keeps_the_runs_settings() -> None:
    from pathlib import Path

    command = run_command(Path("my photos"), Path("runs/a"), "draft", {"train": {"field.levels": "4"}}, 600.0,
                          until="train")
    assert command == ("nerfpipe run 'my photos' --out runs/a --preset draft --set train.field.levels=4 "
                       "--budget 600 --until train")
    assert run_command(Path("p"), Path("r"), None, {}, None) == "nerfpipe run p --out r --budget off"
