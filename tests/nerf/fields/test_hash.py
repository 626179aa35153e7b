"""The hash-grid field: its hashed rows by hand, its dense levels as the grid field's, a spec round trip,
and finite gradients at the box's edges and beyond, in fp32 and bf16."""

from __future__ import annotations

import pytest
import torch

from nerfpipe.nerf.registry import FIELDS, config_class, part_class

from nerfpipe.nerf.fields.grid import trilinear_corners
from nerfpipe.nerf.fields.configs import HashConfig
from nerfpipe.nerf.fields.hash import HashGridField, hashed_corners


def test_a_hashed_level_puts_each_corner_where_instant_ngps_hash_says() -> None:
    # one level of 1000 cells (1001^3 vertices) into 2^10 rows: a point in cell (3, 7, 500) at its corner (0, 0, 0)
    resolutions, sizes, offsets = torch.tensor([1000]), torch.tensor([1024]), torch.tensor([0])
    u = torch.tensor([[3.25, 7.5, 500.75]]) / 1000
    index, weights = hashed_corners(u, resolutions, offsets, sizes)
    expected = [((3 + dx) ^ ((7 + dy) * 2654435761) ^ ((500 + dz) * 805459861)) % 1024
                for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)]
    assert index[0, :, 0].tolist() == expected
    # corner c = 4 dx + 2 dy + dz: weights (1 - fx or fx) (1 - fy or fy) (1 - fz or fz) with f = (.25, .5, .75)
    assert weights[0, :, 0].tolist() == pytest.approx([0.75 * 0.5 * 0.25, 0.75 * 0.5 * 0.75, 0.75 * 0.5 * 0.25, 0.75 * 0.5 * 0.75,
                                                        0.25 * 0.5 * 0.25, 0.25 * 0.5 * 0.75, 0.25 * 0.5 * 0.25, 0.25 * 0.5 * 0.75])


def test_dense_levels_index_as_the_grid_field_does_and_every_row_is_in_its_level() -> None:
    config = HashConfig(levels=6, min_resolution=4, max_resolution=200, features=2, log2_table=12)
    field = HashGridField((-1.0,) * 3, (1.0,) * 3, config)
    assert config.resolutions() == [4, 9, 19, 42, 91, 200]
    assert config.level_sizes() == [125, 1000, 4096, 4096, 4096, 4096]  # 5^3 and 10^3 vertices, then 2^12 rows
    assert field.table.shape == (sum(config.level_sizes()), 2)
    u = torch.rand(5000, 3, generator=torch.Generator().manual_seed(0))
    index, _ = field.corners(u)
    dense, _ = trilinear_corners(u, field.resolutions[:2], field.offsets[:2])
    assert torch.equal(index[:2], dense)
    for level in range(6):
        start, size = int(field.offsets[level]), int(field.sizes[level])
        assert bool(((index[level] >= start) & (index[level] < start + size)).all())


def test_the_registry_builds_it_and_its_spec_rebuilds_it() -> None:
    config = config_class(FIELDS, "hash")(**{k: v for k, v in vars(HashConfig(levels=4, min_resolution=16, max_resolution=512, log2_table=14)).items()})
    cls = part_class(config)
    field = cls.from_config(config, ((-1.0, -2.0, 0.0), (1.0, 2.0, 3.0)))
    again = cls.from_config(field.config, field.box())
    again.load_state_dict(field.state_dict())
    x, d = torch.rand(64, 3) * 2 - 0.5, torch.nn.functional.normalize(torch.randn(64, 3), dim=-1)
    for a, b in zip(field(x, d), again(x, d)):
        torch.testing.assert_close(a, b)
    assert "the finest 3 hashed into tables of 2^14 rows" in field.config.describe()  # of 16, 51, 161, 512


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
def test_gradients_are_finite_at_the_edges_of_the_box_and_far_beyond(dtype) -> None:
    torch.manual_seed(0)
    field = HashGridField((-1.0,) * 3, (1.0,) * 3, HashConfig(levels=8, max_resolution=2048, log2_table=15))
    torch.nn.init.uniform_(field.table, -0.5, 0.5)
    edges = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [1.0 - 1e-7, 0.0, -1.0], [1e30, -1e30, 0.0],
                          [float("inf"), 0.0, 0.0], [0.3, -0.2, 0.999999]])
    x = torch.cat([edges, torch.rand(256, 3) * 2 - 1]).requires_grad_(True)
    d = torch.nn.functional.normalize(torch.randn(len(x), 3), dim=-1)
    with torch.autocast("cpu", dtype=dtype, enabled=dtype != torch.float32):
        rgb, sigma = field(x, d)
    assert torch.isfinite(rgb).all() and torch.isfinite(sigma).all() and (sigma[3:5] == 0).all()  # outside: empty
    (rgb.float().sum() + sigma.float().sum()).backward()
    assert all(torch.isfinite(p.grad).all() for p in field.parameters() if p.grad is not None)
    assert torch.isfinite(x.grad[:3]).all() and torch.isfinite(x.grad[5:]).all()
    assert field.table.grad.abs().sum() > 0
