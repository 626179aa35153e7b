"""HierarchicalSampler: coarse + fine rendering of ray batches (Section 5.2) with small analytic fields,
through ``RadianceModel.render``."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from nerfpipe.nerf.spaces.rays import RayBatch

from nerfpipe.nerf.samplers.configs import HierarchicalConfig
from nerfpipe.nerf.samplers.hierarchical import HierarchicalSampler
from nerfpipe.nerf.samplers.sampling import stratified_samples
from tests.nerf.fieldfns import model_of, render_fields

LN2 = math.log(2.0)


def blob_field(points: torch.Tensor, viewdirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """A Gaussian blob of density around (0.2, -0.1, 1.5) with a colour that varies with x and d."""
    centre = torch.tensor([0.2, -0.1, 1.5], dtype=points.dtype)
    sigma = 8.0 * torch.exp(-((points - centre) ** 2).sum(-1) / 0.3)
    rgb = torch.sigmoid(2.0 * points + 0.5 * viewdirs)
    return rgb, sigma


def random_rays(n: int, seed: int = 0, dtype=torch.float32) -> RayBatch:
    g = torch.Generator().manual_seed(seed)
    origins = torch.cat([torch.rand(n, 2, generator=g, dtype=dtype) - 0.5, torch.full((n, 1), -0.5, dtype=dtype)], -1)
    tilt = 0.2 * (torch.rand(n, 2, generator=g, dtype=dtype) - 0.5)
    directions = torch.cat([tilt, torch.ones(n, 1, dtype=dtype)], -1)
    near = 0.5 + 0.1 * torch.rand(n, generator=g, dtype=dtype)
    far = 3.5 + 0.5 * torch.rand(n, generator=g, dtype=dtype)
    return RayBatch(origins, directions, nn.functional.normalize(directions, dim=-1), near, far)


def axis_rays(n: int, near: float = 0.0, far: float = 4.0) -> RayBatch:
    """n copies of the ray from the origin along +z: the sample at t is the point (0, 0, t)."""
    zeros, z = torch.zeros(n, 3), torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3)
    return RayBatch(zeros, z.clone(), z.clone(), torch.full((n,), near), torch.full((n,), far))


class Recorder:
    """A constant field (density ln 2, colour (0.2, 0.4, 0.6)) that keeps the points it was asked about."""

    def __init__(self) -> None:
        self.calls: list[torch.Tensor] = []

    def __call__(self, points, viewdirs):
        self.calls.append(points.detach().clone())
        m = points.shape[0]
        return torch.tensor([0.2, 0.4, 0.6]).expand(m, 3), torch.full((m,), LN2)


def render_rays(coarse, fine, rays, sampling, background=None, randomized=True, generator=None):
    return render_fields(coarse, fine, rays, HierarchicalSampler(sampling), background, randomized, generator)


def test_points_are_o_plus_t_d():
    # o = (1, 2, 3), d = (0, 0, 2), t = 0.5, 1 -> (1, 2, 4), (1, 2, 5).
    rays = RayBatch(torch.tensor([[1.0, 2.0, 3.0]]), torch.tensor([[0.0, 0.0, 2.0]]), torch.tensor([[0.0, 0.0, 1.0]]),
                    torch.tensor([0.0]), torch.tensor([1.0]))
    points = rays.points(torch.tensor([0, 0]), torch.tensor([0.5, 1.0]))
    assert torch.equal(points, torch.tensor([[1.0, 2.0, 4.0], [1.0, 2.0, 5.0]]))


def test_constant_density_coarse_by_hand():
    # near 0, far 4, N_c 4: t = 0.5, 1.5, 2.5, 3.5, each standing for the stretch nearest it: [0, 1], [1, 2],
    # [2, 3], [3, 4]; sigma ln 2: alpha = 1/2 each, w = 1/2, 1/4, 1/8, 1/16, acc = 1 - 2^-4.
    # rgb over a white background = acc (0.2, 0.4, 0.6) + (1 - acc).
    field = Recorder()
    out = render_rays(field, None, axis_rays(2), HierarchicalConfig(n_coarse=4, n_fine=0),
                      background=torch.ones(3), randomized=False)
    assert out.earlier == () and out.evaluated == 8
    expected_w = torch.tensor([[0.5, 0.25, 0.125, 0.0625]] * 2)
    acc = 1 - 2**-4
    assert torch.allclose(out.weights.reshape(2, 4), expected_w, rtol=0, atol=1e-6)
    assert torch.allclose(out.acc, torch.full((2,), acc), rtol=0, atol=1e-6)
    colour = torch.tensor([0.2, 0.4, 0.6])
    assert torch.allclose(out.rgb, (acc * colour + (1 - acc)).expand(2, 3), rtol=0, atol=1e-6)
    # mean stopping depths (rendering.interval_stop_depths): in a stretch [s, s + 1] of tau = ln 2 a ray stops
    # g = 1/tau - 1/(e^tau - 1) = 1/ln2 - 1 past s
    g = 1 / math.log(2) - 1
    depth = sum(w * (s + g) for s, w in enumerate((0.5, 0.25, 0.125, 0.0625))) / acc
    assert torch.allclose(out.depth, torch.full((2,), depth), rtol=0, atol=1e-5)
    # the field saw z = 0.5, 1.5, 2.5, 3.5 on each ray
    assert torch.equal(field.calls[0][:, 2], torch.tensor([0.5, 1.5, 2.5, 3.5] * 2))


def test_fine_pass_uses_the_union_of_samples():
    field = Recorder()
    out = render_rays(field, None, axis_rays(3), HierarchicalConfig(n_coarse=8, n_fine=16), randomized=False)
    assert len(field.calls) == 2  # coarse, then the coarse field again for the fine pass
    assert field.calls[0].shape == (3 * 8, 3) and field.calls[1].shape == (3 * 24, 3)
    z = field.calls[1][:, 2].reshape(3, 24)
    assert (z[:, 1:] >= z[:, :-1]).all() and (z >= 0).all() and (z <= 4).all()
    # the 8 coarse samples are among the 24
    coarse = stratified_samples(torch.zeros(3), torch.full((3,), 4.0), 8, perturb=False)
    assert all(torch.isin(coarse[i], z[i]).all() for i in range(3))
    assert out.weights.shape == (3 * 24,) and len(out.earlier) == 1 and out.earlier[0].weights.shape == (3 * 8,)
    assert out.evaluated == 3 * (8 + 24)


def test_fine_samples_concentrate_where_the_coarse_weights_are():
    # a thin slab of density around z = 3: most of the 64 fine samples fall within [2.5, 3.5].
    def slab(points, viewdirs):
        sigma = torch.where((points[:, 2] - 3.0).abs() < 0.25, 20.0, 0.0)
        return torch.full_like(points, 0.5), sigma

    seen = []

    def recording_slab(points, viewdirs):
        seen.append(points[:, 2].clone())
        return slab(points, viewdirs)

    render_rays(slab, recording_slab, axis_rays(1), HierarchicalConfig(n_coarse=16, n_fine=64), randomized=False)
    z = seen[0]
    assert ((z > 2.5) & (z < 3.5)).sum().item() >= 64


def test_lindisp_sampling_reaches_the_field():
    field = Recorder()
    render_rays(field, None, axis_rays(1, near=1.0, far=4.0), HierarchicalConfig(n_coarse=2, n_fine=0, lindisp="on"),
                randomized=False)
    # bin centres in disparity between 1 and 1/4: 16/13, 16/7
    assert torch.allclose(field.calls[0][:, 2], torch.tensor([16 / 13, 16 / 7]), rtol=0, atol=1e-6)


@pytest.mark.parametrize("sampling", [HierarchicalConfig(n_coarse=16, n_fine=0), HierarchicalConfig(n_coarse=16, n_fine=32)])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_batched_equals_per_ray(sampling, dtype):
    rays = random_rays(6, dtype=dtype)
    background = torch.tensor([0.1, 0.9, 0.5], dtype=dtype)
    together = render_rays(blob_field, None, rays, sampling, background, randomized=False)
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    assert together.acc.max() > 0.1  # the blob is actually hit
    per_ray = sampling.n_coarse + sampling.n_fine
    for i in range(len(rays)):
        alone = render_rays(blob_field, None, rays.slice(i, i + 1), sampling, background, randomized=False)
        for level, (a_out, b_out) in enumerate(zip(together.passes(), alone.passes())):
            for key in ("rgb", "depth", "disparity", "acc"):
                a, b = getattr(a_out, key)[i], getattr(b_out, key)[0]
                assert torch.allclose(a, b, rtol=tol, atol=tol), (level, key, i)
        assert torch.allclose(together.weights.reshape(6, per_ray)[i], alone.weights, rtol=tol, atol=tol)


def test_render_rays_in_chunks_equals_one_render():
    rays = random_rays(7, seed=3)
    model = model_of(blob_field, blob_field, HierarchicalSampler(HierarchicalConfig(n_coarse=8, n_fine=8)))
    whole = model.render(rays)
    chunked = model.render_rays(rays, chunk=3)
    for key in ("rgb", "depth", "disparity", "acc"):
        assert torch.allclose(chunked[key], getattr(whole, key), rtol=1e-6, atol=1e-6), key
    assert chunked["rgb"].shape == (7, 3) and float(chunked["samples"]) == 8 + 16


def test_render_rays_of_no_rays():
    out = model_of(blob_field, None, HierarchicalSampler(HierarchicalConfig(n_coarse=4, n_fine=0))).render_rays(random_rays(0))
    assert all(v.numel() == 0 for k, v in out.items() if k != "samples")


def test_randomized_rendering_is_seeded():
    rays = random_rays(4, seed=1)
    sampling = HierarchicalConfig(n_coarse=8, n_fine=8)

    def run(seed):
        return render_rays(blob_field, None, rays, sampling, randomized=True,
                           generator=torch.Generator().manual_seed(seed)).rgb

    assert torch.equal(run(5), run(5))
    assert not torch.equal(run(5), run(6))
    deterministic = render_rays(blob_field, None, rays, sampling, randomized=False).rgb
    assert not torch.equal(run(5), deterministic)
    assert torch.isfinite(run(5)).all()


def test_fine_pass_sends_no_gradient_to_the_coarse_field():
    # The fine samples are detached (Section 5.2): the fine colour depends on the coarse field only through
    # where it samples, which carries no gradient.
    a = torch.tensor(2.0, requires_grad=True)
    b = torch.tensor(3.0, requires_grad=True)

    def coarse(points, viewdirs):
        rgb, sigma = blob_field(points, viewdirs)
        return rgb, a * sigma

    def fine(points, viewdirs):
        rgb, sigma = blob_field(points, viewdirs)
        return rgb * b / 3.0, b * sigma

    out = render_rays(coarse, fine, random_rays(4), HierarchicalConfig(n_coarse=8, n_fine=8), randomized=False)
    out.rgb.sum().backward()
    assert a.grad is None
    assert b.grad is not None and b.grad.abs() > 0
    out.earlier[0].rgb.sum().backward()
    assert a.grad is not None and a.grad.abs() > 0
