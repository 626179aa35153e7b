"""Every numeric parameter in docs/parameters.md, driven through extreme values (0, negative, 1e20, NaN, huge
integers, its own bounds): in ``status --set`` and in ``run --until`` the first stage that reads it. Each ends
in one line and exit 2, or runs within its bounds: no traceback, no hang past 60 s, no allocation past 2 GB
(the runs are children of ``tests.forkserver`` under ``RLIMIT_DATA``, which nerfpipe's memory checks read).

``status`` is asked in-process (it plans, and allocates nothing); the runs repeat a tiny prepared job, each
changing one parameter, so that only the stage that reads it runs again."""

from __future__ import annotations

import math
import os
import queue
import re
import shutil
import threading
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from nerfpipe.cli.main import app
from nerfpipe.stages import default_stages
from tests.forkserver import ForkServer
from tests.helpers import REPO, temple_subset

DOC = REPO / "docs" / "parameters.md"
LIMIT = 2 << 30  # bytes a run may allocate
SECONDS = 60  # a run still going after this is hung (hidden=1024 took 30 s on a slow day of this 2-core box)
# the tiny job every run repeats: 6 photos of 100 px, 8 training steps of 256 rays on a field of at most 32 cells a
# side, small exports
BASE = {"ingest.max_size": "100", "train.steps": "8", "train.optim.batch_rays": "256",
        "train.optim.batch_samples": "2048", "train.field.min_resolution": "16", "train.field.max_resolution": "32",
        "export_points.acc_threshold": "0.0", "export_mesh.texture": "0",
        "export_mesh.resolution": "32", "render.frames": "4", "render.short_side": "0"}
BUDGET = "30s"


def numeric_parameters() -> list[tuple[str, str, tuple[float, float]]]:
    """(name, type, (low, high)) of every int or float parameter the reference lists, read from its table."""
    rows = re.findall(r"^\| `([\w.]+)` \| (int|float)(?: or none)? \| `[^`]*` \| \[([^\]]+)\] \|", DOC.read_text(),
                      re.MULTILINE)
    return [(name, kind, tuple(float(b.replace("_", "")) for b in bounds.split(", "))) for name, kind, bounds in rows]


NUMERIC = numeric_parameters()
EXTREMES = ("0", "-1", "1e20", "nan", "-inf", str(10**30), "9" * 5000)


def test_the_reference_lists_bounds_for_every_numeric_parameter() -> None:
    from nerfpipe.pipeline.params import param_specs

    declared = {f"{s.name}.{p.name}" for s in default_stages() for p in param_specs(s.Params) if p.is_number}
    assert {name for name, _, _ in NUMERIC} == declared and len(declared) == 103


def in_bounds(kind: str, bounds: tuple[float, float], text: str) -> bool:
    try:
        value = float(text) if kind == "float" else int(text)
    except (ValueError, OverflowError):
        return False
    return math.isfinite(value) and bounds[0] <= value <= bounds[1]


@pytest.fixture(scope="module")
def prepared(tmp_path_factory) -> tuple[Path, Path]:
    """A capture and a finished tiny run of it (every stage), made through the CLI."""
    root = tmp_path_factory.mktemp("extremes")
    capture = temple_subset(root, "capture", [1, 3, 5, 7, 9, 11])
    with ForkServer() as server:
        done = server.run(["run", capture, "--out", root / "run", "--budget", BUDGET, *flags(BASE)], root, LIMIT, 300)
    assert done.code == 0, done.stderr
    return capture, root / "run"


def flags(values: dict[str, str]) -> list[str]:
    return [word for name, value in values.items() for word in ("--set", f"{name}={value}")]


def one_line_or_fine(code: int, stderr: str, what: str) -> None:
    """Exit 0, or one ``error:`` line and exit 2 (a setting refused) or 1 (a stage that could not make its
    result from these data); never a traceback, a signal or another status."""
    assert "Traceback" not in stderr, f"{what}:\n{stderr[-3000:]}"
    assert code in (0, 1, 2), f"{what}: exit {code} (negative: killed by that signal; SIGALRM: past {SECONDS} s)\n" \
                              f"{stderr[-3000:]}"
    if code:
        errors = [line for line in stderr.splitlines() if line.startswith("error:")]
        assert len(errors) == 1, f"{what}:\n{stderr[-3000:]}"
        assert "is in use by" not in errors[0], f"{what}: another lane held the run's lock: {errors[0]}"


def status(run: Path, name: str, value: str):
    result = CliRunner().invoke(app, ["status", str(run), "--set", f"{name}={value}"])
    assert not isinstance(result.exception, Exception) or isinstance(result.exception, SystemExit), \
        f"{name}={value[:40]}: {result.exception!r}"
    return result


def test_status_takes_every_extreme_of_every_parameter_or_names_it(prepared) -> None:
    _, run = prepared
    for name, kind, bounds in NUMERIC:
        for value in (*EXTREMES, *(repr(b) if kind == "float" else str(int(b)) for b in bounds)):
            result = status(run, name, value)
            shown = f"{name}={value[:40]}"
            if in_bounds(kind, bounds, value):
                assert result.exit_code in (0, 2), f"{shown}: {result.output[-2000:]}"
            else:
                assert result.exit_code == 2, f"{shown} was taken: {result.output[-2000:]}"
                errors = [line for line in result.output.splitlines() if line.startswith("error:")]
                assert len(errors) == 1 and name.split(".", 1)[1].split(".")[-1] in errors[0], f"{shown}: {errors}"


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(parameter=st.sampled_from(NUMERIC),
       value=st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                       st.integers(min_value=-10**40, max_value=10**40).map(str),
                       st.text(max_size=12)))
def test_status_property_any_text_for_any_parameter(prepared, parameter, value) -> None:
    name, kind, bounds = parameter
    result = status(prepared[1], name, value)
    assert result.exit_code in (0, 2), f"{name}={value!r}: {result.output[-2000:]}"
    if not in_bounds(kind, bounds, value.strip()):
        assert result.exit_code == 2, f"{name}={value!r} was taken"


def first_stage(name: str) -> str:
    return name.split(".", 1)[0]


def run_cases() -> list[tuple[str, str]]:
    """Each parameter at its own two bounds, the in-bounds extremes of all, which a run must survive; and at the
    extremes outside every parameter's bounds, which ``run`` must refuse as ``status`` does, before it starts."""
    cases = []
    for name, kind, bounds in NUMERIC:
        for b in bounds:
            value = repr(b) if kind == "float" else str(int(b))
            if BASE.get(name) != value:
                cases.append((name, value))
        cases += [(name, value) for value in RUN_EXTREMES]
    return cases


RUN_EXTREMES = ("-1", "nan")  # outside every parameter's bounds (status takes all of EXTREMES)


@pytest.mark.slow
def test_a_run_until_the_stage_survives_each_parameter_at_its_bounds(prepared, tmp_path) -> None:
    """Two fork servers, one a core, each taking the next case when it is done with its last; the last stages'
    first (they take longest), so that the two end together."""
    capture, run = prepared
    order = [s.name for s in default_stages()]
    cases = queue.SimpleQueue()
    for case in sorted(run_cases(), key=lambda case: -order.index(first_stage(case[0]))):
        cases.put(case)
    failures: list[str] = []

    def work(lane: int) -> None:
        with ForkServer() as server:
            while not cases.empty():
                name, value = cases.get()
                folder = tmp_path / f"run{lane}"
                if value not in RUN_EXTREMES or not folder.exists():  # a refused run writes nothing: no fresh copy
                    shutil.rmtree(folder, ignore_errors=True)
                    # linked, not copied: a run never writes into a committed result or a file it replaces whole
                    shutil.copytree(run, folder, symlinks=True, copy_function=os.link,
                                    ignore=shutil.ignore_patterns(".lock", ".locks"))  # locks are written in place
                outcome = server.run(["run", capture, "--out", folder, "--budget", BUDGET, *flags({**BASE, name: value}),
                                      "--until", first_stage(name)], tmp_path, LIMIT, SECONDS)
                try:
                    one_line_or_fine(outcome.code, outcome.stderr, f"{name}={value}")
                    if value in RUN_EXTREMES:
                        assert outcome.code == 2 and name.rsplit(".", 1)[-1] in outcome.stderr, \
                            f"{name}={value} was not refused: {outcome.stderr[-1000:]}"
                except AssertionError as err:
                    failures.append(str(err))

    lanes = [threading.Thread(target=work, args=(lane,)) for lane in range(LANES)]
    for lane in lanes:
        lane.start()
    for lane in lanes:
        lane.join()
    assert not failures, "\n\n".join(failures)


LANES = 2
