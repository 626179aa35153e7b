"""Training's march in one native loop a ray (nerfpipe.nerf.samplers.march.march with a budget,
nerfpipe.nerf.native.march_marched): torch's samples -- rays, t, stretches and spans -- in contracted and box spaces,
jittered or not; the budget's leading rays as within_budget keeps them; one ray over the budget kept whole; the same
bits on one thread as on two; rays it cannot take left to torch."""

from __future__ import annotations

import pytest
import torch

from nerfpipe.nerf import native
from nerfpipe.nerf.samplers.march import march, within_budget
from nerfpipe.nerf.spaces.rays import RayBatch
from tests.nerf.test_fused import build, rays

pytestmark = pytest.mark.skipif(native.library() is None, reason="no native kernels on this machine")

EVERYTHING = 10**9  # a budget every ray fits


def torch_march(batch: RayBatch, model, randomized: bool, seed: int):
    """The march torch's operators lay out (no budget: the native loop does not run)."""
    return march(batch, model.ray_space, model.sampler.grid, 64, randomized, torch.Generator().manual_seed(seed))


def native_march(batch: RayBatch, model, randomized: bool, seed: int, budget: int = EVERYTHING):
    return march(batch, model.ray_space, model.sampler.grid, 64, randomized, torch.Generator().manual_seed(seed),
                 budget)


@pytest.mark.parametrize("contracted", [True, False])
@pytest.mark.parametrize("randomized", [True, False])
def test_the_native_march_lays_out_torch_s_samples(contracted, randomized, monkeypatch) -> None:
    """The same samples of the same rays, their t and stretches to float rounding (in contracted space a step's
    length comes from the norm of the ray's direction, which torch and C round differently: along a ray to 100
    units that grows to a few parts in a million), the spans exactly; and the native loop did run."""
    model, batch = build(contracted), rays(contracted, n=1000)
    called = []
    kernel = native.march_marched
    monkeypatch.setattr(native, "march_marched", lambda *a: called.append(1) or kernel(*a))
    ours, reference = native_march(batch, model, randomized, 5), torch_march(batch, model, randomized, 5)
    assert called and ours.n_rays == reference.n_rays == len(batch)
    assert torch.equal(ours.ray, reference.ray) and len(ours) > 5 * len(batch)
    for a, b in ((ours.t, reference.t), (ours.starts, reference.starts), (ours.ends, reference.ends)):
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-6)
    assert torch.equal(ours.spans[0], reference.spans[0]) and torch.equal(ours.spans[1], reference.spans[1])
    # the sample lies its ray's fraction u into its stretch, the same u along a ray (0.5 unless jittered)
    length = ours.ends - ours.starts
    long = length > 1e-3
    u, ray = ((ours.t - ours.starts) / length.clamp_min(1e-12))[long], ours.ray[long]
    first = u[ray == ray[0]]
    assert len(first) > 1 and torch.allclose(first, first[:1].expand_as(first), atol=1e-3)
    if not randomized:
        assert torch.allclose(u, torch.full_like(u, 0.5), atol=1e-3)


@pytest.mark.parametrize("contracted", [True, False])
def test_a_budget_keeps_the_leading_rays_within_budget_keeps(contracted) -> None:
    model, batch = build(contracted), rays(contracted, n=400)
    reference = torch_march(batch, model, True, 3)
    for budget in (len(reference) // 3, len(reference) - 1, len(reference)):
        ours = native_march(batch, model, True, 3, budget)
        kept = within_budget(reference, budget)
        expected = reference.leading(kept)
        assert ours.n_rays == kept and len(ours) == len(expected) <= budget
        assert torch.equal(ours.ray, expected.ray)


def test_a_first_ray_longer_than_the_budget_is_kept_whole() -> None:
    model, batch = build(True), rays(True, n=50)
    reference = torch_march(batch, model, False, 0)
    first = int((reference.ray == 0).sum())
    assert first > 1
    ours = native_march(batch, model, False, 0, budget=1)
    assert ours.n_rays == 1 and len(ours) == first and bool((ours.ray == 0).all())


def test_two_threads_give_one_thread_s_bits() -> None:
    model, batch = build(True), rays(True, n=2000)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = native_march(batch, model, True, 7)
        torch.set_num_threads(2)
        two = native_march(batch, model, True, 7)
    finally:
        torch.set_num_threads(before)
    assert all(torch.equal(a, b) for a, b in ((one.ray, two.ray), (one.t, two.t), (one.ends, two.ends)))


def test_rays_the_kernel_refuses_march_through_torch(monkeypatch) -> None:
    """A ray that is not finite the kernel refuses (torch's operators then say what they say); without a budget,
    torch marches."""
    model, batch = build(True), rays(True, n=20)
    bad = RayBatch(batch.origins.clone(), batch.directions, batch.viewdirs, batch.near, batch.far)
    bad.origins[3, 0] = float("nan")
    assert native.march_marched(True, (0.0,) * 3, (1.0,) * 3, 0.1, 257, model.sampler.grid.occupied,
                                ((-2.0,) * 3, (2.0,) * 3), bad.origins, bad.directions, bad.near, bad.far,
                                torch.full((20,), 0.5), EVERYTHING) is None
    monkeypatch.setattr(native, "march_marched", lambda *a: pytest.fail("the native march ran"))
    march(batch, model.ray_space, model.sampler.grid, 64, False, budget=0)  # no budget: torch's


def test_no_rays_are_nothing_to_march() -> None:
    model, batch = build(False), rays(False, n=4)
    empty = RayBatch(*(x[:0] for x in (batch.origins, batch.directions, batch.viewdirs, batch.near, batch.far)))
    assert len(native_march(empty, model, True, 0)) == 0
