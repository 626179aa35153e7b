"""Ray spaces: world <-> field coordinates, the camera depth of a ray parameter, steps of a field length, and
model.json round trips, for each space through the one protocol."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nerfpipe.nerf.spaces.ray_space import BoxSpace, ContractedSpace, NdcSpace, space_from_json

from nerfpipe.nerf.spaces.rays import camera_rays, pixel_centers
from tests.helpers import look_at

BOX = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))


def ndc_space() -> NdcSpace:
    reference = look_at(np.array([0.0, -3.0, 0.2]), np.array([0.0, 0.0, 0.0]))
    return NdcSpace(tuple(map(tuple, reference.tolist())), 40.0, (64, 48), 1.2)


SPACES = [BoxSpace(), BoxSpace(BOX), ndc_space(), ContractedSpace(((-0.5, -1.0, -0.2), (0.5, 1.0, 0.6)))]


def test_ndc_field_coordinates_round_trip():
    space = ndc_space()
    points = torch.tensor([[0.1, 0.0, 0.0], [-0.5, 1.0, 0.3], [0.2, 7.0, -0.4]], dtype=torch.float64)
    field = space.to_field(points)
    assert torch.all(field[:, 2] > -1) and torch.all(field[:, 2] < 1)  # beyond the near plane, before infinity
    assert torch.allclose(space.from_field(field), points, atol=1e-10)
    # the reference camera's centre line maps to x' = y' = 0; depth 2 near lies at z' = 0
    reference = np.array(space.c2w)
    on_axis = torch.tensor(reference[:3, 3] + 2.4 * reference[:3, 2])[None]
    assert torch.allclose(space.to_field(on_axis), torch.zeros(1, 3, dtype=torch.float64), atol=1e-9)
    world = BoxSpace(BOX)
    assert torch.equal(world.to_field(points), points) and torch.equal(world.from_field(points), points)


@pytest.mark.parametrize("space", SPACES, ids=lambda s: f"{s.kind}")
def test_every_space_maps_its_rays_points_to_the_field_as_it_maps_world_points(space):
    """The points of a pixel's ray, taken to the field through ``field_points``, are the world points on that
    pixel's camera ray taken there through ``to_field``; and ``from_field`` brings them back."""
    c2w = torch.tensor(look_at(np.array([0.4, -2.8, 0.0]), np.array([0.1, 0.0, 0.1])), dtype=torch.float64)
    uv = pixel_centers(4, 3).double()
    k = torch.tensor([10.0, 10.0, 2.0, 1.5], dtype=torch.float64).expand(len(uv), 4)
    n = len(uv)
    near, far = torch.full((n,), 1.5, dtype=torch.float64), torch.full((n,), 4.0, dtype=torch.float64)
    rays = space.rays(uv, k, c2w, near, far)
    t = rays.near + 0.37 * (rays.far - rays.near)
    on_ray = space.field_points(rays.origins + t[:, None] * rays.directions)
    origins, directions = camera_rays(uv, k, c2w)
    depth = space.camera_depth(uv, k, c2w, t)
    world = origins + depth[:, None] * directions
    assert torch.allclose(space.to_field(world), on_ray, atol=1e-6)
    assert torch.allclose(space.from_field(on_ray), world, atol=1e-6)
    assert torch.allclose(rays.viewdirs, torch.nn.functional.normalize(directions, dim=-1))


def test_camera_depth_inverts_the_ndc_ray_parameter():
    """A world point at camera depth s lies on the pixel's NDC ray at some t'; camera_depth(t') gives s back,
    for a camera other than the reference."""
    space = ndc_space()
    c2w = torch.tensor(look_at(np.array([0.4, -2.8, 0.0]), np.array([0.1, 0.0, 0.1])), dtype=torch.float32)
    uv = pixel_centers(8, 6)
    k = torch.tensor([10.0, 10.0, 4.0, 3.0]).expand(len(uv), 4)
    origins, directions = camera_rays(uv, k, c2w)
    n = len(uv)
    rays = space.rays(uv, k, c2w, torch.zeros(n), torch.ones(n))
    s = torch.linspace(1.5, 6.0, n)
    field_points = space.to_field(origins + s[:, None] * directions)
    t = (field_points - rays.origins)[:, 2] / rays.directions[:, 2]
    assert torch.all((t > 0) & (t < 1))
    # the point is on the NDC ray, not only at its z'
    assert torch.allclose(rays.origins + t[:, None] * rays.directions, field_points, atol=1e-4)
    assert torch.allclose(space.camera_depth(uv, k, c2w, t), s, rtol=1e-4)
    assert torch.equal(BoxSpace().camera_depth(uv, k, c2w, s), s)


def test_field_box_ends_at_the_far_depth():
    space = ndc_space()
    lo, hi = space.field_box(far=12.0)
    assert lo == (-1.0, -1.0, -1.0) and hi[:2] == (1.0, 1.0)
    assert np.isclose(hi[2], 1 - 2 * 1.2 / 12.0)
    assert BoxSpace().field_box() is None and BoxSpace(BOX).field_box() == BOX
    assert ContractedSpace(BOX).field_box() == ((-2.0,) * 3, (2.0,) * 3)


def test_mesh_boxes_and_world_voxels():
    scene = ((0.0, 0.0, 0.0), (4.0, 2.0, 2.0))
    assert BoxSpace().mesh_box(9.0, scene, "box") == scene and BoxSpace(BOX).mesh_box(9.0, scene, "all") == BOX
    assert ContractedSpace(BOX).mesh_box(9.0, scene, "box") == ((-1.0,) * 3, (1.0,) * 3)
    assert ContractedSpace(BOX).mesh_box(9.0, scene, "all") == ((-1.99,) * 3, (1.99,) * 3)
    assert ndc_space().mesh_box(12.0, scene, "box") == ndc_space().field_box(12.0)
    # a world box keeps its voxels; warped spaces take the scene box's share: 4 / 100
    assert BoxSpace(BOX).world_voxel(0.3, 100, scene) == 0.3
    assert ndc_space().world_voxel(0.3, 100, scene) == ContractedSpace(BOX).world_voxel(0.3, 100, scene) == 0.04


@pytest.mark.parametrize("space", SPACES, ids=lambda s: f"{s.kind}")
def test_steps_tile_each_ray_and_are_of_the_field_length_asked(space):
    c2w = torch.tensor(look_at(np.array([0.0, -3.0, 0.3]), np.zeros(3)), dtype=torch.float64)
    uv = pixel_centers(5, 4).double()
    k = torch.tensor([5.0, 5.0, 2.5, 2.0], dtype=torch.float64).expand(len(uv), 4)
    n = len(uv)
    rays = space.rays(uv, k, c2w, torch.full((n,), 1.0, dtype=torch.float64), torch.full((n,), 6.0, dtype=torch.float64))
    starts, ends = space.steps(rays.origins, rays.directions, rays.near, rays.far, 0.05, 4000)
    assert torch.allclose(starts[:, 0], rays.near) and torch.allclose(ends.amax(dim=-1), rays.far)
    assert torch.all(ends >= starts) and torch.allclose(starts[:, 1:], ends[:, :-1], atol=1e-12)  # contiguous
    a = space.field_points(rays.origins[:, None] + starts[..., None] * rays.directions[:, None])
    b = space.field_points(rays.origins[:, None] + ends[..., None] * rays.directions[:, None])
    length = torch.linalg.vector_norm(b - a, dim=-1)
    whole = ends < rays.far[:, None]  # steps not cut at far
    if isinstance(space, ContractedSpace):
        # a contracted step's length is set at its start, from how far out it is: a ray heading inwards (these
        # cameras are outside the box) takes steps up to a few times too long, and none shorter than asked
        assert float(length[whole].min()) > 0.045 and float(length[whole].max()) < 4 * 0.05
    else:
        assert torch.allclose(length[whole], torch.full_like(length[whole], 0.05))


@pytest.mark.parametrize("space", SPACES, ids=lambda s: f"{s.kind}")
def test_a_space_survives_json_and_an_unknown_one_is_named(space):
    import json

    assert space_from_json(json.loads(json.dumps(space.to_json()))) == space
    with pytest.raises(ValueError, match="unknown ray space 'sphere'; known: box, ndc, contracted"):
        space_from_json({"kind": "sphere"})
    with pytest.raises(ValueError, match="unknown ray space None"):  # the flag form of models before the classes
        space_from_json({"ndc": False, "box": None, "contraction": None})


def test_segment_rays_run_between_their_ends_in_every_space():
    start = torch.tensor([[0.1, 0.2, 0.3], [0.5, -0.2, 0.0]], dtype=torch.float64)
    end = torch.tensor([[0.2, 0.2, 0.1], [0.4, -0.1, 0.2]], dtype=torch.float64)
    view = torch.nn.functional.normalize(end - start, dim=-1)
    for space in SPACES:
        rays = space.segment_rays(start, end, view)
        at = lambda t: space.field_points(rays.origins + t * rays.directions)  # noqa: E731
        assert torch.allclose(at(0.0), space.to_field(start), atol=1e-9)
        assert torch.allclose(at(1.0), space.to_field(end), atol=1e-9)
        assert torch.equal(rays.near, torch.zeros(2, dtype=torch.float64)) and torch.equal(rays.far, torch.ones(2, dtype=torch.float64))
