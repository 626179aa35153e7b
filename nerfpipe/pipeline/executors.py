"""Where the tasks of a batch run: in this process, in local worker processes, or on a Ray cluster.

A task is a module-level function (so any process can import it) with arguments; it may run after other
tasks, whose return values are appended to its arguments. ``submit`` returns a handle at once and
``wait`` returns the tasks that finished, each with its return value or a ``TaskFailure``. Tasks are
expected to catch their own errors and report them in their return value; a ``TaskFailure`` is what
the executor saw instead: the worker died more times than ``max_retries`` allows (killed, out of
memory, its node lost), or an exception escaped the task.

The executors schedule only; what a task does (run one stage of one capture) is ``nerfpipe.pipeline.batch``'s.
"""

from __future__ import annotations

import concurrent.futures as cf
import itertools
import multiprocessing
import os
import sys
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

from nerfpipe.pipeline.errors import ParamError


@dataclass(frozen=True)
class TaskFailure:
    """A task without a return value: ``reason`` is one line; ``lost`` when its worker died."""

    reason: str
    lost: bool = False


@dataclass(eq=False)
class Handle:
    """A submitted task."""

    label: str
    fn: Callable[..., Any]
    args: tuple[Any, ...]
    after: tuple["Handle", ...]
    cpus: float
    gpus: float
    attempts: int = 0
    ref: Any = None  # the executor's own reference (a future, a Ray ObjectRef)
    done: bool = False
    value: Any = None
    serial: int = field(default_factory=itertools.count().__next__)


class Executor(ABC):
    """Runs tasks; ``max_retries`` bounds how often a task whose worker died is started again."""

    name: str

    def __init__(self, max_retries: int = 2) -> None:
        if max_retries < 0:
            raise ParamError(f"--max-retries {max_retries}: must be 0 or more")
        self.max_retries = max_retries

    def has_gpus(self) -> bool:
        return False

    @abstractmethod
    def submit(self, fn: Callable[..., Any], args: tuple[Any, ...], after: Sequence[Handle] = (), cpus: float = 1,
               gpus: float = 0, label: str = "") -> Handle:
        """Schedule ``fn(*args, *results of after)``; the handle is returned at once."""

    @abstractmethod
    def wait(self, handles: Sequence[Handle], timeout: float | None = None) -> list[Handle]:
        """Tasks that finished (``done`` set, ``value`` filled), at least one unless ``timeout`` seconds
        passed first. ``handles`` are all the tasks not yet seen finished."""

    def close(self) -> None:
        """Release workers; tasks still running are abandoned (their stages never commit)."""

    def __enter__(self) -> "Executor":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _upstream_failure(handle: Handle) -> TaskFailure | None:
    for up in handle.after:
        if isinstance(up.value, TaskFailure):
            return TaskFailure(f"{up.label} failed: {up.value.reason}", up.value.lost)
    return None


class LocalExecutor(Executor):
    """This machine. ``workers`` = 1 runs each task in this process, in submission order (what
    ``nerfpipe run`` does); more starts that many worker processes, each with an equal share of the cores
    for its threads, and restarts them when one dies."""

    name = "local"

    def __init__(self, workers: int = 1, max_retries: int = 2) -> None:
        super().__init__(max_retries)
        if workers < 1:
            raise ParamError(f"--max-parallel {workers}: must be 1 or more for the local executor")
        self.workers = workers
        self._queue: list[Handle] = []  # submitted, not yet started
        self._running: list[Handle] = []
        self._pool: cf.ProcessPoolExecutor | None = None

    def submit(self, fn, args, after=(), cpus=1, gpus=0, label=""):
        handle = Handle(label, fn, tuple(args), tuple(after), cpus, gpus)
        self._queue.append(handle)
        return handle

    def _ready(self) -> list[Handle]:
        return [h for h in self._queue if all(up.done for up in h.after)]

    def _start(self, handle: Handle) -> bool:
        """Start ``handle`` or, when an upstream task failed, finish it with that failure. True if started."""
        self._queue.remove(handle)
        failure = _upstream_failure(handle)
        if failure is not None:
            handle.done, handle.value = True, failure
            return False
        handle.attempts += 1
        if self.workers == 1:
            try:
                handle.value = handle.fn(*handle.args, *(up.value for up in handle.after))
            except Exception as err:  # a bug in the task: it is reported, the batch goes on
                handle.value = TaskFailure(f"{type(err).__name__}: {err}")
            handle.done = True
            return False
        handle.ref = self._ensure_pool().submit(handle.fn, *handle.args, *(up.value for up in handle.after))
        self._running.append(handle)
        return True

    def _ensure_pool(self) -> cf.ProcessPoolExecutor:
        if self._pool is None:
            threads = max(1, (len(os.sched_getaffinity(0)) or 1) // self.workers)
            self._pool = cf.ProcessPoolExecutor(
                self.workers, mp_context=multiprocessing.get_context("spawn"), initializer=_limit_threads,
                initargs=(threads,),
            )
        return self._pool

    def wait(self, handles, timeout=None):
        finished: list[Handle] = []
        while not finished:
            for handle in self._ready():
                if self.workers == 1 or len(self._running) < self.workers:
                    self._start(handle)
                    if handle.done:
                        finished.append(handle)
                        if self.workers == 1:
                            break  # one task per call in this process, so progress shows between them
            if finished or not self._running:
                break
            done, _ = cf.wait([h.ref for h in self._running], timeout=timeout, return_when=cf.FIRST_COMPLETED)
            if not done:
                break
            finished.extend(self._collect(done))
        return finished

    def _collect(self, done: set[cf.Future]) -> list[Handle]:
        finished, broken = [], False
        for handle in [h for h in self._running if h.ref in done]:
            try:
                handle.value = handle.ref.result()
            except cf.process.BrokenProcessPool:
                broken = True
                continue
            except Exception as err:
                handle.value = TaskFailure(f"{type(err).__name__}: {err}")
            self._running.remove(handle)
            handle.done = True
            finished.append(handle)
        if broken:
            # A worker died (killed, out of memory): the pool is unusable. Every task it was running is
            # started again in a new pool, up to max_retries times each.
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
            for handle in list(self._running):
                self._running.remove(handle)
                if handle.attempts > self.max_retries:
                    handle.done = True
                    handle.value = TaskFailure(f"its worker process died {handle.attempts} times", lost=True)
                    finished.append(handle)
                else:
                    self._queue.insert(0, handle)
        return finished

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None


def _limit_threads(threads: int) -> None:
    """In a fresh worker process, before torch or OpenCV start their thread pools (they read the variable when
    they start). The engine does not import torch; one that a stage library already loaded is told directly."""
    os.environ["OMP_NUM_THREADS"] = str(threads)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(threads)


class RayExecutor(Executor):
    """A Ray cluster (``address``), or a Ray instance started here for this batch (``address`` None).

    Each task is a Ray task with declared resources: ``cpus`` CPUs, and ``gpus`` GPUs where the cluster
    has any. Its upstream tasks are passed as object references, so Ray starts it where and when they are
    done; a task whose worker or node dies is restarted by Ray up to ``max_retries`` times (Ray's own
    ``max_retries``; exceptions are not retried: the tasks report their own errors).
    """

    name = "ray"

    def __init__(self, address: str | None = None, max_retries: int = 2, num_cpus: int | None = None) -> None:
        super().__init__(max_retries)
        try:
            import ray
        except ImportError:
            raise ParamError("--executor ray needs Ray: pip install 'nerfpipe[ray]'") from None
        self._ray = ray
        self._started = not ray.is_initialized()
        if self._started:
            try:
                if address is None:
                    ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, configure_logging=False)
                else:
                    ray.init(address=address, log_to_driver=False, configure_logging=False)
            except ConnectionError as err:
                raise ParamError(f"--address {address}: no Ray cluster answers there ({err}); start one with "
                                 f"`ray start --head` or leave --address out to start Ray on this machine") from None
        self._remote: dict[Callable[..., Any], Any] = {}
        self._gpus = ray.cluster_resources().get("GPU", 0) > 0

    def has_gpus(self) -> bool:
        return self._gpus

    def submit(self, fn, args, after=(), cpus=1, gpus=0, label=""):
        handle = Handle(label, fn, tuple(args), tuple(after), cpus, gpus if self._gpus else 0)
        remote = self._remote.get(fn)
        if remote is None:
            remote = self._remote[fn] = self._ray.remote(fn)
        handle.ref = remote.options(
            num_cpus=cpus, num_gpus=handle.gpus, max_retries=self.max_retries, retry_exceptions=False,
            name=label or fn.__name__,
        ).remote(*handle.args, *(up.ref for up in handle.after))
        return handle

    def wait(self, handles, timeout=None):
        pending = {h.ref: h for h in handles if not h.done}
        if not pending:
            return []
        ready, _ = self._ray.wait(list(pending), num_returns=1, timeout=timeout)
        if ready:
            ready, _ = self._ray.wait(list(pending), num_returns=len(pending), timeout=0)
        finished = []
        for ref in ready:
            handle = pending[ref]
            try:
                handle.value = self._ray.get(ref)
            except self._ray.exceptions.RayTaskError as err:
                handle.value = TaskFailure(f"{type(err.cause).__name__}: {err.cause}")
            except self._ray.exceptions.RayError as err:  # the worker or its node died, beyond the retries
                first = str(err).strip().splitlines()[0] if str(err).strip() else ""
                handle.value = TaskFailure(f"{type(err).__name__} after {self.max_retries} retries: {first}", lost=True)
            handle.done = True
            finished.append(handle)
        return finished

    def close(self) -> None:
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()
