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
    changed = tmp_path / "scatter.c"
    changed.write_text(native.SOURCE.read_text() + "\n/* changed */\n")
    monkeypatch.setattr(native, "SOURCE", changed)
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
