"""Native CPU kernels: plain C, built on first use by the machine's C compiler and called through ctypes.

Loops that torch runs as many small operations (``kernels.c`` says how each differs; the figures are in
docs/benchmarks.md): ``grid_gather`` and ``grid_scatter``, the dense grid field's features and their gradient made
from the points themselves (``nerfpipe.nerf.fields.grid._NativeGrid``), the largest share of a training step on a
CPU; ``scatter_bags``, the table gradient of the fields that make their corners otherwise (hashed, planes) or whose
points train (``nerfpipe.nerf.fields.grid._Trilinear``); ``contracted_steps``, the steps of a march in contracted
space (``nerfpipe.nerf.spaces.ray_space.ContractedSpace.steps``), eight operations over every ray for each step;
``render_marched`` (``render.c``), rendering a dense grid field without gradients, one loop a ray from its march to
its colour (``nerfpipe.nerf.fused``); ``reached_marched`` and ``march_marched``, training's visibility pass and march
in the same loop (``nerfpipe.nerf.samplers``).

The library is built once a machine, in about a second, into the user's cache (``cache_dir``) under a name that
hashes its source, the compiler's identity and the machine's architecture, so that a changed source or a home
shared by other machines never loads a stale or foreign build; it is written beside and renamed into place, so
that two processes building at once each load a whole one. Without a C compiler, with ``NERFPIPE_COMPILE=off``,
or where the build fails (said once), callers get None and use torch's operators: the same results to float
rounding.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import logging
import os
import platform
import shutil
import subprocess
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from nerfpipe.nerf.compiling import choice

log = logging.getLogger("nerfpipe.nerf.native")

HERE = Path(__file__).parent
SOURCES = (HERE / "kernels.c", HERE / "render.c")
HEADERS = (HERE / "grid.h",)
# no -march=native: a shared home may serve other CPUs (render.c builds its own AVX2 clone, chosen at load time)
FLAGS = ("-O3", "-shared", "-fPIC", "-std=c99")
# tried in turn: OpenMP, whose runtime (libgomp.so.1) is then the one torch has loaded already, so the kernels' two
# halves run on torch's own threads, waiting for work between its operators; without render.c's AVX2 clone (a
# compiler without target_clones); on one thread
VARIANTS = (("-fopenmp",), ("-fopenmp", "-DNERFPIPE_NO_CLONES"), ("-DNERFPIPE_NO_CLONES",))


def cache_dir() -> Path:
    """``$NERFPIPE_CACHE_DIR/native``, else the user's cache (``$XDG_CACHE_HOME``, else ``~/.cache``)."""
    named = os.environ.get("NERFPIPE_CACHE_DIR")
    if named:
        return Path(named) / "native"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "nerfpipe" / "native"


def c_compiler() -> str | None:
    """``CC``, else gcc, clang or cc on the PATH, or None."""
    named = os.environ.get("CC")
    return shutil.which(named) if named else shutil.which("gcc") or shutil.which("clang") or shutil.which("cc")


def build(compiler: str, directory: Path, extra: tuple[str, ...] = ()) -> Path:
    """The shared library of ``SOURCES`` (and their ``HEADERS``) built by ``compiler`` with ``FLAGS`` and ``extra`` into
    ``directory`` (reused when already there)."""
    flags = (*FLAGS, *extra)
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30).stdout
    text = b"".join(p.read_bytes() for p in (*SOURCES, *HEADERS))
    key = hashlib.sha256(text + version.encode() + " ".join(flags).encode()
                         + platform.machine().encode()).hexdigest()[:16]
    library = directory / f"nerfpipe_native_{key}.so"
    if library.exists():
        return library
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=directory) as scratch:
        built = Path(scratch) / library.name
        includes = sorted({f"-I{p.parent}" for p in HEADERS})
        result = subprocess.run([compiler, *flags, *includes, *map(str, SOURCES), "-o", str(built), "-lm"],
                                capture_output=True, text=True, timeout=120)
        if result.returncode != 0:
            lines = (result.stderr or result.stdout).strip().splitlines()
            raise RuntimeError(lines[0] if lines else f"{compiler} exited {result.returncode}")
        os.replace(built, library)
    return library


@functools.cache
def library() -> ctypes.CDLL | None:
    """The kernels' library, built if needed; None where there is none to be had (see the module's docstring)."""
    compiler = c_compiler()
    if choice() == "off" or compiler is None:
        return None
    for extra in VARIANTS:
        try:
            lib = ctypes.CDLL(str(build(compiler, cache_dir(), extra)))
            break
        except (OSError, RuntimeError, subprocess.SubprocessError) as err:
            failure = err
    else:
        log.warning("building the native kernels (the grid's features and gradient, the contracted march's steps, "
                    "rendering) failed (%s: %s); using torch's operators (slower)", type(failure).__name__, failure)
        return None
    p, i64 = ctypes.c_void_p, ctypes.c_int64
    lib.nerfpipe_scatter_bags.argtypes = [p, i64, i64, p, p, p, i64, i64]
    lib.nerfpipe_scatter_bags.restype = i64
    lib.nerfpipe_contracted_steps.argtypes = [p, p, p, p, p, i64, i64, p, p]
    lib.nerfpipe_contracted_steps.restype = i64
    lib.nerfpipe_openmp.restype = i64
    lib.nerfpipe_grid_gather.argtypes = [p, i64, i64, p, i64, p, p, p, p, p, i64, p, p, i64]
    lib.nerfpipe_grid_scatter.argtypes = [p, i64, i64, p, i64, p, p, p, p, p, i64, p, i64]
    for kernel in (lib.nerfpipe_grid_gather, lib.nerfpipe_grid_scatter):
        kernel.restype = i64
    lib.nerfpipe_render_marched.argtypes = [ctypes.POINTER(_MarchedGrid), p, p, p, p, p, i64, p, p, p, p, i64]
    lib.nerfpipe_render_marched.restype = i64
    lib.nerfpipe_reached_marched.argtypes = [ctypes.POINTER(_MarchedGrid), p, p, i64, p, p, p, p, i64, p, i64]
    lib.nerfpipe_reached_marched.restype = i64
    lib.nerfpipe_march_marched.argtypes = [ctypes.POINTER(_MarchedGrid), p, p, p, p, p, i64, i64, i64, p, p, p, p, p,
                                           p, i64]
    lib.nerfpipe_march_marched.restype = i64
    return lib


def scatter_bags(out: Tensor, bags: Tensor, weights: Tensor, grad: Tensor) -> bool:
    """out[bags[i, c]] += weights[i, c] * grad[i] for (R, F) ``out``, (N, C) ``bags`` and ``weights``, (N, F)
    ``grad``, all float32 (int64 bags) on the CPU. Returns False, ``out`` untouched, where the kernel cannot run
    (no library, other dtypes or devices); raises IndexError if a bag names a row outside ``out``."""
    lib = library()
    if (lib is None or bags.dtype != torch.int64 or not out.is_contiguous()
            or any(t.device.type != "cpu" for t in (out, bags, weights, grad))
            or any(t.dtype != torch.float32 for t in (out, weights, grad))):
        return False
    bags, weights, grad = bags.contiguous(), weights.contiguous(), grad.contiguous()
    if weights.shape != bags.shape or grad.shape != (bags.shape[0], out.shape[1]):
        raise ValueError(f"scatter_bags: bags {tuple(bags.shape)}, weights {tuple(weights.shape)} and grad "
                         f"{tuple(grad.shape)} do not match a table of {out.shape[1]} features")
    outside = lib.nerfpipe_scatter_bags(out.data_ptr(), out.shape[0], out.shape[1], bags.data_ptr(), weights.data_ptr(),
                                        grad.data_ptr(), bags.shape[0], bags.shape[1])
    if outside:
        raise IndexError(f"scatter_bags: {outside} corners name rows outside the table's {out.shape[0]}")
    return True


def contracted_steps(x0: Tensor, dx: Tensor, base: Tensor, near: Tensor, far: Tensor, most: int) -> Tensor | None:
    """The edges (R, K + 1) of the steps ``ContractedSpace.steps`` takes along R rays, x0 + t dx (R, 3) in the
    box's units, from ``near`` to ``far`` (R,) with steps ``base`` (R,) times the squared clamped norm, K the most
    any ray took (at least 1, at most ``most``). None where the kernel cannot run: no library, tensors not float32
    on the CPU, a gradient to carry, or a value that is not finite (the kernel says so; torch's operators carry NaN
    as its loop would not)."""
    lib = library()
    inputs = (x0, dx, base, near, far)
    if lib is None or any(t.device.type != "cpu" or t.dtype != torch.float32 or t.requires_grad for t in inputs):
        return None
    x0, dx, base, near, far = (t.contiguous() for t in inputs)
    edges = torch.empty(len(near), most + 1)
    counts = torch.empty(len(near), dtype=torch.int64)
    longest = lib.nerfpipe_contracted_steps(x0.data_ptr(), dx.data_ptr(), base.data_ptr(), near.data_ptr(),
                                            far.data_ptr(), len(near), most, edges.data_ptr(), counts.data_ptr())
    return None if longest < 0 else edges[:, :longest + 1]


def level_sizes(resolutions: Tensor, sizes: Tensor | None) -> Tensor:
    """Each level's rows as the kernels take them: ``sizes`` (fewer than a level's (r + 1)^3 vertices where it is
    hashed, ``nerfpipe.nerf.fields.hash``), or every level dense where None."""
    return ((resolutions.to(torch.int64) + 1) ** 3 if sizes is None else sizes.to(torch.int64)).contiguous()


def _grid_inputs(table: Tensor, x: Tensor, lo: Tensor, hi: Tensor, resolutions: Tensor, offsets: Tensor,
                 sizes: Tensor | None) -> tuple | None:
    """The grid kernels' inputs made contiguous, or None where they cannot run (no library, not float32 on the CPU,
    x not (M, 3), levels, offsets and sizes of different lengths)."""
    lib = library()
    sizes = level_sizes(resolutions, sizes)
    if (lib is None or x.dim() != 2 or x.shape[1] != 3 or not table.is_contiguous()
            or not len(resolutions) == len(offsets) == len(sizes)
            or any(t.device.type != "cpu" for t in (table, x, lo, hi, resolutions, offsets, sizes))
            or any(t.dtype != torch.float32 for t in (table, x, lo, hi))):
        return None
    return (lib, x.contiguous(), lo.contiguous(), hi.contiguous(), resolutions.to(torch.int64).contiguous(),
            offsets.to(torch.int64).contiguous(), sizes)


def _grid_result(code: int, table: Tensor, resolutions: Tensor, offsets: Tensor, sizes: Tensor) -> bool:
    """Whether a grid kernel ran (0), refused a NaN (-1); raises ValueError where the levels overrun the table (-2,
    checked by the kernel itself: no work in Python on every call)."""
    if code == -2:
        raise ValueError(f"grid kernels: levels of {resolutions.tolist()} cells, {sizes.tolist()} rows at rows "
                         f"{offsets.tolist()} do not fit a table of {table.shape[0]} rows (a hashed level's rows: a "
                         "power of two below its vertices)")
    return code == 0


def grid_gather(table: Tensor, x: Tensor, lo: Tensor, hi: Tensor, resolutions: Tensor, offsets: Tensor,
                sizes: Tensor | None = None) -> tuple[Tensor, Tensor] | None:
    """A grid field's features (M, L, F) of points x (M, 3) and whether each lies in the box [lo, hi] (M,), from its
    (V, F) ``table`` whose level l, of ``resolutions[l]`` cells a side, starts at row ``offsets[l]`` and holds
    ``sizes[l]`` rows (hashed where fewer than its vertices; None: every level dense): the trilinear corners and
    their weighted sum of ``nerfpipe.nerf.fields.grid`` (and ``hash``) in one pass. None where the kernel cannot
    run (see ``_grid_inputs``) or a coordinate is NaN (torch's operators then say what they say)."""
    inputs = _grid_inputs(table, x, lo, hi, resolutions, offsets, sizes)
    if inputs is None:
        return None
    lib, x, lo, hi, resolutions, offsets, sizes = inputs
    out = torch.empty(len(x), len(resolutions), table.shape[1])
    inside = torch.empty(len(x), dtype=torch.bool)
    code = lib.nerfpipe_grid_gather(table.data_ptr(), table.shape[0], table.shape[1], x.data_ptr(), len(x),
                                    lo.data_ptr(), hi.data_ptr(), resolutions.data_ptr(), offsets.data_ptr(),
                                    sizes.data_ptr(), len(resolutions), out.data_ptr(), inside.data_ptr(),
                                    torch.get_num_threads())
    return (out, inside) if _grid_result(code, table, resolutions, offsets, sizes) else None


def grid_scatter(table_grad: Tensor, x: Tensor, lo: Tensor, hi: Tensor, resolutions: Tensor, offsets: Tensor,
                 grad: Tensor, sizes: Tensor | None = None) -> bool:
    """``grid_gather``'s backward: adds each point's weighted (M, L, F) ``grad`` into the rows of its corners in
    ``table_grad`` (V, F). False, ``table_grad`` untouched, where the kernel cannot run."""
    inputs = _grid_inputs(table_grad, x, lo, hi, resolutions, offsets, sizes)
    if inputs is None or grad.dtype != torch.float32 or grad.device.type != "cpu":
        return False
    lib, x, lo, hi, resolutions, offsets, sizes = inputs
    if grad.shape != (len(x), len(resolutions), table_grad.shape[1]):
        raise ValueError(f"grid_scatter: grad {tuple(grad.shape)} is not (points, levels, features) = "
                         f"({len(x)}, {len(resolutions)}, {table_grad.shape[1]})")
    grad = grad.contiguous()
    code = lib.nerfpipe_grid_scatter(table_grad.data_ptr(), table_grad.shape[0], table_grad.shape[1], x.data_ptr(),
                                     len(x), lo.data_ptr(), hi.data_ptr(), resolutions.data_ptr(), offsets.data_ptr(),
                                     sizes.data_ptr(), len(resolutions), grad.data_ptr(), torch.get_num_threads())
    return _grid_result(code, table_grad, resolutions, offsets, sizes)


_f3 = ctypes.c_float * 3


class _MarchedGrid(ctypes.Structure):
    """render.c's MarchedGrid, field by field."""

    _fields_ = [("contracted", ctypes.c_int64), ("center", _f3), ("half", _f3), ("step", ctypes.c_float),
                ("most", ctypes.c_int64), ("limit", ctypes.c_double), ("occupied", ctypes.c_void_p),
                ("occupancy_resolution", ctypes.c_int64), ("occupancy_lo", _f3), ("occupancy_hi", _f3),
                ("table", ctypes.c_void_p), ("rows", ctypes.c_int64), ("features", ctypes.c_int64),
                ("levels", ctypes.c_int64), ("resolutions", ctypes.c_void_p), ("offsets", ctypes.c_void_p),
                ("sizes", ctypes.c_void_p),
                ("lo", _f3), ("hi", _f3), ("hidden", ctypes.c_int64), ("geo", ctypes.c_int64),
                ("dir_freqs", ctypes.c_int64), ("view_dependent", ctypes.c_int64),
                *((name, ctypes.c_void_p) for name in ("w1", "b1", "w2", "b2", "w3", "b3", "w4", "b4", "w5", "b5"))]


@dataclass(frozen=True)
class MarchedGrid:
    """What ``render_marched`` renders: a march through an occupancy grid over a dense grid field.

    contracted: the ray space contracts what lies beyond ``center`` +- ``half`` (its scene box; else the field is in
    world coordinates); step, most: the march's step in field units and the most steps a ray takes; early_stop: the
    transmittance at which a ray stops (0: never); occupied (r^3,) bool over the box ``occupancy_box``; table (V, F),
    resolutions, offsets and sizes (L,) of the field's levels over ``box`` (a level hashed where its rows are fewer
    than its vertices); layers: the density MLP's two and the colour MLP's
    three (weight (out, in), bias (out,)) pairs, float32; dir_freqs, view_dependent: what the colour MLP reads beside
    the density MLP's other outputs (``nerfpipe.nerf.fields.grid.GridField``)."""

    contracted: bool
    center: tuple[float, float, float]
    half: tuple[float, float, float]
    step: float
    most: int
    early_stop: float
    occupied: Tensor
    occupancy_box: tuple[tuple[float, ...], tuple[float, ...]]
    table: Tensor
    resolutions: Tensor
    offsets: Tensor
    sizes: Tensor
    box: tuple[tuple[float, ...], tuple[float, ...]]
    layers: tuple[tuple[Tensor, Tensor], ...]
    dir_freqs: int
    view_dependent: bool


def _occupancy_bytes(occupied: Tensor) -> Tensor:
    """An occupancy grid's cells as the kernels read them, a byte each: its bools read as bytes where they are laid
    out so (no copy of its cells on every training step)."""
    cells = occupied.contiguous()
    return cells.view(torch.uint8) if cells.dtype == torch.bool else cells.to(torch.uint8)


def _marched_struct(grid: MarchedGrid, rays: tuple[Tensor, ...]) -> tuple[ctypes.CDLL, _MarchedGrid, list] | None:
    """render.c's MarchedGrid of ``grid`` and the tensors it points into (kept alive by the caller), or None where the
    kernels cannot run (no library, tensors not float32 on the CPU)."""
    lib = library()
    weights = [t for layer in grid.layers for t in layer]
    if (lib is None or len(grid.layers) != 5 or any(t.device.type != "cpu" or t.dtype != torch.float32
                                                    for t in (*rays, grid.table, *weights))):
        return None
    occupied = _occupancy_bytes(grid.occupied)
    table = grid.table.detach().contiguous()
    resolutions, offsets = (t.to(torch.int64).contiguous() for t in (grid.resolutions, grid.offsets))
    sizes = level_sizes(resolutions, grid.sizes)
    # (in, out), but the colour's last layer (3, in): render.c's products
    kept = [t.detach().t().contiguous() if t.dim() == 2 and i < 8 else t.detach().contiguous()
            for i, t in enumerate(weights)]
    (hidden, features_in), geo = grid.layers[0][0].shape, grid.layers[1][0].shape[0] - 1
    struct = _MarchedGrid(
        int(grid.contracted), _f3(*grid.center), _f3(*grid.half), grid.step, grid.most,
        -math.log(grid.early_stop) if grid.early_stop > 0 else math.inf, occupied.data_ptr(),
        round(occupied.numel() ** (1 / 3)), _f3(*grid.occupancy_box[0]), _f3(*grid.occupancy_box[1]),
        table.data_ptr(), table.shape[0], table.shape[1], len(resolutions), resolutions.data_ptr(), offsets.data_ptr(),
        sizes.data_ptr(), _f3(*grid.box[0]), _f3(*grid.box[1]), hidden, geo, grid.dir_freqs, int(grid.view_dependent),
        *(t.data_ptr() for t in kept))
    if struct.occupancy_resolution ** 3 != occupied.numel() or features_in != len(resolutions) * table.shape[1]:
        raise ValueError(f"the native renderer: an occupancy grid of {occupied.numel()} cells or a density MLP of "
                         f"{features_in} inputs does not fit {len(resolutions)} levels of {table.shape[1]} features")
    return lib, struct, [occupied, table, resolutions, offsets, sizes, *kept]


def render_marched(grid: MarchedGrid, origins: Tensor, directions: Tensor, viewdirs: Tensor, near: Tensor,
                   far: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor] | None:
    """R rays (origins, directions, viewdirs (R, 3), near, far (R,)) rendered through ``grid`` without gradients, each
    in one loop from its march to its colour (render.c): rgb (R, 3) composited onto nothing, depth and acc (R,) as
    ``volume_render`` gives them, and each ray's samples evaluated (R,). None where the kernel cannot run: no
    library, tensors not float32 on the CPU, a value that is not finite, sizes beyond the kernel's bounds."""
    rays = tuple(t.detach().contiguous() for t in (origins, directions, viewdirs, near, far))
    made = _marched_struct(grid, rays)
    if made is None:
        return None
    lib, struct, _alive = made
    origins, directions, viewdirs, near, far = rays
    n = len(near)
    rgb, depth, acc = torch.empty(n, 3), torch.empty(n), torch.empty(n)
    counts = torch.empty(n, dtype=torch.int64)
    code = lib.nerfpipe_render_marched(ctypes.byref(struct), origins.data_ptr(), directions.data_ptr(),
                                       viewdirs.data_ptr(), near.data_ptr(), far.data_ptr(), n, rgb.data_ptr(),
                                       depth.data_ptr(), acc.data_ptr(), counts.data_ptr(), torch.get_num_threads())
    return None if _grid_result(code, *_alive[1:5]) is False else (rgb, depth, acc, counts)


def reached_marched(grid: MarchedGrid, origins: Tensor, directions: Tensor, ray: Tensor, t: Tensor, starts: Tensor,
                    ends: Tensor) -> Tensor | None:
    """Which of N samples (ray (N,) int64, non-decreasing; t, starts, ends (N,)) of R rays (origins, directions (R, 3))
    each ray reaches before its transmittance falls below ``grid.early_stop``, from ``grid``'s density: a mask (N,),
    what ``nerfpipe.nerf.samplers.march.visible`` keeps, in one native loop a ray (render.c). None where the kernel
    cannot run (as ``render_marched``; a sample that names no ray too)."""
    rays = tuple(x.detach().contiguous() for x in (origins, directions, t, starts, ends))
    made = _marched_struct(grid, rays)
    if made is None or ray.dtype != torch.int64 or ray.device.type != "cpu":
        return None
    lib, struct, _alive = made
    origins, directions, t, starts, ends = rays
    ray = ray.contiguous()
    keep = torch.empty(len(ray), dtype=torch.bool)
    code = lib.nerfpipe_reached_marched(ctypes.byref(struct), origins.data_ptr(), directions.data_ptr(), len(origins),
                                        ray.data_ptr(), t.data_ptr(), starts.data_ptr(), ends.data_ptr(), len(ray),
                                        keep.data_ptr(), torch.get_num_threads())
    return None if _grid_result(code, *_alive[1:5]) is False else keep


def march_marched(contracted: bool, center: tuple[float, ...], half: tuple[float, ...], step: float, most: int,
                  occupied: Tensor, occupancy_box: tuple[tuple[float, ...], tuple[float, ...]], origins: Tensor,
                  directions: Tensor, near: Tensor, far: Tensor, u: Tensor,
                  budget: int) -> tuple[tuple[Tensor, Tensor, Tensor, Tensor, Tensor], int] | None:
    """Training's march in one native loop a ray (render.c: ``nerfpipe.nerf.samplers.march.march`` and
    ``within_budget``): the occupied steps of R rays (origins, directions (R, 3), near, far (R,); the march's
    ``contracted``, ``center``, ``half``, ``step`` and ``most`` as ``MarchedGrid``'s, through the (r^3,) ``occupied``
    cells over ``occupancy_box``), each sample a fraction u (R,) into its step, of the leading rays whose samples
    number at most ``budget`` > 0 together (at least one ray). Returns (ray, t, starts, ends, step along the ray), each
    (N,), and how many rays were kept; None where the kernel cannot run (no library, tensors not float32 on the CPU,
    a value not finite)."""
    lib = library()
    rays = tuple(x.detach().contiguous() for x in (origins, directions, near, far, u))
    if (lib is None or budget < 1 or not len(near) or any(x.device.type != "cpu" or x.dtype != torch.float32 for x in rays)
            or occupied.device.type != "cpu"):
        return None
    cells = _occupancy_bytes(occupied)
    struct = _MarchedGrid(int(contracted), _f3(*center), _f3(*half), step, most, math.inf, cells.data_ptr(),
                          round(cells.numel() ** (1 / 3)), _f3(*occupancy_box[0]), _f3(*occupancy_box[1]))
    if struct.occupancy_resolution ** 3 != cells.numel():
        raise ValueError(f"march_marched: an occupancy grid of {cells.numel()} cells is not a cube")
    origins, directions, near, far, u = rays
    capacity = budget + most
    ray, k = torch.empty(capacity, dtype=torch.int64), torch.empty(capacity, dtype=torch.int64)
    t, starts, ends = torch.empty(capacity), torch.empty(capacity), torch.empty(capacity)
    kept = ctypes.c_int64(0)
    count = lib.nerfpipe_march_marched(ctypes.byref(struct), origins.data_ptr(), directions.data_ptr(),
                                       near.data_ptr(), far.data_ptr(), u.data_ptr(), len(near), budget, capacity,
                                       ray.data_ptr(), t.data_ptr(), starts.data_ptr(), ends.data_ptr(), k.data_ptr(),
                                       ctypes.byref(kept), torch.get_num_threads())
    if count < 0:
        return None
    return (ray[:count], t[:count], starts[:count], ends[:count], k[:count]), kept.value
