"""Alpha compositing (Eq. 3) and the weights of Eq. 5, checked on tiny hand-worked cases and by two routes."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import example, given, settings
from hypothesis import strategies as st

from nerfpipe.nerf.rendering import (
    MAX_OPTICAL_DEPTH,
    alphas_from_density,
    composite,
    compositing_weights,
    optical_depth,
    sample_deltas,
    termination_depths,
    transmittance,
    transmittance_from_alphas,
)

LN2 = math.log(2.0)


def t64(values) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float64)


def test_sample_deltas_spacing_then_far():
    # t = 1, 2, 4 and far = 5: spacings 1, 2, and the last interval 4 -> 5 is 1.
    deltas = sample_deltas(t64([[1.0, 2.0, 4.0]]), t64([5.0]))
    assert torch.equal(deltas, t64([[1.0, 2.0, 1.0]]))


def test_sample_deltas_clamps_far_before_last_sample():
    # far = 3.5 < t_N = 4: the last interval would be -0.5; it is 0.
    deltas = sample_deltas(t64([[1.0, 2.0, 4.0]]), t64([3.5]))
    assert torch.equal(deltas, t64([[1.0, 2.0, 0.0]]))


def test_sample_deltas_keeps_float64_and_upcasts_half():
    assert sample_deltas(t64([[0.0, 1.0]]), t64([2.0])).dtype == torch.float64
    half = sample_deltas(torch.tensor([[0.0, 1.0]], dtype=torch.bfloat16), torch.tensor([2.0], dtype=torch.bfloat16))
    assert half.dtype == torch.float32


def test_optical_depth_clamps_negative_density_and_caps():
    # sigma = -3 counts as 0; 2 * 0.5 = 1; 1e9 * 1 is capped.
    tau = optical_depth(t64([[-3.0, 2.0, 1e9]]), t64([[1.0, 0.5, 1.0]]))
    assert torch.equal(tau, t64([[0.0, 1.0, MAX_OPTICAL_DEPTH]]))


def test_alphas_hand_values():
    # alpha = 1 - exp(-sigma delta): ln2 -> 1/2, ln4 -> 3/4, 0 -> 0.
    alphas = alphas_from_density(t64([[LN2, 2 * LN2, 0.0]]), t64([[1.0, 1.0, 1.0]]))
    assert torch.allclose(alphas, t64([[0.5, 0.75, 0.0]]), rtol=0, atol=1e-15)


def test_compositing_weights_equal_transmittance_times_alpha_by_hand():
    # deltas 1, sigma = ln2, ln4, 0, ln2 -> alpha = 1/2, 3/4, 0, 1/2
    # T = 1, 1/2, 1/2 * 1/4 = 1/8, 1/8 (the empty sample lets everything through)
    # w = T alpha = 1/2, 3/8, 0, 1/16
    sigmas = t64([[LN2, 2 * LN2, 0.0, LN2]])
    deltas = torch.ones_like(sigmas)
    assert torch.allclose(transmittance(sigmas, deltas), t64([[1.0, 0.5, 0.125, 0.125]]), rtol=0, atol=1e-15)
    weights = compositing_weights(sigmas, deltas)
    assert torch.allclose(weights, t64([[0.5, 0.375, 0.0, 0.0625]]), rtol=0, atol=1e-15)


def test_composite_two_samples_by_hand():
    # t = 1, 2, far = 3 -> deltas 1, 1; sigma = ln 2 -> alpha = 1/2, 1/2.
    # weights: 1/2, (1 - 1/2) 1/2 = 1/4; acc = 3/4.
    # rgb = 1/2 red + 1/4 green + 1/4 blue background = (0.5, 0.25, 0.25)
    # stretches of ray: [1, 1.5] and [1.5, 3]; optical depths ln2 / 2 and 1.5 ln2; mean stopping depths
    # 1 + 0.5 g(ln2 / 2) and 1.5 + 1.5 g(1.5 ln2) with g(tau) = 1/tau - 1/(e^tau - 1) (see below);
    # depth = (1/2 z_0 + 1/4 z_1) / (3/4).
    sigmas = t64([[LN2, LN2]])
    colors = t64([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    result = composite(sigmas, colors, t64([[1.0, 2.0]]), t64([3.0]), background=t64([0.0, 0.0, 1.0]))
    assert torch.allclose(result.weights, t64([[0.5, 0.25]]), rtol=0, atol=1e-15)
    assert torch.allclose(result.acc, t64([0.75]), rtol=0, atol=1e-15)
    assert torch.allclose(result.rgb, t64([[0.5, 0.25, 0.25]]), rtol=0, atol=1e-15)
    z0 = 1 + 0.5 * (2 / LN2 - 1 / (2**0.5 - 1))
    z1 = 1.5 + 1.5 * (1 / (1.5 * LN2) - 1 / (2**1.5 - 1))
    depth = (0.5 * z0 + 0.25 * z1) / 0.75
    assert torch.allclose(result.depth, t64([depth]), rtol=0, atol=1e-14)
    assert torch.allclose(result.disparity, t64([1 / depth]), rtol=0, atol=1e-14)


def test_composite_explicit_deltas_and_black_background():
    # t = 2, 3 with deltas given as 0.5, 0.25 and sigma = 2 ln2, 4 ln2: sigma delta = ln2 again,
    # so weights 1/2, 1/4; background None is black. The stopping depths come from t and far, not the
    # deltas: [2, 2.5] with optical depth ln2: 2 + 0.5 (1/ln2 - 1); [2.5, 100] is opaque (tau = 270):
    # 2.5 + 1 / (4 ln2), the mean free path.
    result = composite(
        t64([[2 * LN2, 4 * LN2]]),
        t64([[[1.0, 1.0, 1.0], [1.0, 0.0, 0.0]]]),
        t64([[2.0, 3.0]]),
        t64([100.0]),  # ignored for the deltas, which are given
        deltas=t64([[0.5, 0.25]]),
    )
    assert torch.allclose(result.weights, t64([[0.5, 0.25]]), rtol=0, atol=1e-15)
    assert torch.allclose(result.rgb, t64([[0.75, 0.5, 0.5]]), rtol=0, atol=1e-15)
    depth = (0.5 * (2 + 0.5 * (1 / LN2 - 1)) + 0.25 * (2.5 + 1 / (4 * LN2))) / 0.75
    assert torch.allclose(result.depth, t64([depth]), rtol=0, atol=1e-14)
    assert torch.allclose(result.disparity, t64([1 / depth]), rtol=0, atol=1e-14)


def test_termination_depths_by_hand():
    # t = 1, 2, 4, far 6: stretches [1, 1.5], [1.5, 3], [3, 6].
    # sigma 0: a ray stops uniformly within the stretch: its middle, 1.25, 2.25, 4.5.
    # sigma 1e6 (opaque): at the stretch start plus the mean free path 1e-6.
    # sigma ln2 / 1.5 over [1.5, 3]: tau = ln2, g = 1/ln2 - 1/(2 - 1).
    t, far = t64([[1.0, 2.0, 4.0]]), t64([6.0])
    assert torch.allclose(termination_depths(t64([[0.0, 0.0, 0.0]]), t, far), t64([[1.25, 2.25, 4.5]]), rtol=0, atol=1e-15)
    opaque = termination_depths(t64([[1e6, 1e6, 1e6]]), t, far)
    assert torch.allclose(opaque, t64([[1.0, 1.5, 3.0]]) + 1e-6, rtol=0, atol=1e-12)
    middle = termination_depths(t64([[0.0, LN2 / 1.5, 0.0]]), t, far)
    assert torch.allclose(middle[0, 1], t64(1.5 + 1.5 * (1 / LN2 - 1)), rtol=0, atol=1e-14)


def test_termination_depths_small_optical_depth_is_smooth_float32():
    # the series branch (tau < 0.1) and the exact branch meet without a jump, and tiny densities do not
    # lose the result to cancellation: g(tau) -> 1/2 - tau/12
    t = torch.tensor([[0.0, 1.0]])
    far = torch.tensor([2.0])
    sigmas = torch.tensor([[1e-9, 0.0], [0.099 / 0.5, 0.0], [0.101 / 0.5, 0.0]])
    z = termination_depths(sigmas, t.expand(3, 2), far.expand(3))[:, 0]  # stretch [0, 0.5]
    tau = torch.tensor([1e-9 * 0.5, 0.099, 0.101])
    expected = 0.5 * (0.5 - tau / 12 + tau**3 / 720)
    assert torch.allclose(z, expected, rtol=0, atol=1e-6)


def test_composite_per_ray_background():
    # Ray 0 hits nothing (sigma 0): its own background (0.2, 0.4, 0.6); ray 1 is opaque-ish with
    # acc 3/4 of white over background (1, 0, 0): 0.75 + 0.25 * (1, 0, 0) = (1, 0.75, 0.75).
    sigmas = t64([[0.0, 0.0], [LN2, LN2]])
    colors = torch.ones(2, 2, 3, dtype=torch.float64)
    background = t64([[0.2, 0.4, 0.6], [1.0, 0.0, 0.0]])
    result = composite(sigmas, colors, t64([[1.0, 2.0], [1.0, 2.0]]), t64([3.0, 3.0]), background=background)
    assert torch.allclose(result.rgb, t64([[0.2, 0.4, 0.6], [1.0, 0.75, 0.75]]), rtol=0, atol=1e-15)


def test_composite_nothing_hit_depth_is_far():
    # acc = 0: depth is the far bound (4), disparity 1/4.
    result = composite(t64([[0.0, 0.0]]), torch.zeros(1, 2, 3, dtype=torch.float64), t64([[1.0, 2.0]]), t64([4.0]))
    assert result.acc.item() == 0.0
    assert result.depth.item() == 4.0
    assert result.disparity.item() == 0.25


def test_transmittance_before_an_opaque_sample_float32():
    # sigma delta = 0.3 then 1e6 * 0.01 = 1e4 (the cap): T_2 = exp(-0.3) exactly as for a thin second
    # sample, since T_2 only depends on what lies before it; w_1 + w_2 = 1 - T_3 = 1 (T_3 = exp(-1e4.3) = 0).
    sigmas = torch.tensor([[0.3, 1e6, 0.2]])
    deltas = torch.tensor([[1.0, 0.01, 1.0]])
    expected = torch.tensor([[1.0, math.exp(-0.3), 0.0]])
    assert torch.allclose(transmittance(sigmas, deltas), expected, rtol=1e-6, atol=0)
    weights = compositing_weights(sigmas, deltas)
    assert weights.sum().item() <= 1.0 + 1e-6
    assert torch.allclose(weights, torch.tensor([[1 - math.exp(-0.3), math.exp(-0.3), 0.0]]), rtol=1e-6, atol=0)


# Optical depths from empty space (0) through tiny (1e-8) to far beyond the cap.
densities = st.one_of(st.just(0.0), st.floats(-8.0, 7.0).map(lambda e: 10.0**e))
spacings = st.one_of(st.just(0.0), st.floats(-5.0, 0.0).map(lambda e: 10.0**e))


@st.composite
def density_rays(draw, max_samples: int = 12):
    n = draw(st.integers(1, max_samples))
    rows = draw(st.integers(1, 3))
    sig = [[draw(densities) for _ in range(n)] for _ in range(rows)]
    dts = [[draw(spacings) for _ in range(n)] for _ in range(rows)]
    return sig, dts


@settings(max_examples=60, deadline=None)
@given(density_rays())
@example(([[0.3, 1e6, 0.2]], [[1.0, 0.01, 1.0]]))  # a large tau after a small one: see the test above
def test_transmittance_routes_agree_float32(case):
    sigmas, deltas = (torch.tensor(v, dtype=torch.float32) for v in case)
    by_sum = transmittance(sigmas, deltas)
    by_product = transmittance_from_alphas(alphas_from_density(sigmas, deltas))
    assert torch.allclose(by_sum, by_product, rtol=1e-5, atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(density_rays())
def test_transmittance_routes_agree_float64(case):
    sigmas, deltas = (torch.tensor(v, dtype=torch.float64) for v in case)
    by_sum = transmittance(sigmas, deltas)
    by_product = transmittance_from_alphas(alphas_from_density(sigmas, deltas))
    assert by_sum.dtype == by_product.dtype == torch.float64
    assert torch.allclose(by_sum, by_product, rtol=1e-12, atol=1e-14)


@settings(max_examples=40, deadline=None)
@given(density_rays(), st.integers(0, 2**31 - 1))
def test_composite_equals_alpha_route(case, seed):
    # rgb by the cumulative-product route of the authors' code, plus (1 - acc) background.
    sigmas, deltas = (torch.tensor(v, dtype=torch.float64) for v in case)
    g = torch.Generator().manual_seed(seed)
    colors = torch.rand(*sigmas.shape, 3, generator=g, dtype=torch.float64)
    background = torch.rand(3, generator=g, dtype=torch.float64)
    t = torch.cumsum(deltas, dim=-1)
    result = composite(sigmas, colors, t, t[:, -1] + 1.0, background=background, deltas=deltas)
    alphas = alphas_from_density(sigmas, deltas)
    weights = transmittance_from_alphas(alphas) * alphas
    acc = weights.sum(-1)
    rgb = (weights.unsqueeze(-1) * colors).sum(-2) + (1 - acc).unsqueeze(-1) * background
    assert torch.allclose(result.weights, weights, rtol=1e-10, atol=1e-13)
    assert torch.allclose(result.acc, acc, rtol=1e-10, atol=1e-13)
    assert torch.allclose(result.rgb, rgb, rtol=1e-10, atol=1e-13)


def test_composite_gradcheck_float64():
    g = torch.Generator().manual_seed(0)
    sigmas = (0.2 + 1.5 * torch.rand(2, 5, generator=g, dtype=torch.float64)).requires_grad_()
    colors = torch.rand(2, 5, 3, generator=g, dtype=torch.float64).requires_grad_()
    background = torch.rand(3, generator=g, dtype=torch.float64).requires_grad_()
    t = torch.cumsum(0.1 + torch.rand(2, 5, generator=g, dtype=torch.float64), dim=-1)
    far = t[:, -1] + 0.5

    def fn(s, c, bg):
        r = composite(s, c, t, far, background=bg)
        return r.rgb, r.depth, r.disparity, r.acc, r.weights

    assert torch.autograd.gradcheck(fn, (sigmas, colors, background), eps=1e-6, atol=1e-8)


def test_composite_gradcheck_wrt_t_and_deltas_float64():
    g = torch.Generator().manual_seed(1)
    sigmas = 0.2 + torch.rand(1, 4, generator=g, dtype=torch.float64)
    colors = torch.rand(1, 4, 3, generator=g, dtype=torch.float64)
    t = torch.tensor([[1.0, 1.7, 2.1, 3.0]], dtype=torch.float64, requires_grad=True)
    deltas = torch.tensor([[0.7, 0.4, 0.9, 0.6]], dtype=torch.float64, requires_grad=True)

    def fn(t_, d_):
        r = composite(sigmas, colors, t_, torch.tensor([4.0], dtype=torch.float64), deltas=d_)
        return r.rgb, r.depth, r.disparity

    assert torch.autograd.gradcheck(fn, (t, deltas), eps=1e-6, atol=1e-8)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_composite_output_dtypes(dtype):
    result = composite(torch.ones(1, 2, dtype=dtype), torch.zeros(1, 2, 3, dtype=dtype),
                       torch.tensor([[1.0, 2.0]], dtype=dtype), torch.tensor([3.0], dtype=dtype))
    for value in (result.rgb, result.depth, result.disparity, result.acc, result.weights):
        assert value.dtype == dtype


# -- mip-NeRF 360's distortion loss -----------------------------------------------------------------


def test_distortion_by_hand_and_against_the_double_sum() -> None:
    from nerfpipe.nerf.rendering import distortion

    # all weight in one interval of length 0.1: only the within term, 1/3 * 1^2 * 0.1
    one = distortion(torch.tensor([[1.0]]), torch.tensor([[0.0]]), torch.tensor([[0.1]]))
    assert one.item() == pytest.approx(0.1 / 3)
    # half at each end of the ray: 2 * 0.5 * 0.5 * |0.05 - 0.95| + 1/3 * (0.25 * 0.1 + 0.25 * 0.1)
    split = distortion(torch.tensor([[0.5, 0.5]]), torch.tensor([[0.0, 0.9]]), torch.tensor([[0.1, 1.0]]))
    assert split.item() == pytest.approx(0.45 + 0.05 / 3)
    # random sorted intervals with zero-weight padding at the end (as packed marching samples have)
    g = torch.Generator().manual_seed(0)
    edges = torch.sort(torch.rand(4, 13, generator=g), dim=-1).values
    starts, ends = edges[:, :-1:2], edges[:, 1::2]  # 6 disjoint intervals per ray
    w = torch.rand(4, 6, generator=g) / 6
    w[:, -2:] = 0.0
    mid = (starts + ends) / 2
    brute = (w[:, :, None] * w[:, None, :] * (mid[:, :, None] - mid[:, None, :]).abs()).sum(dim=(1, 2)) \
        + (w**2 * (ends - starts)).sum(dim=-1) / 3
    torch.testing.assert_close(distortion(w, starts, ends), brute)


def test_distortion_gradients_pull_split_weight_together() -> None:
    from nerfpipe.nerf.rendering import distortion

    w = torch.tensor([[0.45, 0.1, 0.45]], requires_grad=True)
    loss = distortion(w, torch.tensor([[0.0, 0.45, 0.9]]), torch.tensor([[0.1, 0.55, 1.0]]))
    loss.sum().backward()
    assert torch.isfinite(w.grad).all()
    assert w.grad[0, 1] < w.grad[0, 0]  # moving weight to the middle costs less than adding to an end
