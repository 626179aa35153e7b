"""Scene contraction (mip-NeRF 360 Eq. 10, L-infinity norm): values by hand, identity inside, continuity at
the box, bounded by 2, the inverse, and steps of even length in contracted space."""

from __future__ import annotations

import torch

from nerfpipe.nerf.spaces.contraction import Contraction, contract, uncontract

from nerfpipe.nerf.samplers.march import march
from nerfpipe.nerf.samplers.occupancy import OccupancyGrid
from nerfpipe.nerf.spaces.ray_space import ContractedSpace
from nerfpipe.nerf.spaces.rays import RayBatch


def test_values_by_hand():
    x = torch.tensor([[0.5, -0.25, 1.0], [2.0, 0.0, 0.0], [4.0, -2.0, 1.0], [-10.0, 0.0, 5.0]])
    # ||x||inf = 1 -> itself; 2 -> (2 - 1/2) x / 2 = 0.75 x; 4 -> 1.75 x / 4; 10 -> 1.9 x / 10
    expected = torch.tensor([[0.5, -0.25, 1.0], [1.5, 0.0, 0.0], [1.75, -0.875, 0.4375], [-1.9, 0.0, 0.95]])
    torch.testing.assert_close(contract(x), expected)


def test_identity_inside_continuous_at_the_surface_and_bounded_by_two():
    gen = torch.Generator().manual_seed(0)
    inside = torch.rand((1000, 3), generator=gen) * 2 - 1
    assert torch.equal(contract(inside), inside)
    direction = torch.nn.functional.normalize(torch.randn((100, 3), generator=gen), dim=-1)
    on_box = direction / direction.abs().amax(-1, keepdim=True)  # ||x||inf = 1
    for eps in (1e-3, 1e-6):
        torch.testing.assert_close(contract(on_box * (1 + eps)), on_box, atol=3 * eps, rtol=0)
    huge = direction * torch.logspace(0, 30, 100).unsqueeze(-1)
    out = contract(huge)
    assert bool(torch.isfinite(out).all()) and float(out.abs().max()) <= 2.0
    norms = out.abs().amax(-1)
    assert bool((norms[1:] >= norms[:-1] - 1e-6).all())  # farther stays farther


def test_uncontract_inverts_contract():
    gen = torch.Generator().manual_seed(1)
    x = torch.randn((500, 3), generator=gen, dtype=torch.float64) * 5
    torch.testing.assert_close(uncontract(contract(x)), x)


def test_gradients_are_finite_everywhere():
    x = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [3.0, 0.0, 0.0], [1e20, -1e20, 0.0]], requires_grad=True)
    contract(x).sum().backward()
    assert bool(torch.isfinite(x.grad).all())


def test_the_scene_box_maps_to_the_unit_cube():
    c = Contraction((0.0, -2.0, 1.0), (2.0, 2.0, 3.0))  # centre (1, 0, 2), half sizes (1, 2, 1)
    corners = torch.tensor([[0.0, -2.0, 1.0], [2.0, 2.0, 3.0], [1.0, 0.0, 2.0], [5.0, 0.0, 2.0]])
    torch.testing.assert_close(c.to_field(corners), torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0],
                                                                  [1.75, 0.0, 0.0]]))
    torch.testing.assert_close(c.from_field(c.to_field(corners)), corners)


def test_the_step_scale_from_the_uncontracted_norm_is_the_one_from_the_contracted_point():
    c = Contraction((-1.0, -0.5, -0.8), (1.0, 0.5, 0.8))
    world = torch.tensor([[0.2, 0.1, -0.3], [1.5, 0.0, 0.0], [-4.0, 1.0, 2.0], [0.0, 0.0, 3e4], [1e9, 0.0, 0.0]])
    x0, dx = c.box_rays(world, torch.zeros_like(world))
    assert torch.equal(dx, torch.zeros_like(world))
    # 1 inside, the squared L-infinity norm in the box's units beyond (1.5, 4 / 1, 3e4 / 0.8), capped at 1e12
    expected = torch.tensor([1.0, 2.25, 16.0, (3e4 / 0.8) ** 2, 1e12])
    torch.testing.assert_close(Contraction.step_scale_at(x0.abs().amax(dim=-1)), expected)
    # the round trip through the contracted point agrees near the box; far out (3e4) its 2 - 1 / n has lost digits
    torch.testing.assert_close(Contraction.step_scale(c.to_field(world))[:3], expected[:3], rtol=1e-5, atol=0)


def test_steps_are_even_in_contracted_space_and_grow_in_the_world():
    c = Contraction((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
    o = torch.zeros((1, 3))
    d = torch.tensor([[1.0, 0.0, 0.0]])
    step = 0.05
    space = ContractedSpace((c.lo, c.hi))
    starts, ends = space.steps(o, d, torch.zeros(1), torch.tensor([50.0]), step, 4000)
    assert float(ends[0, -1]) == 50.0 and torch.equal(starts[0, 1:], ends[0, :-1])  # they tile [near, far]
    lengths = ends[0] - starts[0]
    assert torch.allclose(lengths[:19], torch.full((19,), step))  # inside the box: the plain step
    field = c.to_field(torch.stack([starts[0], torch.zeros_like(starts[0]), torch.zeros_like(starts[0])], -1))
    moved = field[1:, 0] - field[:-1, 0]
    assert float(moved[:-1].max()) <= step + 1e-6 and float(moved[20:-1].min()) > 0.2 * step  # even in contracted space
    assert float(lengths[-2]) > 10 * step  # and long in the world, far out
    assert starts.shape[1] < 60  # 20 steps to the box, about 19 more to reach 1.98 of the 2


def test_march_in_contracted_space_keeps_only_occupied_cells():
    c = Contraction((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
    grid = OccupancyGrid((-2.0,) * 3, (2.0,) * 3, 8)
    grid.occupied.zero_()
    shell = grid.cell_index(torch.tensor([[1.75, 0.0, 0.0]]))[0]  # the cell that holds world x = 4
    grid.occupied[shell] = True
    o, d = torch.zeros((1, 3)), torch.tensor([[1.0, 0.0, 0.0]])
    samples = march(RayBatch(o, d, d, torch.zeros(1), torch.tensor([100.0])), ContractedSpace((c.lo, c.hi)), grid, 32,
                    False)
    kept = samples.t
    assert len(kept) > 0
    x = c.to_field(torch.stack([kept, torch.zeros_like(kept), torch.zeros_like(kept)], -1))[:, 0]
    assert bool(((x >= 1.5) & (x <= 2.0)).all())  # world 2 .. infinity: the cell [1.5, 2.0] of contracted x
    assert float(kept.min()) >= 2.0 - 1e-4 and float(kept.max()) <= 100.0
    # the half-unit cell takes a few steps of 6.93 / 32 = 0.22 contracted units, however far it reaches
    assert 2 <= len(kept) <= 8
