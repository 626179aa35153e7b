"""Rendering's hot functions compiled: what every stage that renders a trained field spends most of its time in.

Rendering (held-out views, depth maps, the video, the mesh's density and texture) evaluates a field without
gradients, in chunks whose sizes change with what the occupancy grid keeps. ``run`` calls a pure function compiled
once a process by ``torch.compile`` with dynamic shapes (inductor: C++ loops on the CPU, Triton kernels on CUDA),
so that a chain of element-wise steps and gathers over every sample becomes a few loops over them, where eagerly
each step writes an array the size of the samples to memory and reads it back. Two of them:

- the field's (``RenderingField``, ``for_rendering``): the samples' points and field coordinates, their trilinear
  corners, the gather and weighted sum of those (``nerfpipe.nerf.fields.grid.gather_corners``) and the small MLPs'
  activations; the matrix products stay the BLAS library's;
- the march's (``nerfpipe.nerf.samplers.march``): every candidate step's point, its field coordinates and its cell
  of the occupancy grid.

The results are the eager ones to float32 rounding. Where a gradient would flow through them, within a training
step (``eager``), with few points, or with ``NERFPIPE_COMPILE`` other than auto, the same functions run eagerly. If
compiling fails (no C++ compiler or Python headers, an operator inductor lacks), rendering says so once and goes on eagerly:
no machine loses a render to it. ``NERFPIPE_COMPILE=auto`` (the default) compiles on CUDA, and on the CPU where a
C++ compiler is found.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import shutil
from typing import Any, Callable, Iterator

import torch
from torch import Tensor

from nerfpipe.nerf.compiling import choice

log = logging.getLogger("nerfpipe.nerf.kernels")

# fewer rows than this run eagerly: the compiler would specialize a graph for sizes 0 and 1, and a handful of
# points costs nothing either way
FEWEST_ROWS = 256
BACKEND: str | Callable = "inductor"  # torch.compile's backend (a test's may trace without code generation instead)


@functools.cache
def cpp_compiler() -> str | None:
    """The C++ compiler inductor builds its CPU loops with (``CXX``, else g++ or clang++ on the PATH), or None."""
    named = os.environ.get("CXX")
    return shutil.which(named) if named else (shutil.which("g++") or shutil.which("clang++"))


class _Compiled:
    """The compiled functions, one each a process. What they compute on (fields, grids, rays) are arguments, so
    every model of the same kind and shape -- each stage loads its own -- reuses what the first compiled.
    ``working``: None until a compiled function first ran, then whether compiling worked."""

    def __init__(self) -> None:
        self.functions: dict[Callable, Callable] = {}
        self.working: bool | None = None

    def of(self, fn: Callable) -> Callable:
        if fn not in self.functions:
            # sizes that happen to be equal in the first call (rays and samples of a chunk) are not assumed equal
            # in the next: one graph for every chunk (``use_duck_shape``, process-wide; fixed-shape compiles ignore it)
            import torch.fx.experimental._config as shapes

            shapes.use_duck_shape = False
            self.functions[fn] = torch.compile(fn, backend=BACKEND, dynamic=True)
        return self.functions[fn]

    def reset(self) -> None:
        self.functions.clear()
        self.working = None


COMPILED = _Compiled()


_EAGER = [0]  # how many ``eager()`` blocks are open


@contextlib.contextmanager
def eager() -> Iterator[None]:
    """Everything ``run`` calls inside runs eagerly: a training step's own rendering (its march, visibility pass and
    occupancy refresh), where compiling at the start would take seconds from a time budget of training that the
    faster steps do not win back on a short training (scripts/bench_throughput.py on the temple: 107 steps in its
    first 20 s, against 337)."""
    _EAGER[0] += 1
    try:
        yield
    finally:
        _EAGER[0] -= 1


def enabled(device: torch.device) -> bool:
    """Whether ``run`` compiles on ``device``: outside ``eager()``, ``NERFPIPE_COMPILE`` is auto, compiling has not
    failed in this process, and there is something to compile with (CUDA's Triton, a C++ compiler on the CPU)."""
    if _EAGER[0] or COMPILED.working is False or choice() != "auto":
        return False
    return device.type == "cuda" or BACKEND != "inductor" or cpp_compiler() is not None


def _learns(inputs: tuple) -> bool:
    """Whether any of ``inputs`` is a tensor that requires a gradient or a module with such parameters."""
    return any(x.requires_grad if isinstance(x, Tensor) else
               isinstance(x, torch.nn.Module) and any(p.requires_grad for p in x.parameters()) for x in inputs)


def run(fn: Callable, rows: int, device: torch.device, *inputs: Any) -> Any:
    """``fn(*inputs)``, a pure function of tensors and of objects holding them, compiled where ``enabled`` says and
    there are at least ``FEWEST_ROWS`` rows of work, unless a gradient would flow through it; else eagerly."""
    if rows < FEWEST_ROWS or (torch.is_grad_enabled() and _learns(inputs)) or not enabled(device):
        return fn(*inputs)
    # a view (a chunk of a view's rays, a piece of the samples) is passed as a tensor of its own: the compiled graph
    # would otherwise be guarded on its base's size and offset, and compiled again for the next chunk
    inputs = tuple(x.clone() if isinstance(x, Tensor) and x._base is not None else x for x in inputs)
    try:
        result = COMPILED.of(fn)(*inputs)
    except Exception as err:  # a missing compiler or header, an operator inductor lacks: the same, eagerly
        cause: BaseException = err
        while (inner := getattr(cause, "inner_exception", None) or cause.__cause__) is not None:
            cause = inner  # the compiler's own error, under dynamo's wrapping
        lines = str(cause).strip().splitlines()
        log.warning("rendering: compiling %s failed (%s%s); rendering without compiling (slower)", fn.__name__,
                    type(cause).__name__, f": {lines[0]}" if lines else "")
        COMPILED.working = False
        return fn(*inputs)
    COMPILED.working = True
    return result


def _density_features(field: Any, x: Tensor) -> tuple[Tensor, Tensor]:
    return field.density_features(x)


def _density_along(field: Any, space: Any, origins: Tensor, directions: Tensor, ray: Tensor,
                   t: Tensor) -> tuple[Tensor, Tensor]:
    return field.density_features(space.field_points(torch.addcmul(origins[ray], t.unsqueeze(-1), directions[ray])))


def _colour(field: Any, features: Tensor, d: Tensor | None) -> Tensor:
    return field.colour(features, d)


def _forward(field: Any, x: Tensor, d: Tensor | None) -> tuple[Tensor, Tensor]:
    return field(x, d)


class RenderingField:
    """A field's functions as rendering calls them, without gradients: compiled (``run``) if the field opts in
    (``compiles = True``: the grid fields; the paper's MLP field is matrix products already)."""

    def __init__(self, field: Any) -> None:
        self.field = field
        self.compiles = bool(getattr(field, "compiles", False))
        self.device = next(iter(field.parameters()), torch.empty(0)).device

    def _run(self, fn: Callable, rows: int, *inputs: Any) -> Any:
        return run(fn, rows if self.compiles else 0, self.device, self.field, *inputs)

    def density_features(self, x: Tensor) -> tuple[Tensor, Tensor]:
        return self._run(_density_features, x.shape[0], x)

    def density_along(self, space: Any, origins: Tensor, directions: Tensor, ray: Tensor,
                      t: Tensor) -> tuple[Tensor, Tensor]:
        """``density_features`` at the points t (M,) along rays ``ray`` (M,) of (R, 3) ``origins`` and ``directions``
        in ``space`` (a ``RaySpace``): the gathers, the points and their field coordinates compiled with the field."""
        rows = ray.shape[0] if origins.shape[0] > 1 else 0  # one ray: eagerly (a graph for size 1 would be its own)
        return self._run(_density_along, rows, space, origins, directions, ray, t)

    def query_density(self, x: Tensor) -> Tensor:
        return self.density_features(x)[0]

    def colour(self, features: Tensor, d: Tensor | None) -> Tensor:
        return self._run(_colour, features.shape[0], features, d)

    def __call__(self, x: Tensor, d: Tensor | None = None) -> tuple[Tensor, Tensor]:
        return self._run(_forward, x.shape[0], x, d)


def for_rendering(field: Any) -> RenderingField:
    """``field`` as rendering evaluates it: compiled where ``run`` says, else as it is."""
    return RenderingField(field)
