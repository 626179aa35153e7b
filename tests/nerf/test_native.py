"""The native C kernels (nerfpipe.nerf.native): the grid fields' table gradient (torch's sums to float rounding,
IEEE infinities where torch has them, rows outside the table refused) and the march's steps in contracted space
(torch's loop to float rounding, what is not finite left to torch); a machine without a compiler, or whose build
fails, back on torch's operators, said once."""

from __future__ import annotations

import logging

import pytest
import torch

from nerfpipe.nerf import native
from nerfpipe.nerf.compiling import VARIABLE
from nerfpipe.nerf.fields.configs import GridConfig
from nerfpipe.nerf.fields.grid import GridField

needs_compiler = pytest.mark.skipif(native.c_compiler() is None, reason="no C compiler on this machine")


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    """The library looked for again, built into a folder of this test's own."""
    monkeypatch.setenv("NERFPIPE_CACHE_DIR", str(tmp_path / "cache"))
    native.library.cache_clear()
    yield tmp_path / "cache" / "native"
    native.library.cache_clear()


def reference(rows: int, bags: torch.Tensor, weights: torch.Tensor, grad: torch.Tensor) -> torch.Tensor:
    out = torch.zeros(rows, grad.shape[1])
    out.index_add_(0, bags.reshape(-1), (grad.unsqueeze(1) * weights.unsqueeze(-1)).reshape(-1, grad.shape[1]))
    return out


def problem(n=5000, corners=8, rows=700, features=4, seed=0):
    g = torch.Generator().manual_seed(seed)
    bags = torch.randint(0, rows, (n, corners), generator=g)
    return rows, bags, torch.rand(n, corners, generator=g), torch.randn(n, features, generator=g)


@needs_compiler
def test_the_kernel_adds_what_index_add_adds(fresh) -> None:
    rows, bags, weights, grad = problem()
    bags[:50] = 3  # one row that many corners add to, and rows at both ends of the table
    bags[50:60, 0], bags[60:70, 1] = 0, rows - 1
    out = torch.zeros(rows, grad.shape[1])
    assert native.scatter_bags(out, bags, weights, grad)
    torch.testing.assert_close(out, reference(rows, bags, weights, grad), atol=1e-5, rtol=1e-5)
    again = torch.ones(rows, grad.shape[1])  # added to what is there
    native.scatter_bags(again, bags, weights, grad)
    torch.testing.assert_close(again, out + 1)
    hand = torch.zeros(2, 1)  # by hand: row 0 gets 0.5 * 4, row 1 gets 0.5 * 2 + 0.25 * 2 + 0 * 4
    native.scatter_bags(hand, torch.tensor([[1, 1], [0, 1]]), torch.tensor([[0.5, 0.25], [0.5, 0.0]]),
                        torch.tensor([[2.0], [4.0]]))
    assert hand.flatten().tolist() == [2.0, 1.5]


@needs_compiler
def test_extreme_gradients_overflow_as_torch_s_do(fresh) -> None:
    rows, bags, weights, grad = problem(n=200, rows=40)
    grad[0], grad[1], grad[2] = 3e38, float("inf"), -float("inf")
    weights[3] = 0.0
    grad[3] = 1e30
    out = torch.zeros(rows, grad.shape[1])
    assert native.scatter_bags(out, bags, weights, grad)
    torch.testing.assert_close(out, reference(rows, bags, weights, grad), equal_nan=True, atol=1e-4, rtol=1e-5)


@needs_compiler
def test_a_row_outside_the_table_is_refused_and_other_tensors_left_to_torch(fresh) -> None:
    rows, bags, weights, grad = problem(n=10, rows=20)
    for bad in (20, -1):
        bags[4, 2] = bad
        with pytest.raises(IndexError, match="1 corners name rows outside the table's 20"):
            native.scatter_bags(torch.zeros(rows, 4), bags, weights, grad)
    bags[4, 2] = 0
    out = torch.zeros(rows, 4, dtype=torch.float64)
    assert not native.scatter_bags(out, bags, weights.double(), grad.double()) and not out.any()
    with pytest.raises(ValueError, match="do not match a table of 3 features"):
        native.scatter_bags(torch.zeros(rows, 3), bags, weights, grad)


@needs_compiler
def test_the_library_is_built_once_and_again_for_a_changed_source(fresh, monkeypatch, tmp_path) -> None:
    assert native.library() is not None
    built = sorted(fresh.glob("*.so"))
    assert len(built) == 1
    stamp = built[0].stat().st_mtime_ns
    native.library.cache_clear()
    assert native.library() is not None and built[0].stat().st_mtime_ns == stamp  # reused, not rebuilt
    copies = tmp_path / "changed"
    copies.mkdir()
    for source in (*native.SOURCES, *native.HEADERS):
        (copies / source.name).write_text(source.read_text())
    (copies / "render.c").write_text((copies / "render.c").read_text() + "\n/* changed */\n")
    monkeypatch.setattr(native, "SOURCES", tuple(copies / p.name for p in native.SOURCES))
    monkeypatch.setattr(native, "HEADERS", tuple(copies / p.name for p in native.HEADERS))
    native.library.cache_clear()
    assert native.library() is not None and len(list(fresh.glob("*.so"))) == 2
    assert not list(fresh.glob("tmp*"))  # the build's scratch folder is gone


def test_without_a_compiler_or_with_compile_off_torch_adds_instead(fresh, monkeypatch, caplog) -> None:
    rows, bags, weights, grad = problem(n=100, rows=30)
    monkeypatch.setenv(VARIABLE, "off")
    assert native.library() is None
    assert not native.scatter_bags(torch.zeros(rows, 4), bags, weights, grad)
    native.library.cache_clear()
    monkeypatch.setenv(VARIABLE, "native")
    monkeypatch.setenv("CC", "no-such-compiler")
    assert native.library() is None
    native.library.cache_clear()
    monkeypatch.setenv("CC", "false")  # a compiler that fails: said once, in one line, then torch's operators
    with caplog.at_level(logging.WARNING, logger="nerfpipe.nerf.native"):
        assert native.library() is None and native.library() is None
        field = GridField((-1.0,) * 3, (1.0,) * 3, GridConfig(levels=2, min_resolution=4, max_resolution=8))
        field(torch.rand(50, 3), torch.nn.functional.normalize(torch.randn(50, 3), dim=-1))[1].sum().backward()
    assert field.table.grad is not None and bool(torch.isfinite(field.table.grad).all())
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "building the native kernels" in lines[0] and "false" in lines[0]


@needs_compiler
def test_a_field_s_table_gradient_is_the_same_native_or_not(fresh, monkeypatch) -> None:
    torch.manual_seed(0)
    field = GridField((-1.0,) * 3, (1.0,) * 3, GridConfig(levels=3, max_resolution=32))
    x = torch.cat([torch.tensor([[1e30, -1e30, 0.0], [float("inf"), 0.0, 0.0], [1.0, 1.0, 1.0]]),
                   torch.rand(2000, 3) * 2 - 1])
    d = torch.nn.functional.normalize(torch.randn(len(x), 3), dim=-1)
    grads = {}
    for mode in ("native", "off"):
        monkeypatch.setenv(VARIABLE, mode)
        native.library.cache_clear()
        field.zero_grad(set_to_none=True)
        rgb, sigma = field(x, d)
        (rgb.sum() + sigma.sum()).backward()
        grads[mode] = field.table.grad.clone()
    assert native.library() is None  # the second pass was torch's
    assert bool(torch.isfinite(grads["native"]).all()) and grads["native"].abs().sum() > 0
    torch.testing.assert_close(grads["native"], grads["off"], atol=1e-6, rtol=1e-5)


def steps_both_ways(monkeypatch, origins, directions, near, far, step, most):
    from nerfpipe.nerf.spaces.ray_space import ContractedSpace

    space = ContractedSpace(((-1.0, -2.0, -0.5), (1.0, 2.0, 1.5)))
    out = {}
    for mode in ("native", "off"):
        monkeypatch.setenv(VARIABLE, mode)
        native.library.cache_clear()
        out[mode] = space.steps(origins, directions, near, far, step, most)
    return out["native"], out["off"]


@needs_compiler
@pytest.mark.parametrize("most", [4000, 7])
def test_contracted_steps_are_torch_s_loop(fresh, monkeypatch, most) -> None:
    """The native march steps in contracted space: the same columns as torch's loop (the longest ray's count, or
    ``most``), each ray's edges to float rounding, repeating far once reached; rays from inside and outside the box,
    a ray along an axis, one whose near lies past its far, and one that never leaves the box."""
    g = torch.Generator().manual_seed(1)
    origins = torch.cat([torch.randn(200, 3, generator=g) * 3, torch.zeros(3, 3)])
    directions = torch.nn.functional.normalize(torch.randn(203, 3, generator=g), dim=-1)
    directions[200] = torch.tensor([0.0, 0.0, 1.0])
    near = torch.rand(203, generator=g) * 0.5
    far = near + torch.rand(203, generator=g) * 80
    near[201], far[201] = 5.0, 2.0  # empty: one step, to far
    far[202] = near[202] + 0.3  # inside the box all the way
    (starts, ends), (s_ref, e_ref) = steps_both_ways(monkeypatch, origins, directions, near, far, 0.03, most)
    assert starts.shape == s_ref.shape and (most == 7) == (starts.shape[1] == 7)
    torch.testing.assert_close(starts, s_ref, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(ends, e_ref, rtol=1e-4, atol=1e-5)
    assert torch.equal(starts[:, 1:], ends[:, :-1]) and float(ends[201, 0]) == 2.0
    if most == 4000:
        assert torch.equal(ends[:, -1], far)  # every ray reaches its far


@needs_compiler
def test_contracted_steps_leave_what_is_not_finite_to_torch(fresh, monkeypatch) -> None:
    origins, directions = torch.zeros(2, 3), torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    far = torch.tensor([float("nan"), 30.0])
    (starts, ends), (s_ref, e_ref) = steps_both_ways(monkeypatch, origins, directions, torch.zeros(2), far, 0.05, 400)
    torch.testing.assert_close(ends, e_ref, equal_nan=True)
    assert bool(torch.isnan(ends[0]).any()) and not bool(torch.isnan(ends[1]).any())


def torch_features(field: GridField, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The grid's features (M, L, F) and inside (M,) as torch's operators compute them."""
    from nerfpipe.nerf.fields.grid import gather_corners

    u = (x - field.lo) / (field.hi - field.lo)
    index, weights = field.corners(u)
    return gather_corners(field.table, index, weights), ((u >= 0) & (u <= 1)).all(dim=-1)


def edge_points(g: torch.Generator) -> torch.Tensor:
    """Random points in and around the box (-1, -2, -0.5)-(1, 2, 1.5), and points on its faces, corners and a level's
    vertices, at infinities and far beyond it."""
    lo, hi = torch.tensor([-1.0, -2.0, -0.5]), torch.tensor([1.0, 2.0, 1.5])
    inside = lo + (hi - lo) * torch.rand(3000, 3, generator=g)
    around = lo + (hi - lo) * (torch.rand(500, 3, generator=g) * 1.6 - 0.3)
    vertices = lo + (hi - lo) * torch.randint(0, 9, (200, 3), generator=g) / 8.0  # on every level's vertices
    extremes = torch.tensor([[float("inf"), 0.0, 0.0], [0.0, -float("inf"), 1.0], [1e30, -1e30, 0.0], [-1.0, -2.0, -0.5],
                             [1.0, 2.0, 1.5], [1.0, -2.0, 1.5]])
    return torch.cat([inside, around, vertices, extremes])


@needs_compiler
@pytest.mark.parametrize("hashed", [False, True])
def test_the_grid_kernels_are_torch_s_corners_and_sums(fresh, hashed) -> None:
    """The native gather: torch's features to float rounding and the same inside flags, for points in, on and around
    the box and at infinities; its scatter: torch's table gradient, computed from the same points. Hashed: levels of
    16 and 32 cells (4913 and 35937 vertices) in tables of 2^12 rows by Instant-NGP's hash, the first level dense."""
    from nerfpipe.nerf.fields.configs import HashConfig
    from nerfpipe.nerf.fields.grid import native_features
    from nerfpipe.nerf.fields.hash import HashGridField

    torch.manual_seed(0)
    box = ((-1.0, -2.0, -0.5), (1.0, 2.0, 1.5))
    field = (HashGridField(*box, HashConfig(levels=3, min_resolution=8, max_resolution=32, log2_table=12)) if hashed
             else GridField(*box, GridConfig(levels=3, min_resolution=8, max_resolution=32)))
    assert field.sizes.tolist() == ([729, 4096, 4096] if hashed else [729, 4913, 35937])
    with torch.no_grad():
        field.table.normal_()  # rows that differ, so that a wrong row shows
    x = edge_points(torch.Generator().manual_seed(0))
    features, inside = native_features(field, x)
    expected, expected_inside = torch_features(field, x)
    torch.testing.assert_close(features, expected, atol=1e-6, rtol=1e-5)
    assert torch.equal(inside, expected_inside) and bool(inside[:3000].all()) and bool(inside[3500:3700].all())
    assert inside[-6:].tolist() == [False, False, False, True, True, True]  # the faces are inside
    grad = torch.randn_like(features)
    native_grad, = torch.autograd.grad((features * grad).sum(), field.table)
    torch_grad, = torch.autograd.grad((expected * grad).sum(), field.table)
    torch.testing.assert_close(native_grad, torch_grad, atol=1e-5, rtol=1e-5)


@needs_compiler
def test_the_grid_gather_by_hand(fresh) -> None:
    """One level of one cell over the box [0, 2]^3, vertex (i, j, k) holding 4 i + 2 j + k: the centre reads their
    mean, 3.5; (0.5, 1, 2) reads 4 (0.25) + 2 (0.5) + 1 = 3; a point past a face reads the face; the gradient of the
    centre's feature is 1/8 on every vertex."""
    from nerfpipe.nerf.fields.grid import native_features

    field = GridField((0.0,) * 3, (2.0,) * 3, GridConfig(levels=1, min_resolution=1, max_resolution=1, features=1))
    with torch.no_grad():
        field.table.copy_(torch.arange(8.0).view(8, 1))
    x = torch.tensor([[1.0, 1.0, 1.0], [0.5, 1.0, 2.0], [5.0, 1.0, 1.0]])
    features, inside = native_features(field, x)
    assert features.flatten().tolist() == [3.5, 3.0, 5.5] and inside.tolist() == [True, True, False]
    grad, = torch.autograd.grad(features[0].sum(), field.table)
    assert grad.flatten().tolist() == [0.125] * 8


@needs_compiler
def test_the_grid_kernels_serve_only_where_they_compute_the_same(fresh, monkeypatch) -> None:
    """The dense and the hashed grid fields go through the native gather; planes (corners of their own), points that
    take a gradient (camera refinement) and NaN points go through torch's operators, NaN failing as torch's does; a
    scatter that cannot run leaves the gradient to the field's own corners and ``index_add_``, the same gradient."""
    from nerfpipe.nerf.fields import grid
    from nerfpipe.nerf.fields.configs import HashConfig, PlanesConfig
    from nerfpipe.nerf.fields.hash import HashGridField
    from nerfpipe.nerf.fields.planes import PlaneField

    served = []
    gather = native.grid_gather
    monkeypatch.setattr(native, "grid_gather", lambda *a: served.append(len(a[1])) or gather(*a))
    torch.manual_seed(0)
    box = ((-1.0,) * 3, (1.0,) * 3)
    field = GridField(*box, GridConfig(levels=2, min_resolution=4, max_resolution=16))
    x = torch.rand(300, 3) * 2 - 1
    field.encode(x)
    assert served == [300]
    hashed = HashGridField(*box, HashConfig(levels=2, min_resolution=4, max_resolution=64, log2_table=10))
    hashed.encode(x[:10])
    PlaneField(*box, PlanesConfig(levels=2, min_resolution=4, max_resolution=16)).encode(x[:7])  # corners of its own
    field.encode(x[:20].requires_grad_())
    assert served == [300, 10]
    nan = x[:5].clone()
    nan[2, 1] = float("nan")
    with pytest.raises(RuntimeError):
        field.encode(nan)
    assert served == [300, 10, 5]  # asked, refused, then torch's operators
    for each in (field, hashed):  # a scatter that cannot run: the field's own corners and index_add_, the same
        with torch.no_grad():
            each.table.normal_()
        features = grid.native_features(each, x)[0]
        gradient, = torch.autograd.grad((features * features.detach()).sum(), each.table)
        with monkeypatch.context() as patch:
            patch.setattr(native, "grid_scatter", lambda *a: False)
            features = grid.native_features(each, x)[0]
            fallback, = torch.autograd.grad((features * features.detach()).sum(), each.table)
        torch.testing.assert_close(fallback, gradient, atol=1e-5, rtol=1e-5)


@needs_compiler
def test_levels_that_overrun_the_table_are_refused(fresh) -> None:
    table = torch.zeros(100, 2)  # a level of 4 cells a side has 125 vertices
    with pytest.raises(ValueError, match="do not fit a table of 100 rows"):
        native.grid_gather(table, torch.zeros(1, 3), torch.zeros(3), torch.ones(3), torch.tensor([4]), torch.tensor([0]))
    assert native.grid_gather(table.double(), torch.zeros(1, 3), torch.zeros(3), torch.ones(3), torch.tensor([1]),
                              torch.tensor([0])) is None
    # hashed levels: fewer rows than vertices, a power of two, within the table
    args = (torch.zeros(1, 3), torch.zeros(3), torch.ones(3), torch.tensor([4]), torch.tensor([0]))
    assert native.grid_gather(table, *args, torch.tensor([64])) is not None
    for rows in (96, 126, 128, 0):  # not a power of two; more than the 125 vertices; past the table; none
        with pytest.raises(ValueError, match="do not fit a table of 100 rows"):
            native.grid_gather(table, *args, torch.tensor([rows]))


@needs_compiler
def test_two_threads_give_one_thread_s_sums_exactly(fresh) -> None:
    """On torch's threads (OpenMP, where the compiler has it), the gather splits the points and the scatter the
    table's rows, each row receiving its additions in the points' order: the same bits as one thread, on enough
    points for the work to split (16,384: beer's step)."""
    torch.manual_seed(0)
    field = GridField((-1.0,) * 3, (1.0,) * 3, GridConfig(levels=3, min_resolution=16, max_resolution=64))
    x = torch.rand(16384, 3) * 2.2 - 1.1
    grad = torch.randn(16384, 3, field.config.features)
    args = (x, field.lo, field.hi, field.resolutions, field.offsets)
    results = {}
    threads = torch.get_num_threads()
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            table_grad = torch.zeros_like(field.table)
            assert native.grid_scatter(table_grad, *args, grad)
            results[n] = (*native.grid_gather(field.table.detach(), *args), table_grad)
    finally:
        torch.set_num_threads(threads)
    for one, two in zip(results[1], results[2]):
        assert torch.equal(one, two)


@needs_compiler
def test_openmp_runs_on_torch_s_runtime_or_is_left_out(fresh, monkeypatch, caplog) -> None:
    """The OpenMP build shares the OpenMP runtime torch loaded (one libgomp.so.1 in the process, not a second pool of
    threads); a compiler without OpenMP (here a flag it refuses) gets the one-thread build, silently."""
    import sys

    lib = native.library()
    assert lib is not None
    if native.c_compiler().endswith("gcc"):
        assert lib.nerfpipe_openmp() == 1  # gcc has OpenMP
    if sys.platform.startswith("linux"):  # what answers to the name the library asks for, libgomp.so.1 (pycolmap and
        with open("/proc/self/maps") as maps:  # rawpy bring their own runtimes under hashed names of their own)
            runtimes = {line.split()[-1] for line in maps if line.split()[-1].rsplit("/", 1)[-1].startswith("libgomp.so")}
        assert len(runtimes) <= 1, runtimes
    native.library.cache_clear()
    monkeypatch.setattr(native, "VARIANTS", (("-fno-such-option",), ()))
    with caplog.at_level(logging.WARNING, logger="nerfpipe.nerf.native"):
        lib = native.library()
    assert lib is not None and lib.nerfpipe_openmp() == 0 and not caplog.records
    field = GridField((-1.0,) * 3, (1.0,) * 3, GridConfig(levels=2, min_resolution=4, max_resolution=8))
    features, inside = native.grid_gather(field.table.detach(), torch.zeros(3, 3), field.lo, field.hi,
                                          field.resolutions, field.offsets)
    torch.testing.assert_close(features, torch_features(field, torch.zeros(3, 3))[0].detach())
