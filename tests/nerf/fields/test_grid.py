"""The fast field: trilinear interpolation on stacked multiresolution grids, its hand-written backward
pass, and the field's contract (density 0 outside its box, the same density from both entry points)."""

from __future__ import annotations

import pytest
import torch

from nerfpipe.nerf.fields.configs import GridConfig, HashConfig, PlanesConfig
from nerfpipe.nerf.fields.grid import GridField, _Trilinear, trilinear_corners
from nerfpipe.nerf.registry import part_class


def test_trilinear_interpolation_reproduces_linear_functions_exactly() -> None:
    """Trilinear interpolation of vertex values of f(x) = a.x + b gives f itself, at every level."""
    resolutions, config = torch.tensor([2, 5]), GridConfig(levels=2, min_resolution=2, max_resolution=5, features=1)
    assert config.resolutions() == [2, 5]
    sizes = [(r + 1) ** 3 for r in (2, 5)]
    offsets = torch.tensor([0, sizes[0]])
    a, b = torch.tensor([0.3, -1.2, 2.0], dtype=torch.float64), 0.7
    table = []
    for r in (2, 5):
        i, j, k = torch.meshgrid(*(torch.arange(r + 1, dtype=torch.float64),) * 3, indexing="ij")
        vertices = torch.stack([i, j, k], dim=-1).reshape(-1, 3) / r
        table.append(vertices @ a + b)
    table = torch.cat(table).unsqueeze(-1)
    u = torch.rand(500, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    u[:3] = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 0.5]], dtype=torch.float64)  # faces and corners
    index, weights = trilinear_corners(u, resolutions, offsets)
    assert index.shape == (2, 8, 500) and torch.allclose(weights.sum(dim=1), torch.ones(2, 500, dtype=torch.float64))
    assert bool((weights >= 0).all()) and int(index.max()) < sum(sizes)
    out = _Trilinear.apply(table, index, weights)  # (M, L, 1)
    expected = (u @ a + b).unsqueeze(-1).expand(500, 2)
    torch.testing.assert_close(out.squeeze(-1), expected, rtol=0, atol=1e-12)


def test_the_scatter_backward_matches_numerical_gradients() -> None:
    table = torch.randn(3**3 + 5**3, 2, dtype=torch.float64, requires_grad=True)
    u = torch.rand(40, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    index, weights = trilinear_corners(u, torch.tensor([2, 4]), torch.tensor([0, 27]))
    assert torch.autograd.gradcheck(lambda t: _Trilinear.apply(t, index, weights), (table,))


def test_the_weights_backward_matches_numerical_gradients() -> None:
    """The points train too (camera refinement): d out / d w_c is the corner's row, for both inputs at once."""
    table = torch.randn(3**3 + 5**3, 3, dtype=torch.float64, requires_grad=True)
    u = torch.rand(30, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    index, weights = trilinear_corners(u, torch.tensor([2, 4]), torch.tensor([0, 27]))
    weights.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t, w: _Trilinear.apply(t, index, w), (table, weights))


def test_density_is_zero_outside_the_box_and_the_same_from_both_entry_points() -> None:
    torch.manual_seed(0)
    field = GridField((-1.0, -2.0, 0.0), (1.0, 2.0, 3.0), GridConfig(levels=2, min_resolution=4, max_resolution=8))
    x = torch.tensor([[0.0, 0.0, 1.5], [0.99, -1.99, 0.01], [1.01, 0.0, 1.0], [0.0, 0.0, -0.01], [0.0, 2.5, 1.0]])
    d = torch.nn.functional.normalize(torch.randn(5, 3), dim=-1)
    rgb, sigma = field(x, d)
    assert rgb.shape == (5, 3) and bool(((rgb > 0) & (rgb < 1)).all())
    assert bool((sigma[:2] > 0).all()) and sigma[2:].tolist() == [0.0, 0.0, 0.0]
    torch.testing.assert_close(field.query_density(x), sigma)
    # only the 8 vertices per level around each point get gradients (outside points clamp to the faces)
    (rgb.sum() + sigma.sum()).backward()
    touched = field.table.grad.abs().sum(-1) > 0
    assert 0 < int(touched.sum()) <= 5 * 2 * 8 < field.table.shape[0] // 2


def test_huge_raw_density_stays_finite() -> None:
    field = GridField((0.0,) * 3, (1.0,) * 3, GridConfig(levels=1, min_resolution=4, max_resolution=4))
    with torch.no_grad():
        field.density_net[-1].bias[0] = 1e4  # exp would overflow to inf
    sigma = field.query_density(torch.full((3, 3), 0.5))
    assert bool(torch.isfinite(sigma).all()) and float(sigma.detach().max()) == torch.exp(torch.tensor(15.0)).item()


def test_gradients_reach_the_points_and_match_finite_differences() -> None:
    """Camera refinement moves the points a grid field is queried at: d(rgb, sigma)/dx of the trilinear
    interpolation agrees with central differences wherever the field is smooth across the step (its one-sided
    differences agree: no cell face of the trilinear interpolation, no ReLU of the MLPs, in between)."""
    torch.manual_seed(0)
    field = GridField((-1.0,) * 3, (1.0,) * 3, GridConfig(levels=2, min_resolution=4, max_resolution=8))
    torch.nn.init.uniform_(field.table, -0.5, 0.5)
    x = (torch.rand(6, 3) * 1.6 - 0.8).requires_grad_()
    d = torch.nn.functional.normalize(torch.randn(6, 3), dim=-1)

    def f(p: torch.Tensor) -> torch.Tensor:
        rgb, sigma = field(p, d)
        return rgb.sum() + sigma.sum()

    f(x).backward()
    eps, ahead, behind = 1e-3, torch.zeros_like(x), torch.zeros_like(x)
    with torch.no_grad():
        at = f(x)
        for i in range(6):
            for j in range(3):
                step = torch.zeros_like(x)
                step[i, j] = eps
                ahead[i, j], behind[i, j] = (f(x + step) - at) / eps, (at - f(x - step)) / eps
    smooth = (ahead - behind).abs() < 2e-3
    assert int(smooth.sum()) >= 15  # a kink within 1e-3 of a few of the 18 coordinates at most
    torch.testing.assert_close(x.grad[smooth], ((ahead + behind) / 2)[smooth], atol=2e-3, rtol=2e-2)


@pytest.mark.parametrize("kind", ["grid", "hash", "planes"])
def test_the_gather_a_compiled_step_traces_is_the_eager_one_with_finite_gradients_at_extreme_inputs(kind) -> None:
    """Inside ``torch.compile`` the corners are gathered by plain indexing (``gather_corners``), which the compiler
    fuses; traced (``aot_eager``: the graph without code generation) it gives the eager field's colour, density
    and gradients, finite at the box's faces, far outside it and at infinity."""
    torch.manual_seed(0)
    config = {"grid": GridConfig(levels=3, max_resolution=32), "hash": HashConfig(levels=4, max_resolution=256, log2_table=10),
              "planes": PlanesConfig(levels=2, max_resolution=64)}[kind]
    field = part_class(config).from_config(config, ((-1.0,) * 3, (1.0,) * 3))
    edges = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [1.0 - 1e-7, 0.0, -1.0], [1e30, -1e30, 0.0],
                          [float("inf"), 0.0, 0.0]])
    x = torch.cat([edges, torch.rand(300, 3) * 2 - 1])
    d = torch.nn.functional.normalize(torch.randn(len(x), 3), dim=-1)

    def outputs(fn):
        field.zero_grad(set_to_none=True)
        rgb, sigma = fn(x, d)
        (rgb.sum() + sigma.sum()).backward()
        return rgb.detach(), sigma.detach(), [p.grad.clone() for p in field.parameters()]

    eager = outputs(lambda a, b: field(a, b))
    traced = outputs(torch.compile(lambda a, b: field(a, b), backend="aot_eager", dynamic=False, fullgraph=True))
    torch.testing.assert_close(traced[0], eager[0])
    torch.testing.assert_close(traced[1], eager[1])
    for g, h in zip(eager[2], traced[2]):
        assert bool(torch.isfinite(h).all())
        torch.testing.assert_close(h, g, atol=1e-6, rtol=1e-5)
