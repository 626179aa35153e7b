"""Rendering a field with a known answer: the expected depth of a solid sphere is its ray intersection."""

from __future__ import annotations

import numpy as np
import torch

from nerfpipe.nerf.fields.analytic import SphereField

from nerfpipe.nerf.spaces.rays import camera_rays, pixel_centers
from nerfpipe.nerf.spaces.rays import RayBatch
from nerfpipe.nerf.samplers.configs import HierarchicalConfig
from nerfpipe.nerf.samplers.hierarchical import HierarchicalSampler
from tests.nerf.fieldfns import model_of
from tests.helpers import look_at


def test_intersect_by_hand() -> None:
    sphere = SphereField(radius=0.5)
    origins = torch.tensor([[0.0, 0.0, -2.0], [0.0, 0.3, -2.0], [0.0, 0.6, -2.0], [0.0, 0.0, 0.0]])
    directions = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    t = sphere.intersect(origins, directions)
    # centre ray enters at z = -0.5: t = 1.5; y = 0.3 enters at z = -0.4 with |d| = 2: t = 1.6 / 2 = 0.8;
    # y = 0.6 misses; a ray starting inside leaves at t = 0.5
    assert torch.allclose(t[:2], torch.tensor([1.5, 0.8])) and torch.isinf(t[2]) and torch.isclose(t[3], torch.tensor(0.5))


def test_rendered_depth_is_the_sphere_surface_within_half_a_sample_spacing() -> None:
    """With a near-opaque sphere all weight falls on the first sample inside it; its stretch of ray starts
    halfway from the sample before, so within half a spacing of the entry point, and a ray stops 1 / sigma
    into a medium of density sigma. Rendered as a trained model renders (``RadianceModel.render_rays``)."""
    sphere = SphereField(center=(0.1, -0.05, 0.0), radius=0.4, density=1e4)
    width = height = 48
    c2w = torch.tensor(look_at(np.array([1.6, 0.9, 0.5]), np.zeros(3)), dtype=torch.float32)
    uv = pixel_centers(width, height)
    intrinsics = torch.tensor([60.0, 60.0, 24.0, 24.0]).expand(len(uv), 4)
    origins, directions = camera_rays(uv, intrinsics, c2w)
    near, far = 0.8, 3.2
    n = len(uv)
    rays = RayBatch(origins, directions, torch.nn.functional.normalize(directions, dim=-1),
                    torch.full((n,), near), torch.full((n,), far))
    sampling = HierarchicalConfig(n_coarse=128, n_fine=0)
    out = model_of(sphere, None, HierarchicalSampler(sampling)).render_rays(rays, background=torch.ones(3))
    spacing = (far - near) / sampling.n_coarse
    t_entry = sphere.intersect(origins, directions)
    t_exit = sphere.intersect(origins + (t_entry.clamp(max=10.0) + 1e-4).unsqueeze(-1) * directions, directions)
    # rays whose chord through the sphere spans two spacings surely have a sample inside
    solid = torch.isfinite(t_entry) & (t_exit + 1e-4 >= 2 * spacing)
    missed = ~torch.isfinite(t_entry)
    assert solid.float().mean() > 0.2 and missed.float().mean() > 0.1  # the view holds both
    expected = t_entry[solid] + 1.0 / sphere.density  # depth is along the optical axis, as t is
    error = out["depth"][solid] - expected
    assert error.abs().max() <= spacing / 2 + 1e-5, (float(error.min()), float(error.max()))
    assert abs(float(error.mean())) < spacing / 8  # entry points fall evenly within a bin: no bias
    assert error.abs().max() > spacing / 4  # the bound is tight: coarse samples cannot do better
    assert torch.all(out["acc"][solid] > 0.99) and torch.all(out["acc"][missed] < 1e-6)
    assert torch.allclose(out["rgb"][missed], torch.ones(3))  # the background shows where the sphere is not
    assert torch.all(out["depth"][missed] == far)  # no hit: depth is the far bound, disparity 1 / far
    assert torch.allclose(out["disparity"][missed], torch.tensor(1 / far))

    # hierarchical sampling packs samples near the surface, and the depth follows them
    fine = model_of(sphere, None, HierarchicalSampler(HierarchicalConfig(n_coarse=128, n_fine=64))).render_rays(
        rays, background=torch.ones(3))
    fine_error = (fine["depth"][solid] - expected).abs()
    assert fine_error.max() <= spacing / 2 + 1e-5 and fine_error.mean() < error.abs().mean() / 4
