"""Floors under a busy machine: early in training, one line says whether the outputs fit the budget at their floors,
or how much longer the job will take; the cost of rendering is injected, as a slow machine would measure it."""

from __future__ import annotations

import logging
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

import nerfpipe.nerf.train.floors as floors
from nerfpipe.nerf.policy import build_model
from nerfpipe.nerf.train.images import Views
from nerfpipe.pipeline.budget import format_duration
from nerfpipe.pipeline.stage import LaterStage
from nerfpipe.stages import ExportDepthParams, ExportDepthStage, RenderParams, RenderStage, TrainParams
from tests.nerf.scenes import loader_of, write_image_folders


def per_ray(seconds: float):
    """The injected cost model: a view of w x h pixels takes ``seconds`` a ray."""
    return lambda model, intrinsics, c2w, width, height, *rest: seconds * width * height


@pytest.fixture
def job(tmp_path: Path):
    """Three 12x8 photos, the first held out; the video (5 s of the budget) and the depth maps (3 s) still to come."""
    loader = loader_of(write_image_folders(tmp_path))
    model, _ = build_model(TrainParams(), loader.scene, loader.world, loader.bounds, torch.device("cpu"))
    frames = loader.world.frames
    views = Views(train=frames[1:], heldout=frames[:1], rule="the first")
    later = (LaterStage(RenderStage(), RenderParams(), 5.0), LaterStage(ExportDepthStage(), ExportDepthParams(), 3.0))
    return model, loader, views, later


def test_a_slow_machine_is_told_how_much_longer_the_job_takes_at_the_floors(job, monkeypatch) -> None:
    model, loader, views, later = job
    # the injected cost model: 1.2 microseconds a ray
    monkeypatch.setattr(floors, "seconds_per_view", per_ray(1.2e-6))
    priced = floors.floor_check(model, loader, views, (0.5, 1.0), later, 100.0, 4096)
    line, over = priced.line("training"), priced.over
    # the video: 360 px on the short side of 12x8 photos is 540x360, 45 frames, their rays plus 0.025 s a frame:
    # 45 x 540 x 360 x 1.2e-6 + 1.125 = 11.62 s, 6.62 s over its 5 s; the evaluation (one view at 6x4, 24 rays) and
    # the depth maps (three at a quarter of 12x8, 3x2, 1.15 x 18 rays) cost microseconds and fit their 1 s and 3 s
    # the 4 s the other two leave of their parts pass on to the video: over by 11.62 s less the 9 s kept for all three
    assert over == pytest.approx(45 * 540 * 360 * 1.2e-6 + 1.125 + (24 + 3 * 1.15 * 6) * 1.2e-6 - 9.0, rel=1e-9)
    assert line == ("budget: the outputs at their floors take about 12 s, where the 1 min 40 s budget keeps 9 s for "
                    "them (the video, 45 frames at 540x360, 7 s over): the job takes about 3 s longer rather than make "
                    "them smaller (a larger --budget, or --budget off, runs them as set)")


def test_a_fast_machine_hears_that_the_outputs_fit(job, monkeypatch) -> None:
    model, loader, views, later = job
    monkeypatch.setattr(floors, "seconds_per_view", per_ray(1e-7))  # the video: 0.87 s + 1.125 s of its 5 s
    priced = floors.floor_check(model, loader, views, (0.5, 1.0), later, 100.0, 4096)
    line, over = priced.line("training"), priced.over
    assert over == 0.0
    assert line == "budget: the outputs at their floors take about 2 s of the 9 s the 1 min 40 s budget keeps for them"


def test_each_output_over_its_part_is_named_and_all_take_what_they_need_beyond_all_their_parts(job, monkeypatch) -> None:
    model, loader, views, later = job
    monkeypatch.setattr(floors, "seconds_per_view", per_ray(0.1))  # a tenth of a second a ray
    over = floors.floor_check(model, loader, views, (0.5, 1.0), later, 100.0, 4096).over
    video = 45 * 540 * 360 * 0.1 + 1.125
    # the depth maps' 2.07 s leave 0.93 s of their 3 s to the others: over by what all take beyond all three parts
    assert over == pytest.approx((24 * 0.1 - 1.0) + (video - 5.0) + (3 * 1.15 * 6 * 0.1 - 3.0))
    line = floors.floor_check(model, loader, views, (0.5, 0.1), later[1:], 100.0, 4096).line("training")
    # 2.4 s for one view at 6x4 (2.3 s over its 0.1 s), 2.07 s for the depth maps (within their 3 s): 1.37 s over
    assert "(the held-out evaluation, 1 view at 6x4, 2 s over): the job takes about 1 s longer" in line
    assert "depth maps" not in line


def test_a_video_along_the_capture_is_priced_over_the_scenes_whole_depth_range(job, monkeypatch) -> None:
    model, loader, views, later = job
    # the injected cost model: a microsecond a ray for each unit of depth range the rays march
    monkeypatch.setattr(floors, "seconds_per_view",
                        lambda model, k, c2w, width, height, near, far, *rest: 1e-6 * (far - near) * width * height)
    own = loader.near_far[views.heldout[0].name]
    scene = (loader.bounds.near, loader.bounds.far)
    assert own == (1.0, 5.0) and scene == (2.0, 9.0)  # the held-out photo sees a part of the scene's range
    priced = floors.floor_check(model, loader, views, (0.5, 1.0), later, 100.0, 4096)
    line, over = priced.line("training"), priced.over
    # the render stage's own path renders over the bounds' 7 units (``RenderStage._run``), not the probe photo's 4
    video = 45 * 540 * 360 * 1e-6 * 7.0 + 1.125
    others = (24 + 3 * 1.15 * 6) * 1e-6 * 4.0  # the evaluation and the depth maps over the photo's own 4 units
    assert over == pytest.approx(video + others - 9.0, rel=1e-9)  # all three, less the 1 + 3 + 5 s kept for them
    assert f"the video, 45 frames at 540x360, {format_duration(video - 5.0)} over" in line


def settle(calibration: floors.Calibration, first_step: int, steps: int, per_ray: float, occupancy: float,
           seconds_per_step: float = 0.1) -> int | None:
    """Feed ``calibration`` ``steps`` training steps of 100 rays at ``per_ray`` samples a ray from ``first_step`` on;
    the step it said yes at, if it did."""
    for step in range(first_step, first_step + steps):
        if calibration(step, step * seconds_per_step, int(100 * per_ray), 100, occupancy):
            return step
    return None


def test_the_line_waits_until_the_grid_has_freed_cells_and_the_samples_a_ray_have_settled() -> None:
    window = floors.SETTLED_WINDOW
    # the temple's trace: the grid frees its first cells at step 256 and its samples a ray fall 18 -> 8 -> 4.7
    calibration = floors.Calibration(seconds=1000.0)  # 0.1 s a step: a tenth of the time is step 1000
    assert settle(calibration, 0, 1000, 18.0, 1.0) is None  # the grid as it started: samples a ray mean nothing yet
    assert settle(calibration, 1000, window, 8.0, 0.41) is None  # one window since it began to free cells
    assert settle(calibration, 1000 + window, window, 6.0, 0.38) is None  # 8 -> 6: 25 % apart
    assert settle(calibration, 1000 + 2 * window, window - 1, 5.6, 0.35) is None  # 6 -> 5.6 (7 %): one step short
    assert settle(calibration, 1000 + 3 * window - 1, 1, 5.6, 0.35) == 1000 + 3 * window - 1
    # settled early still waits for 256 steps and a tenth of the training time
    early = floors.Calibration(seconds=1000.0)
    assert settle(early, 0, 100, 30.0, 0.7) is None
    assert settle(early, 100, 2 * window, 20.0, 0.6) is None  # two settled windows by step 228, under 256 steps
    assert settle(early, 100 + 2 * window, 1000, 20.0, 0.6) == 1000  # and under a tenth of 1000 s until step 1000
    # a field whose grid never frees a cell (or whose samples never settle) is timed at 30 % of the training time
    stuck = floors.Calibration(seconds=100.0)
    assert settle(stuck, 0, 400, 41.0, 0.74) == 300
    # a sampler without an occupancy grid has nothing to free: settled samples a ray are enough
    plain = floors.Calibration(seconds=200.0)  # a tenth of it is step 200
    assert settle(plain, 0, 2 * window + 256, 64.0, None) == 256


class Training(SimpleNamespace):
    """What the hook reads of a trainer, and what it asks of one: ``give``, which moves the end of its time budget."""

    def give(self, seconds: float) -> None:
        planned = self.config.seconds + getattr(self, "given", 0.0)
        self.given, self.config = seconds, SimpleNamespace(seconds=planned - seconds)


def test_the_line_comes_once_when_training_has_found_the_scene(job, monkeypatch, caplog) -> None:
    model, loader, views, later = job
    monkeypatch.setattr(floors, "seconds_per_view", per_ray(1e-5))
    caplog.set_level(logging.INFO, "test.floors")
    hook = floors.floor_hook(logging.getLogger("test.floors"), 100.0, later, model, loader, views, 300.0, 4096,
                             (0.5, 30.0))
    config = SimpleNamespace(seconds=300.0)
    model.sampler.grid.occupied[:10] = False  # the grid has begun to free cells before the first look
    for step in range(256):  # steady samples a ray, but not 256 steps yet
        assert not hook(Training(step=step, elapsed=31.0, samples=3000, rays=100, config=config))
    assert not caplog.records
    for step in range(256, 400):  # nor a tenth of the 300 s
        assert not hook(Training(step=step, elapsed=29.0, samples=3000, rays=100, config=config))
    assert not caplog.records
    model.sampler.grid.occupied[:20] = False  # then it frees more: the samples a ray are counted again from here
    for step in range(400, 400 + 2 * floors.SETTLED_WINDOW - 1):
        assert not hook(Training(step=step, elapsed=30.0, samples=3000, rays=100, config=config))
    assert not caplog.records
    trainer = Training(step=527, elapsed=30.0, samples=3000, rays=100, config=config)
    assert not hook(trainer)  # it speaks, and never stops training itself
    # the video's 89 s against its 5, the evaluation and the depth maps far under their 30 s and 3 s: 51 s over in
    # all. Training, 30 s into its 300, can give up to 150 s (keeping half), and gives those 51 s
    over = 45 * 540 * 360 * 1e-5 + 1.125 + (24 + 3 * 1.15 * 6) * 1e-5 - 38.0
    assert trainer.given == pytest.approx(over, rel=1e-9)
    assert [r.levelname for r in caplog.records] == ["INFO"]
    assert caplog.records[0].getMessage().endswith("training gives them 51 s of its time, so the job keeps its budget")
    hook(Training(step=800, elapsed=100.0, samples=3000, rays=100, config=config))
    assert len(caplog.records) == 1  # once, until halfway from there to the end of training


def test_training_gives_the_floors_at_most_half_its_time_and_the_job_says_how_much_longer_it_takes(job, monkeypatch,
                                                                                                  caplog) -> None:
    model, loader, views, later = job
    monkeypatch.setattr(floors, "seconds_per_view", per_ray(1e-4))  # the video: 875.9 s, 870.9 s over its 5 s
    caplog.set_level(logging.INFO, "test.floors")
    hook = floors.floor_hook(logging.getLogger("test.floors"), 100.0, later, model, loader, views, 300.0, 4096,
                             (0.5, 30.0))
    # 90 s of 300 (``LATEST_SHARE``): it prices the floors now, whatever the field does
    trainer = Training(step=0, elapsed=90.0, samples=3000, rays=100, config=SimpleNamespace(seconds=300.0))
    assert not hook(trainer)
    # it keeps 150 s of its 300 and gives the other 150; the rest of what the floors need makes the job longer
    over = 45 * 540 * 360 * 1e-4 + 1.125 + (24 + 3 * 1.15 * 6) * 1e-4 - 38.0  # all three, less all they keep
    assert trainer.given == 150.0
    assert [r.levelname for r in caplog.records] == ["WARNING"]
    assert caplog.records[0].getMessage().endswith(
        f"training gives them 2 min 30 s of its time, the most it gives, and the job takes about "
        f"{format_duration(over - 150.0)} longer rather than make them smaller (a larger --budget, or --budget "
        "off, runs them as set)")


def test_a_model_probed_mid_training_goes_on_training(job) -> None:
    """The real probe renders without gradients, which sets the fields to eval mode: they are put back."""
    model, loader, views, later = job
    for f in model.fields():
        f.train()
    floors.floor_check(model, loader, views, (0.5, 1.0), later, 100.0, 4096)
    assert all(f.training for f in model.fields())


def test_the_outputs_are_priced_again_halfway_to_the_end_and_training_takes_back_what_a_faster_field_saves(
        job, monkeypatch, caplog) -> None:
    model, loader, views, later = job
    cost = [1e-5]  # seconds a ray: a young field's, then a trained one's at half of it
    monkeypatch.setattr(floors, "seconds_per_view", lambda model, k, c2w, width, height, *rest: cost[0] * width * height)
    caplog.set_level(logging.INFO, "test.floors")
    hook = floors.floor_hook(logging.getLogger("test.floors"), 100.0, later, model, loader, views, 300.0, 4096,
                             (0.5, 30.0))
    trainer = Training(step=0, elapsed=90.0, samples=3000, rays=100, config=SimpleNamespace(seconds=300.0))
    hook(trainer)  # 90 s of 300 (``LATEST_SHARE``): priced now
    rays = 45 * 540 * 360, (24 + 3 * 1.15 * 6)  # the video's, and the evaluation's and depth maps' together
    first = rays[0] * 1e-5 + 1.125 + rays[1] * 1e-5 - 38.0  # 50.6 s over what the three keep: training gives it
    assert trainer.given == pytest.approx(first, rel=1e-9) and trainer.config.seconds == pytest.approx(300.0 - first)
    cost[0] = 0.5e-5
    halfway = 90.0 + 0.5 * (300.0 - first - 90.0)  # 169.7 s
    trainer.elapsed = halfway - 0.1
    hook(trainer)
    assert len(caplog.records) == 1 and trainer.given == pytest.approx(first, rel=1e-9)  # not yet
    trainer.elapsed = halfway
    hook(trainer)
    second = rays[0] * 0.5e-5 + 1.125 + rays[1] * 0.5e-5 - 38.0  # 6.9 s: training takes back 43.7 s and ends later
    assert trainer.given == pytest.approx(second, rel=1e-9) and trainer.config.seconds == pytest.approx(300.0 - second)
    assert [r.levelname for r in caplog.records] == ["INFO", "INFO"]
    assert caplog.records[1].getMessage() == (
        f"budget: timed again {format_duration(halfway)} into training, its field rendering as it will: the outputs "
        "at their floors take about 45 s, where the 1 min 40 s budget keeps 38 s for them (the video, 45 frames at "
        "540x360, 40 s over): training gives them 7 s of its time, so the job keeps its budget")
    trainer.elapsed = 280.0
    hook(trainer)
    assert len(caplog.records) == 2  # twice in all
