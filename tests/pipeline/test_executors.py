"""The local executor: dependency order, upstream results as arguments, failures, and dead workers retried."""

from __future__ import annotations

import pytest

from nerfpipe.pipeline.errors import ParamError
from nerfpipe.pipeline.executors import LocalExecutor, TaskFailure
from tests.helpers import add, die_until, fail_with


def drain(executor, handles):
    finished = []
    while len(finished) < len(handles):
        got = executor.wait([h for h in handles if not h.done], timeout=60)
        assert got, "no task finished within 60 s"
        finished += got
    return finished


@pytest.mark.parametrize("workers", [1, 2])
def test_tasks_run_after_their_upstream_and_receive_its_results(workers):
    with LocalExecutor(workers) as ex:
        a = ex.submit(add, (1, 2), label="a")
        b = ex.submit(add, (10,), label="b")
        c = ex.submit(add, (100,), after=[a, b], label="c")  # 100 + 0 + 3 + 10
        d = ex.submit(add, (1000,), after=[c], label="d")
        order = [h.label for h in drain(ex, [a, b, c, d])]
    assert (a.value, b.value, c.value, d.value) == (3, 10, 113, 1113)
    assert order.index("c") > max(order.index("a"), order.index("b")) and order[-1] == "d"


@pytest.mark.parametrize("workers", [1, 2])
def test_an_exception_fails_its_task_and_its_downstream_not_the_others(workers):
    with LocalExecutor(workers) as ex:
        bad = ex.submit(fail_with, ("no photos",), label="bad")
        after_bad = ex.submit(add, (1,), after=[bad], label="after_bad")
        good = ex.submit(add, (2, 3), label="good")
        drain(ex, [bad, after_bad, good])
    assert bad.value == TaskFailure("ValueError: no photos")
    assert after_bad.value == TaskFailure("bad failed: ValueError: no photos")
    assert good.value == 5


def test_a_dead_worker_process_is_replaced_and_its_task_retried(tmp_path):
    with LocalExecutor(2, max_retries=2) as ex:
        twice = ex.submit(die_until, (str(tmp_path / "twice"), 2), label="twice")  # dies twice, then returns
        after = ex.submit(add, (1,), after=[twice], label="after")
        drain(ex, [twice, after])
    assert twice.value == 7 and twice.attempts == 3 and after.value == 8


def test_a_task_whose_worker_keeps_dying_fails_after_max_retries(tmp_path):
    with LocalExecutor(2, max_retries=1) as ex:
        doomed = ex.submit(die_until, (str(tmp_path / "doomed"), 99), label="doomed")
        drain(ex, [doomed])
    assert doomed.value == TaskFailure("its worker process died 2 times", lost=True)
    assert (tmp_path / "doomed").read_text() == "2"  # the first attempt and one retry, no more


def test_bad_settings_are_parameter_errors():
    with pytest.raises(ParamError, match="--max-parallel 0: must be 1 or more"):
        LocalExecutor(0)
    with pytest.raises(ParamError, match="--max-retries -1"):
        LocalExecutor(1, max_retries=-1)
