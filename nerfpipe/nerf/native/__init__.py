"""Native CPU kernels: plain C, built on first use by the machine's C compiler and called through ctypes.

Two loops that torch runs as many small operations (``scatter.c`` says how each differs; the figures are in
docs/benchmarks.md): ``scatter_bags``, the grid fields' table gradient (``nerfpipe.nerf.fields.grid._Trilinear``),
the largest share of a training step on a CPU; ``contracted_steps``, the steps of a march in contracted space
(``nerfpipe.nerf.spaces.ray_space.ContractedSpace.steps``), eight operations over every ray for each step.

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
import tempfile
from pathlib import Path

import torch
from torch import Tensor

from nerfpipe.nerf.compiling import choice

log = logging.getLogger("nerfpipe.nerf.native")

SOURCE = Path(__file__).with_name("scatter.c")
FLAGS = ("-O3", "-shared", "-fPIC", "-std=c99")  # no -march=native: a shared home may serve other CPUs


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


def build(compiler: str, directory: Path) -> Path:
    """The shared library of ``SOURCE`` built by ``compiler`` into ``directory`` (reused when already there)."""
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30).stdout
    key = hashlib.sha256(SOURCE.read_bytes() + version.encode() + " ".join(FLAGS).encode()
                         + platform.machine().encode()).hexdigest()[:16]
    library = directory / f"nerfpipe_native_{key}.so"
    if library.exists():
        return library
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=directory) as scratch:
        built = Path(scratch) / library.name
        result = subprocess.run([compiler, *FLAGS, str(SOURCE), "-o", str(built)], capture_output=True, text=True,
                                timeout=120)
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
    try:
        lib = ctypes.CDLL(str(build(compiler, cache_dir())))
    except (OSError, RuntimeError, subprocess.SubprocessError) as err:
        log.warning("building the native kernels (the table gradient, the contracted march's steps) failed (%s: %s); "
                    "using torch's operators (slower)", type(err).__name__, err)
        return None
    p, i64 = ctypes.c_void_p, ctypes.c_int64
    lib.nerfpipe_scatter_bags.argtypes = [p, i64, i64, p, p, p, i64, i64]
    lib.nerfpipe_scatter_bags.restype = i64
    lib.nerfpipe_contracted_steps.argtypes = [p, p, p, p, p, i64, i64, p, p]
    lib.nerfpipe_contracted_steps.restype = i64
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
