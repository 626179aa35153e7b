"""A job's time budget: durations, the elastic stage's remainder, the shares, and the cache keys."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import ClassVar

import pytest

from nerfpipe.pipeline import ParamError, Pipeline, Stage, StageError
from nerfpipe.pipeline.budget import (Allotment, FloorWork, JobBudget, format_duration, parse_duration, price_floors,
                                      takes_part)
from nerfpipe.stages.ingest import IngestStage


@pytest.mark.parametrize("text, seconds", [("10m", 600.0), ("90s", 90.0), ("1.5h", 5400.0), ("600", 600.0),
                                           ("2 min", 120.0), (" 4M ", 240.0), ("auto", "auto"), ("off", None)])
def test_durations_read_as_users_write_them(text, seconds):
    assert parse_duration(text) == seconds


def test_durations_read_as_people_say_them():
    assert [format_duration(s) for s in (44.4, 60, 205, 600)] == ["44 s", "1 min", "3 min 25 s", "10 min"]


@pytest.mark.parametrize("text", ["ten minutes", "0", "-5m", "5d", "", "1e9999"])
def test_a_duration_that_is_no_duration_is_one_line_naming_it(text):
    with pytest.raises(ParamError, match="--budget"):
        parse_duration(text)


def test_the_elastic_stage_gets_the_budget_less_what_was_spent_and_the_later_shares():
    now = [1000.0]
    job = JobBudget(100.0, clock=lambda: now[0])
    now[0] += 30.0  # the job has spent 30 s
    # 100 s - 30 s spent - (10 % + 20 %) of 100 s for the stages after it
    assert job.elapsed() == 30.0 and job.remainder([0.1, 0.2]) == 40.0
    assert job.share(0.25) == 25.0
    assert JobBudget(10.0, clock=lambda: now[0], started=now[0] - 30.0).remainder([0.5]) == 0.0  # overspent: never less
    # a stage with a share of 10 % finds 100 - 30 - (10 + 20) = 40 s saved beyond its own share and the later ones
    assert job.spare(0.1, [0.2]) == 40.0
    now[0] += 50.0  # 80 s spent: 20 s left, less than the 30 s the two shares keep, so nothing is spare
    assert job.spare(0.1, [0.2]) == 0.0


def test_auto_is_sized_once_by_the_callers_rule():
    calls = []
    job = JobBudget("auto", resolve=lambda: calls.append(1) or 240.0)
    assert job.seconds == 240.0 and job.seconds == 240.0 and calls == [1]
    with pytest.raises(ParamError, match="auto"):
        _ = JobBudget("auto").seconds


def test_a_chosen_elastic_parameter_stops_the_stage_taking_the_rest():
    assert takes_part(0.0, ("seconds", "steps"), []) == (True, True)
    assert takes_part(0.0, ("seconds", "steps"), ["steps", "lr"]) == (False, False)
    assert takes_part(0.1, (), ["scale"]) == (True, False)
    assert takes_part(0.0, (), []) == (False, False)
    assert Allotment(10.0, 100.0).describe() == "10 s (10% of the 1 min 40 s budget)"
    assert Allotment(10.0, 100.0, spare=75.0).describe() == ("10 s (10% of the 1 min 40 s budget, and 1 min 15 s the "
                                                             "stages before it saved)")


@dataclass(frozen=True)
class SleepParams:
    seconds: float = 0.0
    size: int = 1


class Recorder(Stage):
    """Records the allotment it was given; sleeps ``seconds`` first."""

    version = 1
    Params = SleepParams
    seen: ClassVar[dict[str, Allotment | None]] = {}
    later: ClassVar[dict[str, tuple]] = {}

    def __init__(self, name: str, requires: tuple[str, ...], share: float = 0.0, elastic: tuple[str, ...] = ()) -> None:
        self.name, self.requires, self.budget_share, self.elastic = name, requires, share, elastic
        self.provides = {name: f"{name}.json"}

    def run(self, inputs, out, params, ctx):
        Recorder.seen[self.name] = ctx.allotment
        Recorder.later[self.name] = tuple((s.name, s.seconds) for s in ctx.later)
        time.sleep(params.seconds)
        (out / f"{self.name}.json").write_text("{}")
        return {}


def stages() -> list[Stage]:
    return [IngestStage(), Recorder("slow", ("images_json",)), Recorder("train", ("slow",), elastic=("seconds",)),
            Recorder("render", ("train",), share=0.1), Recorder("mesh", ("train",), share=0.05)]


def test_stages_get_their_part_of_the_job_and_the_budget_enters_only_their_keys(capture, tmp_path):
    run_dir = tmp_path / "run"
    Recorder.seen.clear()
    pipe = Pipeline(stages(), capture, run_dir, overrides={"slow": {"seconds": "0.5"}}, budget=20.0)
    pipe.run()
    train, render, mesh = (Recorder.seen[n] for n in ("train", "render", "mesh"))
    assert (render.seconds, render.budget, mesh.seconds, mesh.budget) == (2.0, 20.0, 1.0, 20.0)
    # 20 s less what ingest and slow spent (at least the 0.5 s slept), less render's 2 s and mesh's 1 s
    assert train.elastic and 15.0 < train.seconds <= 16.5
    # the elastic stage here took nothing of it: the stages after it find it saved, beyond their shares, for floors
    assert train.seconds - 0.5 < render.spare <= train.seconds and render.spare - 0.5 < mesh.spare <= render.spare + 2.0
    # the elastic stage knows the stages still to come with a share, and their seconds (to ask for their floors)
    assert Recorder.later == {"slow": (), "train": (("render", 2.0), ("mesh", 1.0)), "render": (), "mesh": ()}
    assert Recorder.seen["slow"] is None and json.loads((run_dir / "run.json").read_text())["budget"] == 20.0
    manifest = json.loads((pipe.result("render").path / "manifest.json").read_text())
    assert manifest["budget"] == 20.0 and manifest["timings"]["allotted"] == 2.0
    assert manifest["timings"]["spare"] == round(render.spare, 2)  # what it could take for a floor, for the report

    other = Pipeline(stages(), capture, run_dir, overrides={"slow": {"seconds": "0.5"}}, budget=30.0)
    changed = {n for n in other.plan() if other.plan()[n].key != pipe.plan()[n].key}
    assert changed == {"train", "render", "mesh"}
    assert next(s for s in other.status() if s.name == "train").reasons == ("budget changed: 20.0 -> 30.0",)
    assert Pipeline.from_run_dir(stages(), run_dir).plan()["train"].key == pipe.plan()["train"].key

    fixed = Pipeline(stages(), capture, run_dir, overrides={"slow": {"seconds": "0.5"}, "train": {"seconds": "3"}},
                     budget=20.0)
    assert "budget" not in fixed.plan()["train"].material and not fixed.plan()["train"].elastic
    Recorder.seen.clear()
    fixed.run()
    assert Recorder.seen["train"] is None and Recorder.seen["render"].seconds == 2.0
    # the train stage slept its 3 s: 20 s less ingest's and slow's (0.5 s and more), train's 3 s and both shares
    assert 13.0 < Recorder.seen["render"].spare <= 14.5


def test_auto_asks_the_rule_when_a_stage_first_needs_its_allotment(capture, tmp_path):
    asked = []
    Recorder.seen.clear()
    pipe = Pipeline(stages(), capture, tmp_path / "run", budget="auto",
                    budget_rule=lambda p: asked.append(p.result("ingest") is not None) or 50.0)
    pipe.run()
    assert asked == [True] and (Recorder.seen["render"].seconds, Recorder.seen["render"].budget) == (5.0, 50.0)
    assert pipe.plan()["render"].material["budget"] == "auto"


class NoSurface(Recorder):
    optional = True

    def run(self, inputs, out, params, ctx):
        from nerfpipe.pipeline import StageError

        raise StageError(f"{self.name}: found no surface; lower the threshold")


def test_an_optional_stage_that_makes_nothing_warns_and_the_run_goes_on(capture, tmp_path, caplog):
    stages = [IngestStage(), NoSurface("mesh", ("images_json",)), Recorder("screenshot", ("mesh",)),
              Recorder("render", ("images_json",))]
    outcomes = Pipeline(stages, capture, tmp_path / "run").run()
    assert [(o.name, o.action) for o in outcomes] == [("ingest", "ran"), ("mesh", "failed"), ("screenshot", "skipped"),
                                                      ("render", "ran")]
    assert outcomes[1].reasons == ("mesh: found no surface; lower the threshold",)
    assert "mesh: found no surface; lower the threshold (the run goes on without it)" in caplog.text
    assert "screenshot: skipped, since mesh made nothing" in caplog.text
    required = [IngestStage(), Recorder("slow", ("images_json",)), NoSurface("mesh", ("slow",))]
    required[2].optional = False
    with pytest.raises(StageError, match="found no surface"):
        Pipeline(required, capture, tmp_path / "run2").run()


def test_fit_to_allotment_shrinks_to_the_allotment_and_never_below_the_floor() -> None:
    from nerfpipe.pipeline.budget import Fit, fit_to_allotment

    # 100 s at full size, 1 s whatever the size
    assert fit_to_allotment(100.0, None, 0.25, 1.0) == Fit(1.0, 101.0)  # no budget: as asked
    assert fit_to_allotment(100.0, 500.0, 0.25, 1.0) == Fit(1.0, 101.0)  # fits as asked
    # 26 s: sqrt(25 / 100) = 0.5 of each side, 25 + 1 s
    assert fit_to_allotment(100.0, 26.0, 0.25, 1.0) == Fit(0.5, 26.0)
    # 20 s: sqrt(19 / 100) = 0.4359, rounded down to 0.43
    fit = fit_to_allotment(100.0, 20.0, 0.25, 1.0)
    assert fit.scale == 0.43 and fit.seconds == pytest.approx(100 * 0.43**2 + 1) and fit.over == 0.0
    # 2 s: the floor, a quarter of each side, 7.25 s: 5.25 s more than the allotment
    fit = fit_to_allotment(100.0, 2.0, 0.25, 1.0)
    assert fit == Fit(0.25, 7.25, 5.25)
    line = fit.longer("render: 40 frames", Allotment(2.0, 20.0))
    assert line == ("render: 40 frames takes about 7 s, 5 s more than its 2 s (10% of the 20 s budget): the job takes "
                    "that much longer rather than make it smaller (a larger --budget, or --budget off, runs it as set)")
    assert fit_to_allotment(100.0, 26.0, 0.25, 1.0).longer("x", Allotment(26.0, 260.0)) is None
    # a floor of 1 (the size asked for is already the smallest useful one) never shrinks; spent time counts as 0
    assert fit_to_allotment(100.0, -3.0, 1.0) == Fit(1.0, 100.0, 100.0)


def test_a_floor_takes_what_the_stages_before_saved_and_no_output_grows_with_it() -> None:
    from nerfpipe.pipeline.budget import Fit, fit_to_allotment

    # the floor's 7.25 s against 2 s of share: 4 s saved before pay for 4 of the 5.25 s over, 10 s for all of it
    assert fit_to_allotment(100.0, 2.0, 0.25, 1.0, spare=4.0) == Fit(0.25, 7.25, 1.25)
    assert fit_to_allotment(100.0, 2.0, 0.25, 1.0, spare=10.0) == Fit(0.25, 7.25, 0.0)
    assert fit_to_allotment(100.0, 2.0, 0.25, 1.0, spare=10.0).longer("x", Allotment(2.0, 20.0, spare=10.0)) is None
    # an output that fits its share above its floor is sized to the share alone, however much was saved
    assert fit_to_allotment(100.0, 26.0, 0.25, 1.0, spare=1000.0) == Fit(0.5, 26.0)


def test_a_stage_fits_what_is_left_of_its_allotment_and_what_was_saved_before_it() -> None:
    from nerfpipe.pipeline.budget import Fit, fit_within

    assert fit_within(None, 5.0, 100.0, 0.25, 1.0) == Fit(1.0, 101.0)  # no budget: as asked, whatever it spent
    assert fit_within(Allotment(30.0, 300.0), 4.0, 100.0, 0.25, 1.0) == Fit(0.5, 26.0)  # 26 s left of 30
    assert fit_within(Allotment(6.0, 60.0, spare=4.0), 4.0, 100.0, 0.25, 1.0) == Fit(0.25, 7.25, 1.25)


def test_each_floor_is_priced_at_the_rate_it_names() -> None:
    plain = FloorWork(100.0, 1.0, "the plain one")  # the elastic stage's own rate
    wide = FloorWork(100.0, 0.0, "the wide one", rate="scene")
    rates = {None: 0.01, "scene": 0.05}
    priced = price_floors([(plain, 3.0), (wide, 1.0)], rates.__getitem__, 60.0)
    # 100 x 0.01 + 1 = 2 s within its 3; 100 x 0.05 = 5 s, 4 over its 1: 7 s where 4 are kept, 3 over in all
    assert (priced.need, priced.kept, priced.over, priced.given, priced.longer) == (7.0, 4.0, 3.0, 0.0, 3.0)
    assert priced.line("training") == (
        "budget: the outputs at their floors take about 7 s, where the 1 min budget keeps 4 s for them (the wide one, "
        "4 s over): the job takes about 3 s longer rather than make them smaller (a larger --budget, or --budget off, "
        "runs them as set)")
    # one number prices every floor alike
    fits = price_floors([(plain, 3.0), (wide, 1.0)], 0.01, 60.0)
    assert fits.over == 0.0 and fits.line("training") == (
        "budget: the outputs at their floors take about 3 s of the 4 s the 1 min budget keeps for them")
    # one over its part while another leaves more of its own unspent: the time passes on, and they fit together
    assert price_floors([(plain, 6.0), (wide, 2.0)], rates.__getitem__, 60.0).over == 0.0


def test_the_elastic_stage_gives_the_floors_what_they_lack_up_to_what_it_can_spare() -> None:
    video = FloorWork(1000.0, 0.0, "the video")
    # 1000 x 0.1 = 100 s against 40 kept: 60 s over; training can spare 90 s, and gives the 60
    enough = price_floors([(video, 40.0)], 0.1, 300.0, spare=90.0)
    assert (enough.over, enough.given, enough.longer) == (60.0, 60.0, 0.0)
    assert enough.line("training") == (
        "budget: the outputs at their floors take about 1 min 40 s, where the 5 min budget keeps 40 s for them (the "
        "video, 1 min over): training gives them 1 min of its time, so the job keeps its budget")
    # it can spare 45 s: it gives those, and the job takes the other 15 s longer
    short = price_floors([(video, 40.0)], 0.1, 300.0, spare=45.0)
    assert (short.given, short.longer) == (45.0, 15.0)
    assert short.line("training").endswith(
        "(the video, 1 min over): training gives them 45 s of its time, the most it gives, and the job takes about "
        "15 s longer rather than make them smaller (a larger --budget, or --budget off, runs them as set)")
    # outputs that fit take nothing from it
    assert price_floors([(video, 200.0)], 0.1, 300.0, spare=90.0).given == 0.0
