"""A time budget for a whole job, shared by its stages (``nerfpipe run --budget 10m``).

Each stage takes part in one of three ways (``Stage.budget_share``, ``Stage.elastic``):

- a share: the stage is allotted that fraction of the budget and sizes its work to fit it (an export
  renders at the size its allotment affords); its allotment is also what the others reserve for it. What the
  stages before it saved beyond the shares still to come (``Allotment.spare``) pays for its output at a floor
  that does not fit its share, never for a larger one;
- elastic: the stage gets what the job has left once the stages before it have run and the stages after
  it have their shares reserved (training), and may give some of it back to their floors (``price_floors``);
  the parameters it names in ``elastic`` turn that off when a user or a preset sets one of them;
- neither: the stage takes what it takes, bounded by its own design (reading photos, SfM with given poses).

A budget of ``auto`` is resolved, once per job, by a rule the caller supplies (the application knows what
the capture holds; this engine does not). The budget, as given (seconds or ``auto``), enters the cache keys
of the stages it shapes, so a job run again with the same budget reuses their results.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable

from nerfpipe.pipeline.errors import ParamError, StageError

AUTO = "auto"
MAX_BUDGET_SECONDS = 7 * 24 * 3600.0
_UNITS = {"": 1.0, "s": 1.0, "m": 60.0, "min": 60.0, "h": 3600.0}


def parse_duration(text: str, what: str = "--budget") -> float | str | None:
    """``10m``, ``90s``, ``1h``, ``600`` (seconds), ``auto``, or ``off`` (None). Raises ``ParamError``."""
    text = str(text).strip().lower()
    if text in (AUTO, "off"):
        return None if text == "off" else AUTO
    match = re.fullmatch(r"(\d+(?:\.\d*)?|\.\d+)\s*(s|m|min|h)?", text)
    if match is None:
        raise ParamError(f"{what} {text!r}: expected a duration such as 10m, 90s or 600, or auto or off")
    seconds = float(match.group(1)) * _UNITS[match.group(2) or ""]
    if not seconds > 0:
        raise ParamError(f"{what} {text!r}: must be more than 0 seconds")
    if seconds > MAX_BUDGET_SECONDS:
        raise ParamError(f"{what} {text[:30]!r}: at most {format_duration(MAX_BUDGET_SECONDS)} (a week); "
                         "pass off for no budget")
    return seconds


def format_duration(seconds: float) -> str:
    minutes, rest = divmod(round(seconds), 60)
    if not minutes:
        return f"{rest} s"
    return f"{minutes} min {rest} s" if rest else f"{minutes} min"


@dataclass
class JobBudget:
    """``given``: seconds, or ``auto`` (then ``resolve()`` names the seconds, asked once, when a stage first
    needs an allotment). ``clock``: seconds from any start (``time.monotonic``; a test's own steps as it
    says); ``started``: when the job began, by that clock."""

    given: float | str
    resolve: Callable[[], float] | None = None
    clock: Callable[[], float] = time.monotonic
    started: float | None = None
    _seconds: float | None = None

    def __post_init__(self) -> None:
        if self.started is None:
            self.started = self.clock()

    @property
    def seconds(self) -> float:
        if self._seconds is None:
            if isinstance(self.given, str):
                if self.resolve is None:
                    raise ParamError("--budget auto needs a rule to size it; give the budget in seconds or minutes")
                self._seconds = float(self.resolve())
            else:
                self._seconds = float(self.given)
        return self._seconds

    def elapsed(self) -> float:
        return self.clock() - self.started

    def share(self, fraction: float) -> float:
        """The seconds a stage with this share of the budget is allotted."""
        return fraction * self.seconds

    def remainder(self, later_shares: Iterable[float]) -> float:
        """What an elastic stage starting now may take: the budget less what the job spent so far and the
        shares of the stages still to come after it (never below 0)."""
        return max(self.seconds - self.elapsed() - sum(self.share(s) for s in later_shares), 0.0)

    def spare(self, own_share: float, later_shares: Iterable[float]) -> float:
        """What a stage with ``own_share`` starting now finds unspent beyond its own share and those of the stages
        after it: the time the stages before it saved (an elastic stage that stopped early to make room for the
        outputs' floors), or 0 when the job is behind."""
        return max(self.remainder([own_share, *later_shares]), 0.0)


@dataclass(frozen=True)
class Allotment:
    """What a running stage was given: ``seconds`` of the job's ``budget`` (both in seconds), and whether it
    is the elastic stage that takes the remainder. ``spare``: what the stages before it saved (``JobBudget.spare``),
    which an output at its floor that does not fit ``seconds`` may take without making the job longer; an output
    is never made larger with it."""

    seconds: float
    budget: float
    elastic: bool = False
    spare: float = 0.0

    def describe(self) -> str:
        budget = f"the {format_duration(self.budget)} budget"
        role = f"what {budget} leaves" if self.elastic else f"{self.seconds / self.budget:.0%} of {budget}"
        saved = f", and {format_duration(self.spare)} the stages before it saved" if self.spare >= 1.0 else ""
        return f"{format_duration(self.seconds)} ({role}{saved})"

    def record(self) -> dict[str, float]:
        """What a stage's manifest records of it (its ``timings``)."""
        return {"allotted": round(self.seconds, 2), "budget": self.budget, "spare": round(self.spare, 2)}


@dataclass(frozen=True)
class Fit:
    """An output sized to a stage's allotment (``fit_to_allotment``): ``scale`` of every side of the size asked
    for, ``seconds`` predicted at it, and ``over``: the seconds beyond the allotment it takes at its floor, when
    even that does not fit (0 when it fits)."""

    scale: float
    seconds: float
    over: float = 0.0

    def longer(self, what: str, allotment: Allotment) -> str | None:
        """The one line that says the job takes longer, or None when the output fits."""
        if self.over <= 0:
            return None
        return (f"{what} takes about {format_duration(self.seconds)}, {format_duration(self.over)} more than its "
                f"{allotment.describe()}: the job takes that much longer rather than make it smaller (a larger "
                "--budget, or --budget off, runs it as set)")


def fit_to_allotment(full_seconds: float, left: float | None, floor: float, fixed: float = 0.0,
                     spare: float = 0.0) -> Fit:
    """The largest scale s in [floor, 1] of an output whose cost is ``full_seconds`` s^2 + ``fixed`` (its pixels,
    each side times s, and what it costs whatever its size) that fits the ``left`` seconds of the stage's
    allotment (None: no budget, so the size asked for, s = 1); rounded down to hundredths. Never below
    ``floor``, the scale under which the output is useless: when even the floor does not fit, the floor, and
    ``Fit.over`` says by how much it runs past ``left`` and the ``spare`` seconds the job saved before the stage
    (``Allotment.spare``), which pay for a floor but never for a larger size."""
    def cost(scale: float) -> float:
        return full_seconds * scale**2 + fixed

    floor = min(max(floor, 0.0), 1.0)
    if left is None or cost(1.0) <= left:
        return Fit(1.0, cost(1.0))
    scale = (max(left - fixed, 0.0) / max(full_seconds, 1e-12)) ** 0.5
    scale = max(floor, min(1.0, float(int(scale * 100.0)) / 100.0 if scale >= 0.01 else scale))
    return Fit(scale, cost(scale), max(cost(scale) - max(left, 0.0) - max(spare, 0.0), 0.0) if scale <= floor else 0.0)


def fit_within(allotment: Allotment | None, spent: float, full_seconds: float, floor: float,
               fixed: float = 0.0) -> Fit:
    """``fit_to_allotment`` for a stage that has spent ``spent`` seconds of its ``allotment`` (None: no budget)
    already, with what the stages before it saved."""
    if allotment is None:
        return fit_to_allotment(full_seconds, None, floor, fixed)
    return fit_to_allotment(full_seconds, allotment.seconds - spent, floor, fixed, allotment.spare)


@dataclass(frozen=True)
class FloorWork:
    """What a budgeted stage's outputs cost at their floors (``Stage.floor_work``), before it has run: ``units`` of
    the work whose rate the elastic stage measures (for a radiance field's exports: rays, each weighted by its
    stage's overhead), ``fixed`` seconds whatever that rate, and ``what`` they are, for the line that says so.
    ``rate``: which measured rate prices a unit: None for the elastic stage's own measurement, else the name of
    another it knows how to measure (a radiance field's rays rendered over the whole scene's depth range, "scene",
    cost more than those of one photo's)."""

    units: float
    fixed: float
    what: str
    rate: str | None = None

    def seconds(self, per_unit: float) -> float:
        return self.units * per_unit + self.fixed


@dataclass(frozen=True)
class Floors:
    """The outputs priced at their floors (``price_floors``): they take ``need`` seconds where the ``budget`` keeps
    ``kept`` for them, ``over`` beyond that (``parts``: each output over its part, in words). The elastic stage gives
    them ``given`` seconds of its own time (it stops that much sooner); the job takes ``longer`` than its budget by
    the rest. None of them is made smaller than its floor."""

    need: float
    kept: float
    over: float
    given: float
    budget: float
    parts: tuple[str, ...] = ()

    @property
    def longer(self) -> float:
        return max(self.over - self.given, 0.0)

    def line(self, elastic: str) -> str:
        """The one line that says so; ``elastic``: what the elastic stage is called (it "gives them ...")."""
        need, kept, budget = (format_duration(x) for x in (self.need, self.kept, self.budget))
        if self.over < 1.0:
            return f"budget: the outputs at their floors take about {need} of the {kept} the {budget} budget keeps for them"
        said = (f"budget: the outputs at their floors take about {need}, where the {budget} budget keeps {kept} for them "
                f"({'; '.join(self.parts)})")
        gives = f"{elastic} gives them {format_duration(self.given)} of its time"
        if self.longer < 1.0:
            return f"{said}: {gives}, so the job keeps its budget"
        rather = (f"the job takes about {format_duration(self.longer)} longer rather than make them smaller (a larger "
                  "--budget, or --budget off, runs them as set)")
        return f"{said}: {gives}, the most it gives, and {rather}" if self.given >= 1.0 else f"{said}: {rather}"


def price_floors(floors: Iterable[tuple[FloorWork, float]], per_unit: float | Callable[[str | None], float],
                 budget: float, spare: float = 0.0) -> Floors:
    """The outputs at their floors against what the budget keeps for them. ``floors``: each output's ``FloorWork``
    and the seconds the budget keeps for it; ``per_unit``: the measured seconds a unit of work takes, or a function
    of a ``FloorWork.rate`` giving them; ``spare``: the most of its own time the elastic stage gives the outputs
    that do not fit their parts (it gives what they need, up to that). They need what they take beyond all their
    parts together: a part one output leaves unspent passes to those after it (``JobBudget.spare``)."""
    rate_of = per_unit if callable(per_unit) else (lambda rate: per_unit)
    parts, need, kept = [], 0.0, 0.0
    for work, allotted in floors:
        seconds = work.seconds(rate_of(work.rate))
        need, kept = need + seconds, kept + allotted
        if seconds > allotted:
            parts.append(f"{work.what}, {format_duration(seconds - allotted)} over")
    over = need - kept
    if over < 1.0:
        return Floors(need, kept, 0.0, 0.0, budget)
    return Floors(need, kept, over, min(over, max(spare, 0.0)), budget, tuple(parts))


def takes_part(share: float, elastic_params: tuple[str, ...], chosen: Iterable[str]) -> tuple[bool, bool]:
    """(budgeted, elastic) for a stage with ``share`` and ``elastic_params`` whose parameters set by the user
    or a preset are ``chosen``: elastic unless one of those was chosen; budgeted if either."""
    elastic = bool(elastic_params) and not set(elastic_params) & set(chosen)
    return elastic or share > 0, elastic


def check_affordable(allotment: Allotment | None, seconds: float, what: str, advice: str) -> None:
    """Raise ``StageError`` when ``what``, predicted to take ``seconds``, would take more than the job's whole
    budget: it would overrun it, not fit it. No budget (``--budget off``): the user asked for it as set."""
    if allotment is not None and seconds > allotment.budget:
        raise StageError(f"{what} would take about {format_duration(seconds)}, more than the job's whole budget of "
                         f"{format_duration(allotment.budget)}; {advice}, or pass --budget off to run it anyway")


def check_least_seconds(planned: Iterable[Any], budget: float | str | None, ceiling: float | None) -> None:
    """Refuse, before anything runs, a stage set to cost more than the whole job's budget on any machine
    (``Stage.least_seconds``); ``--budget auto`` is compared with the most it can give, ``ceiling``. A stage that
    takes what the budget leaves (``elastic``) sizes itself, and ``--budget off`` runs anything as set."""
    limit = ceiling if isinstance(budget, str) else budget
    if limit is None:
        return
    for stage in planned:
        least = None if stage.elastic else stage.stage.least_seconds(stage.params)
        if least is not None and least[0] > limit:
            raise ParamError(f"{stage.name}.{least[1]} takes at least {format_duration(least[0])}, more than the job's "
                             f"budget of {format_duration(limit)}"
                             f"{' (the most --budget auto gives)' if isinstance(budget, str) else ''}; "
                             "lower it, raise --budget, or pass --budget off")
