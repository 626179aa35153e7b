"""Carving the occupancy grid in front of the sparse points (``cells_in_front``, ``MarchingSampler.start``): which
cells a camera sees empty, by hand on a 4^3 grid, and that training, a reset and a saved model keep them empty."""

from __future__ import annotations

import torch

from nerfpipe.nerf.samplers.configs import MarchingConfig
from nerfpipe.nerf.samplers.marching import MarchingSampler, describe_carving
from nerfpipe.nerf.samplers.occupancy import OccupancyGrid, cells_in_front
from nerfpipe.nerf.spaces.ray_space import BoxSpace

BOX = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
# one camera 3 in front of the box's middle looking down +z (OpenCV), a 200 x 200 photo with a 90 degree field of view:
# every corner of the 4^3 grid over BOX (cells of 0.5) lies at depth 2 to 4, inside the view
C2W = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, -3.0], [0.0, 0.0, 0.0, 1.0]])[None]
K = torch.tensor([[100.0, 100.0, 100.0, 100.0]])


def carved(depth: torch.Tensor, c2w: torch.Tensor = C2W) -> torch.Tensor:
    """(4, 4, 4) over x, y, z: the cells of a 4^3 grid over BOX in front of ``depth`` (1, rows, columns)."""
    grid = OccupancyGrid(*BOX, 4)
    return cells_in_front(grid, lambda points: points, K, c2w, depth).reshape(4, 4, 4)


def test_a_cell_is_carved_when_all_of_it_lies_nearer_than_the_free_depth() -> None:
    # slab z in [-1, -0.5] lies at depth 2 to 2.5, slab [-0.5, 0] at 2.5 to 3
    assert torch.equal(carved(torch.full((1, 4, 4), 2.75)).sum(dim=(0, 1)), torch.tensor([16, 0, 0, 0]))
    assert torch.equal(carved(torch.full((1, 4, 4), 3.25)).sum(dim=(0, 1)), torch.tensor([16, 16, 0, 0]))
    assert not carved(torch.full((1, 4, 4), 2.5)).any()  # a cell's far face at the free depth is not in front of it
    assert not carved(torch.zeros((1, 4, 4))).any()
    backwards = C2W.clone()
    backwards[0, :3, :3] = torch.diag(torch.tensor([-1.0, 1.0, -1.0]))  # looking away from the box
    assert not carved(torch.full((1, 4, 4), 100.0), backwards).any()


def test_a_nearer_point_keeps_the_cells_in_front_of_it() -> None:
    depth = torch.full((1, 4, 4), 3.25)
    depth[0, 0, 0] = 0.1  # something near in the photo's top left corner (the cells of least x and y)
    dip = carved(depth)
    # cell (0, 0, 1) (x, y in [-1, -0.5], depth 2.5 to 3) projects to pixels 60-83, where the free depth now reads
    # 2.97 at its nearest corner: bilinear between the cells' centres at 25 and 75 px, 0.1 * 0.09 + 3.25 * 0.91;
    # cell (0, 0, 0) (depth 2 to 2.5) reads 2.46 at pixel (50, 50), between the four top left cells' centres
    kept = torch.zeros((4, 4, 4), dtype=torch.bool)
    kept[0, 0, 0] = kept[0, 0, 1] = True
    assert torch.equal(dip, carved(torch.full((1, 4, 4), 3.25)) & ~kept)
    assert int(dip.sum()) == 30


def test_a_cell_wider_than_two_cells_of_the_free_depth_is_not_carved() -> None:
    # the nearest slab's cells project 25 px wide; cells of 10 px (20 a side) could hide a nearer point between corners
    assert not carved(torch.full((1, 20, 20), 2.75)).any()


def test_the_sampler_keeps_carved_cells_empty_through_updates_and_resets() -> None:
    sampler = MarchingSampler(OccupancyGrid(*BOX, 4), MarchingConfig(occupancy_resolution=4, carve=0.5))
    least = torch.full((1, 4, 4), 5.5)  # points at depth 5.5: free to 2.75, the nearest slab
    least[0, 3, 3] = torch.inf  # no point near the bottom right: free to nowhere, and so is cell (3, 3, 0)
    sampler.start(BoxSpace(BOX), K, C2W, least)
    occupied = sampler.grid.occupied.reshape(4, 4, 4)
    assert occupied[3, 3, 0] and int(occupied[:, :, 0].sum()) == 1 and occupied[:, :, 1:].all()
    assert sampler.carved == 15 / 64 and "23%" in describe_carving(sampler)
    sampler.grid.update(lambda points: torch.full((len(points),), 100.0), step_size=0.1, threshold=0.01, all_cells=True)
    assert torch.equal(sampler.grid.occupied.reshape(4, 4, 4), occupied)
    sampler.reset()
    assert torch.equal(sampler.grid.occupied.reshape(4, 4, 4), occupied)
    off = MarchingSampler(OccupancyGrid(*BOX, 4), MarchingConfig(occupancy_resolution=4, carve=0.0))
    off.start(BoxSpace(BOX), K, C2W, least)
    assert off.grid.occupied.all() and off.carved == 0.0 and describe_carving(off) is None
    again = MarchingSampler(OccupancyGrid(*BOX, 4), MarchingConfig(occupancy_resolution=4))
    again.load_state_dict(sampler.state_dict())
    assert torch.equal(again.grid.occupied, sampler.grid.occupied)



def test_a_contracted_grid_carves_no_cell_reaching_infinity_nor_where_the_depth_is_not_finite() -> None:
    from nerfpipe.nerf.spaces.ray_space import ContractedSpace

    space = ContractedSpace(BOX)  # the field's [-2, 2]^3: the outermost corners lie at infinity in the world
    grid = OccupancyGrid((-2.0,) * 3, (2.0,) * 3, 8)
    free = cells_in_front(grid, space.from_field, K, C2W, torch.full((1, 4, 4), 1e30)).reshape(8, 8, 8)
    assert free.any() and not free[:, :, -1].any() and not free[:, :, 0].any()  # at infinity, or behind the camera
    sampler = MarchingSampler(OccupancyGrid((-2.0,) * 3, (2.0,) * 3, 8), MarchingConfig(occupancy_resolution=8))
    least = torch.full((1, 4, 4), torch.nan)
    least[0, :2] = torch.inf  # no point near: nothing to carve by
    sampler.start(space, K, C2W, least)
    assert sampler.carved == 0.0 and torch.isfinite(sampler.grid.density).all()
