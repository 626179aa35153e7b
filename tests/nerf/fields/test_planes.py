"""The tri-plane field: its plane rows and weights by hand, the product of the planes, a spec round trip, and
finite gradients at the box's edges and beyond, in fp32 and bf16."""

from __future__ import annotations

import pytest
import torch

from nerfpipe.nerf.registry import FIELDS, config_class, part_class

from nerfpipe.nerf.fields.configs import PlanesConfig
from nerfpipe.nerf.fields.planes import PlaneField, bilinear_corners


def test_each_plane_reads_the_four_vertices_around_the_points_projection() -> None:
    # one level of 4 cells (5 x 5 vertices a plane): u = (0.3, 0.55, 0.9) * 4 = (1.2, 2.2, 3.6)
    index, weights = bilinear_corners(torch.tensor([[0.3, 0.55, 0.9]]), torch.tensor([4]), torch.tensor([10]))
    assert index.shape == weights.shape == (3, 4, 1)
    xy, xz, yz = (index[p, :, 0].tolist() for p in range(3))
    assert xy == [10 + 1 * 5 + 2, 10 + 1 * 5 + 3, 10 + 2 * 5 + 2, 10 + 2 * 5 + 3]  # (i, j) = (1, 2) and neighbours
    assert xz == [10 + 25 + 1 * 5 + 3, 10 + 25 + 1 * 5 + 4, 10 + 25 + 2 * 5 + 3, 10 + 25 + 2 * 5 + 4]
    assert yz == [10 + 50 + 2 * 5 + 3, 10 + 50 + 2 * 5 + 4, 10 + 50 + 3 * 5 + 3, 10 + 50 + 3 * 5 + 4]
    fx, fy, fz = 0.2, 0.2, 0.6
    assert weights[0, :, 0].tolist() == pytest.approx([(1 - fx) * (1 - fy), (1 - fx) * fy, fx * (1 - fy), fx * fy])
    assert weights[2, :, 0].tolist() == pytest.approx([(1 - fy) * (1 - fz), (1 - fy) * fz, fy * (1 - fz), fy * fz])


def test_a_levels_feature_is_the_product_of_its_three_planes() -> None:
    config = PlanesConfig(levels=2, min_resolution=2, max_resolution=8, features=1)
    field = PlaneField((0.0,) * 3, (1.0,) * 3, config)
    assert field.table.shape == (3 * 3**2 + 3 * 9**2, 1) and float(field.table.detach().min()) >= 0.1
    with torch.no_grad():  # plane values that are functions of their vertex: xy -> 2, xz -> 3, yz -> i + 1
        field.table.fill_(1.0)
        offset, n = int(field.offsets[1]), 9
        field.table[offset:offset + n * n] = 2.0
        field.table[offset + n * n:offset + 2 * n * n] = 3.0
        field.table[offset + 2 * n * n:offset + 3 * n * n, 0] = torch.arange(n).repeat_interleave(n).float() + 1
    features, inside = field.encode(torch.tensor([[0.5, 0.25, 0.75]]))
    # level 0: 1 * 1 * 1; level 1: 2 * 3 * (y = 0.25 on 8 cells: vertex i = 2 exactly -> 3)
    assert features.tolist() == [pytest.approx([1.0, 18.0])] and inside.tolist() == [True]


def test_the_registry_builds_it_and_its_spec_rebuilds_it() -> None:
    config = config_class(FIELDS, "planes")(**{k: v for k, v in vars(PlanesConfig(levels=3, min_resolution=16, max_resolution=256)).items()})
    cls = part_class(config)
    field = cls.from_config(config, ((-1.0, -2.0, 0.0), (1.0, 2.0, 3.0)))
    again = cls.from_config(field.config, field.box())
    again.load_state_dict(field.state_dict())
    x, d = torch.rand(64, 3) * 2 - 0.5, torch.nn.functional.normalize(torch.randn(64, 3), dim=-1)
    for a, b in zip(field(x, d), again(x, d)):
        torch.testing.assert_close(a, b)
    assert "3 levels of three planes of 16 to 256 cells a side" in field.config.describe()


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
def test_gradients_are_finite_at_the_edges_of_the_box_and_far_beyond(dtype) -> None:
    torch.manual_seed(0)
    field = PlaneField((-1.0,) * 3, (1.0,) * 3, PlanesConfig(levels=3, min_resolution=64, max_resolution=1024))
    edges = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [1.0 - 1e-7, 0.0, -1.0], [1e30, -1e30, 0.0],
                          [float("inf"), 0.0, 0.0], [0.3, -0.2, 0.999999]])
    x = torch.cat([edges, torch.rand(5000, 3) * 2 - 1]).requires_grad_(True)
    d = torch.nn.functional.normalize(torch.randn(len(x), 3), dim=-1)
    with torch.autocast("cpu", dtype=dtype, enabled=dtype != torch.float32):
        rgb, sigma = field(x, d)
    assert torch.isfinite(rgb).all() and torch.isfinite(sigma).all() and (sigma[3:5] == 0).all()  # outside: empty
    (rgb.float().sum() + sigma.float().sum()).backward()
    assert all(torch.isfinite(p.grad).all() for p in field.parameters() if p.grad is not None)
    assert torch.isfinite(x.grad[:3]).all() and torch.isfinite(x.grad[5:]).all()
    assert field.table.grad.abs().sum() > 0
