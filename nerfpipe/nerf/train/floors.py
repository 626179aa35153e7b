"""Whether a job's outputs fit its budget at their floors, said early in training and again halfway to its end.

Under a job budget every output has a floor below which it is useless (held-out scores at half the photos' side,
depth maps at a quarter, a video of 360 pixels on its short side), and each export stage renders at the size its
share affords, never below its floor. What rendering costs is a property of the trained field (its samples a ray
follow what the occupancy grid has learned), so it cannot be timed before training; it can once the grid has seen
the field and the field has left its first fog (``Calibration``: the grid has begun to free cells and the samples a
ray have settled). Then ``floor_check`` renders a held-out view at a quarter of its side
and says, in one line, whether the outputs fit what the budget keeps for them. When they do not, training, the
elastic stage, gives them the time they lack, up to half its own (``KEEP_TRAINING``), and stops that much sooner; the
line says how much it gave and how much longer the job will take for the rest: before the rest of training, not after
it. A young field renders slower than it will, so halfway from there to training's end the outputs are priced again
and training gives what that says instead, in a second line. Each stage still times its own work when it runs, takes
what training saved for its floor, and says again if it goes over.
"""

from __future__ import annotations

import logging
from typing import Callable, Sequence

from nerfpipe.artifacts import ViewSplit
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.throughput import seconds_per_view
from nerfpipe.nerf.train.evaluation import scaled_size
from nerfpipe.nerf.train.images import ImageLoader, Views
from nerfpipe.pipeline.budget import Floors, FloorWork, format_duration, price_floors
from nerfpipe.pipeline.errors import NerfpipeError
from nerfpipe.pipeline.stage import LaterStage

CALIBRATION_STEPS = 256  # the occupancy grid's warm-up (``MarchingConfig.warmup``)
# and this share of the training time: at 256 steps beer's field still renders 1.7x slower than trained (its depth
# maps predicted at 108 s took 64)
CALIBRATION_SHARE = 0.1
# Then the samples a ray, averaged over windows of this many steps, must have settled: two windows in a row within
# SETTLED_CHANGE of each other, after the occupancy grid began to free cells. The temple's grid frees its first cells
# at step 256 and its samples a ray fall from 18 to 8 at once, then to 4.7 by step 500 (4.2 at the end): timed at
# step 256 and a tenth of its 126 s, its video was predicted at 117 s and took 39. Beer's grid frees its first cells
# about step 650 (41 samples a ray, then 34; 31-33 to the end), the cup's about step 520 (36, then 35; 32 at the end).
SETTLED_WINDOW = 64
SETTLED_CHANGE = 0.1
LATEST_SHARE = 0.3  # whatever the field does, the line comes by this share of the training time
PROBE_SCALE = 0.25  # the share of the view's side timed: whole neighbourhoods of rays, as the exports render them
# The least share of its time training keeps when the outputs' floors need more than the budget keeps for them. Beer's
# held-out score is at its best after 2 of 20 minutes of training and the cup's within 0.3 dB of its 5-minute mark
# after 2 (``nerfpipe bench``, docs/benchmarks.md): half of a main job's 4-5 minutes costs little; less would cost more.
KEEP_TRAINING = 0.5
# A young field renders slower than a trained one (beer's, rendering the probe view: 40-46 k rays a second after 25 s of
# training, 55-60 k after 60 s, 62 k trained; the first line, said at 25 s, priced its outputs 1.4x what they took), so
# the outputs are priced again this share of the way from the first line to training's end, and training gives what
# that says: less where the field got faster, so that it trains longer, or more.
RETIME_SHARE = 0.5


class Calibration:
    """Whether training has gone far enough for its field's rendering cost to say what the outputs will cost: at
    least ``CALIBRATION_STEPS`` and ``CALIBRATION_SHARE`` of the ``seconds`` of training, the occupancy grid below
    what it held when first asked (a sampler without one has nothing to free), and the samples a ray of the last two
    windows of ``SETTLED_WINDOW`` steps since then within ``SETTLED_CHANGE`` of each other; or ``LATEST_SHARE`` of
    the training time, whatever the field does. Called once a step with that step's samples and rays."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.first: float | None = None  # the occupancy when first asked
        self.windows: list[float] = []  # samples a ray of each whole window since the grid began to free cells
        self.samples = self.rays = self.steps = 0

    def __call__(self, step: int, elapsed: float, samples: int, rays: int, occupancy: float | None) -> bool:
        if self.first is None:
            self.first = occupancy
        if occupancy is not None and self.first is not None and occupancy >= self.first:
            self.samples = self.rays = self.steps = 0  # the grid still as it started: nothing counts yet
        else:
            self.samples, self.rays, self.steps = self.samples + samples, self.rays + rays, self.steps + 1
            if self.steps == SETTLED_WINDOW:
                self.windows.append(self.samples / max(self.rays, 1))
                self.samples = self.rays = self.steps = 0
        if elapsed >= LATEST_SHARE * self.seconds:
            return True
        if step < CALIBRATION_STEPS or elapsed < CALIBRATION_SHARE * self.seconds or len(self.windows) < 2:
            return False
        before, last = self.windows[-2:]
        return abs(last - before) <= SETTLED_CHANGE * before


def evaluation_floor(loader: ImageLoader, heldout: Sequence, scale: float) -> FloorWork | None:
    """The held-out evaluation at ``scale`` of the photos' side: its rays."""
    if not heldout:
        return None
    sizes = [scaled_size(c.width, c.height, scale) for c in map(loader.world.camera_of, heldout)]
    return FloorWork(float(sum(w * h for w, h in sizes)), 0.0,
                     f"the held-out evaluation, {len(sizes)} view{'s' * (len(sizes) != 1)} at {sizes[0][0]}x{sizes[0][1]}")


def floor_check(model: RadianceModel, loader: ImageLoader, views: Views, evaluation: tuple[float, float],
                later: Sequence[LaterStage], budget: float, chunk: int, spare: float = 0.0) -> Floors:
    """The outputs priced at their floors against what the budget keeps for them (``price_floors``; ``spare``: the
    most of its time training gives them), with rendering timed on ``model`` as it is now: the first held-out view
    (else the first training view) rendered whole at ``PROBE_SCALE`` of its side (``seconds_per_view``), per ray, over
    its own depth range, and over the bounds' whole range for work priced there (``FloorWork.rate`` "scene": the
    render stage's own camera paths, which render every frame over it; the cup's frames cost 1.3x its photos' rays).

    Args:
        evaluation: (scale, seconds kept): the held-out views' scale and the seconds the budget keeps for scoring
            them. later: the budgeted stages still to run (``StageContext.later``), each asked for its floor
            (``Stage.floor_work(params, world, split)``); a stage that cannot tell is left out.
    """
    first = (views.heldout or views.train)[0]
    camera = loader.world.camera_of(first)
    width, height = scaled_size(camera.width, camera.height, PROBE_SCALE)
    k = camera.scaled(width / camera.width, height / camera.height)
    ranges = {None: loader.near_far[first.name], "scene": (loader.bounds.near, loader.bounds.far)}
    timed: dict[str | None, float] = {}

    def per_ray(rate: str | None) -> float:
        """Seconds a ray of the probe view rendered over the range ``rate`` names: its own, or the whole scene's."""
        if rate not in timed:
            was_training = [f.training for f in model.fields()]
            try:
                timed[rate] = seconds_per_view(model, k.intrinsics, first.c2w, width, height,
                                               *ranges[rate], chunk) / (width * height)
            finally:
                for f, mode in zip(model.fields(), was_training):
                    f.train(mode)
        return timed[rate]

    floors = []
    scored = evaluation_floor(loader, views.heldout, evaluation[0])
    if scored is not None:
        floors.append((scored, evaluation[1]))
    split = ViewSplit([f.name for f in views.train], [f.name for f in views.heldout], views.rule)
    for stage in later:
        try:
            work = stage.floor_work(loader.world, split)
        except NerfpipeError:  # its own settings are wrong (a camera path that cannot be read): it says so itself
            work = None
        if work is not None:
            floors.append((work, stage.seconds))
    return price_floors(floors, per_ray, budget, spare)


def floor_hook(log: logging.Logger, budget: float, later: Sequence[LaterStage], model: RadianceModel,
               loader: ImageLoader, views: Views, seconds: float, chunk: int,
               evaluation: tuple[float, float]) -> Callable[..., bool]:
    """A ``Trainer.run`` step hook that, once ``Calibration`` says so, prices the outputs at their floors
    (``floor_check``), has training give them what they lack, keeping at least ``KEEP_TRAINING`` of its ``seconds``
    (``Trainer.give``), and logs the line: a warning when the job will still take longer than its ``budget``. It prices
    them once more ``RETIME_SHARE`` of the way from there to training's end, where the field renders about as fast as
    it will, and training gives what that says instead (less, or more), with a second line. It never stops training
    itself."""
    calibrated = Calibration(seconds)
    said: list[float] = []  # how far into training each pricing came

    def price(trainer) -> None:
        most = max(seconds - max(KEEP_TRAINING * seconds, trainer.elapsed), 0.0)
        priced = floor_check(model, loader, views, evaluation, later, budget, chunk, most)
        trainer.give(priced.given)
        said.append(trainer.elapsed)
        line = priced.line("training")
        if len(said) > 1:
            line = line.replace("budget: ", f"budget: timed again {format_duration(said[-1])} into training, its field "
                                "rendering as it will: ", 1)
        (log.warning if priced.longer >= 1.0 else log.info)(line)

    def check(trainer) -> bool:
        if not said and calibrated(trainer.step, trainer.elapsed, trainer.samples, trainer.rays,
                                   model.sampler.stats().get("occupancy")):
            price(trainer)
        elif len(said) == 1 and trainer.elapsed >= said[0] + RETIME_SHARE * (trainer.config.seconds - said[0]):
            price(trainer)
        return False

    return check
