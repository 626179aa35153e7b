"""Volume rendering of packed samples (Eq. 3) and the weights of Eq. 5, checked on tiny hand-worked cases,
against the cumulative-product route of the authors' code, and across rays of different lengths."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import example, given, settings
from hypothesis import strategies as st

from nerfpipe.nerf.render.volume import (
    MAX_OPTICAL_DEPTH,
    RaySamples,
    distortion,
    interval_stop_depths,
    optical_depth,
    volume_render,
)

LN2 = math.log(2.0)


def t64(values) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float64)


def packed(starts: list[list[float]], ends: list[list[float]], dtype=torch.float64) -> RaySamples:
    """Rays of any number of samples (one list each) packed ray after ray; t at each stretch's start."""
    ray = torch.cat([torch.full((len(row),), i, dtype=torch.long) for i, row in enumerate(starts)])
    s = torch.tensor([v for row in starts for v in row], dtype=dtype)
    e = torch.tensor([v for row in ends for v in row], dtype=dtype)
    return RaySamples(ray, s.clone(), s, e, len(starts))


def render(sigmas, colors, samples: RaySamples, near=None, far=None, background=None):
    near = torch.zeros(samples.n_rays, dtype=samples.t.dtype) if near is None else near
    far = torch.full((samples.n_rays,), 100.0, dtype=samples.t.dtype) if far is None else far
    return volume_render(sigmas, colors, samples, near, far, background)


def test_optical_depth_clamps_negative_density_and_caps():
    # sigma = -3 counts as 0; 2 * 0.5 = 1; 1e9 * 1 is capped.
    tau = optical_depth(t64([[-3.0, 2.0, 1e9]]), t64([[1.0, 0.5, 1.0]]))
    assert torch.equal(tau, t64([[0.0, 1.0, MAX_OPTICAL_DEPTH]]))


def test_weights_are_transmittance_times_alpha_by_hand():
    # stretches of length 1, sigma = ln2, ln4, 0, ln2 -> alpha = 1/2, 3/4, 0, 1/2
    # T = 1, 1/2, 1/2 * 1/4 = 1/8, 1/8 (the empty sample lets everything through)
    # w = T alpha = 1/2, 3/8, 0, 1/16
    samples = packed([[0.0, 1.0, 2.0, 3.0]], [[1.0, 2.0, 3.0, 4.0]])
    out = render(t64([LN2, 2 * LN2, 0.0, LN2]), torch.zeros(4, 3, dtype=torch.float64), samples)
    assert torch.allclose(out.weights, t64([0.5, 0.375, 0.0, 0.0625]), rtol=0, atol=1e-15)


def test_two_samples_by_hand():
    # stretches [1, 2], [2, 3]; sigma = ln 2 -> alpha = 1/2, 1/2; weights 1/2, (1 - 1/2) 1/2 = 1/4; acc = 3/4.
    # rgb = 1/2 red + 1/4 green + 1/4 blue background = (0.5, 0.25, 0.25)
    # a ray stops g(ln 2) = 1/ln2 - 1/(2 - 1) into a stretch of optical depth ln 2: depth = (1/2 z_0 + 1/4 z_1) / (3/4)
    samples = packed([[1.0, 2.0]], [[2.0, 3.0]])
    colors = t64([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    out = render(t64([LN2, LN2]), colors, samples, far=t64([3.0]), background=t64([0.0, 0.0, 1.0]))
    assert torch.allclose(out.weights, t64([0.5, 0.25]), rtol=0, atol=1e-15)
    assert torch.allclose(out.acc, t64([0.75]), rtol=0, atol=1e-15)
    assert torch.allclose(out.rgb, t64([[0.5, 0.25, 0.25]]), rtol=0, atol=1e-15)
    g = 1 / LN2 - 1
    depth = (0.5 * (1 + g) + 0.25 * (2 + g)) / 0.75
    assert torch.allclose(out.depth, t64([depth]), rtol=0, atol=1e-14)
    assert torch.allclose(out.disparity, t64([1 / depth]), rtol=0, atol=1e-14)


def test_a_gap_between_stretches_is_empty_space_and_black_is_the_default_background():
    # stretches [2, 2.5] and [3, 3.25] (a sampler skipped [2.5, 3]) with sigma 2 ln2, 4 ln2: tau = ln2 each, so
    # weights 1/2, 1/4 as if they touched; no background is black. The second stretch's stop: 3 + 0.25 g(ln 2).
    samples = packed([[2.0, 3.0]], [[2.5, 3.25]])
    out = render(t64([2 * LN2, 4 * LN2]), t64([[1.0, 1.0, 1.0], [1.0, 0.0, 0.0]]), samples)
    assert torch.allclose(out.weights, t64([0.5, 0.25]), rtol=0, atol=1e-15)
    assert torch.allclose(out.rgb, t64([[0.75, 0.5, 0.5]]), rtol=0, atol=1e-15)
    g = 1 / LN2 - 1
    depth = (0.5 * (2 + 0.5 * g) + 0.25 * (3 + 0.25 * g)) / 0.75
    assert torch.allclose(out.depth, t64([depth]), rtol=0, atol=1e-14)


def test_interval_stop_depths_by_hand():
    # stretches [1, 1.5], [1.5, 3], [3, 6].
    # sigma 0: a ray stops uniformly within the stretch: its middle, 1.25, 2.25, 4.5.
    # sigma 1e6 (opaque): at the stretch start plus the mean free path 1e-6.
    # sigma ln2 / 1.5 over [1.5, 3]: tau = ln2, g = 1/ln2 - 1/(2 - 1).
    starts, ends = t64([1.0, 1.5, 3.0]), t64([1.5, 3.0, 6.0])
    assert torch.allclose(interval_stop_depths(t64([0.0, 0.0, 0.0]), starts, ends), t64([1.25, 2.25, 4.5]), rtol=0, atol=1e-15)
    opaque = interval_stop_depths(t64([1e6, 1e6, 1e6]), starts, ends)
    assert torch.allclose(opaque, starts + 1e-6, rtol=0, atol=1e-12)
    middle = interval_stop_depths(t64([0.0, LN2 / 1.5, 0.0]), starts, ends)
    assert torch.allclose(middle[1], t64(1.5 + 1.5 * (1 / LN2 - 1)), rtol=0, atol=1e-14)


def test_interval_stop_depths_small_optical_depth_is_smooth_float32():
    # the series branch (tau < 0.1) and the exact branch meet without a jump, and tiny densities do not
    # lose the result to cancellation: g(tau) -> 1/2 - tau/12
    sigmas = torch.tensor([1e-9, 0.099 / 0.5, 0.101 / 0.5])
    z = interval_stop_depths(sigmas, torch.zeros(3), torch.full((3,), 0.5))
    tau = torch.tensor([1e-9 * 0.5, 0.099, 0.101])
    expected = 0.5 * (0.5 - tau / 12 + tau**3 / 720)
    assert torch.allclose(z, expected, rtol=0, atol=1e-6)


def test_per_ray_background():
    # Ray 0 hits nothing (sigma 0): its own background (0.2, 0.4, 0.6); ray 1 has acc 3/4 of white over
    # background (1, 0, 0): 0.75 + 0.25 * (1, 0, 0) = (1, 0.75, 0.75).
    samples = packed([[1.0, 2.0], [1.0, 2.0]], [[2.0, 3.0], [2.0, 3.0]])
    background = t64([[0.2, 0.4, 0.6], [1.0, 0.0, 0.0]])
    out = render(t64([0.0, 0.0, LN2, LN2]), torch.ones(4, 3, dtype=torch.float64), samples, background=background)
    assert torch.allclose(out.rgb, t64([[0.2, 0.4, 0.6], [1.0, 0.75, 0.75]]), rtol=0, atol=1e-15)


def test_nothing_hit_depth_is_far_and_a_ray_without_samples_is_background():
    # acc = 0: depth is the far bound (4), disparity 1/4; ray 1 has no samples at all.
    samples = packed([[1.0, 2.0], []], [[2.0, 3.0], []])
    out = render(t64([0.0, 0.0]), torch.zeros(2, 3, dtype=torch.float64), samples, far=t64([4.0, 5.0]),
                 background=t64([0.1, 0.2, 0.3]))
    assert torch.equal(out.acc, t64([0.0, 0.0])) and torch.equal(out.depth, t64([4.0, 5.0]))
    assert torch.equal(out.disparity, t64([0.25, 0.2]))
    assert torch.equal(out.rgb, t64([[0.1, 0.2, 0.3]] * 2))


def test_transmittance_before_an_opaque_sample_float32():
    # sigma delta = 0.3 then 1e6 * 0.01 = 1e4 (the cap): T_2 = exp(-0.3), since T_2 only depends on what
    # lies before it; w_1 + w_2 = 1 - T_3 = 1 (T_3 = exp(-1e4.3) = 0).
    samples = packed([[0.0, 1.0, 1.01]], [[1.0, 1.01, 2.01]], torch.float32)
    out = render(torch.tensor([0.3, 1e6, 0.2]), torch.zeros(3, 3), samples)
    assert out.weights.sum().item() <= 1.0 + 1e-6
    assert torch.allclose(out.weights, torch.tensor([1 - math.exp(-0.3), math.exp(-0.3), 0.0]), rtol=1e-6, atol=0)


def test_a_ray_behind_many_opaque_rays_keeps_its_transmittance_float32():
    """Transmittance is an exclusive sum of optical depth *per ray*; summing over all samples first (one
    pass for rays of any length) must not lose a late ray's small optical depths to the large sum before it."""
    heavy = 20000
    starts = [[float(k) for k in range(10)] for _ in range(heavy)] + [[0.0, 1.0, 2.0]]
    ends = [[float(k + 1) for k in range(10)] for _ in range(heavy)] + [[1.0, 2.0, 3.0]]
    samples = packed(starts, ends, torch.float32)
    sigmas = torch.cat([torch.full((10 * heavy,), 1e6), torch.tensor([1e-6, 2e-6, 3e-6])])
    out = render(sigmas, torch.ones(len(sigmas), 3), samples)
    expected = [math.exp(-sum([1e-6, 2e-6][:i])) * -math.expm1(-tau) for i, tau in enumerate([1e-6, 2e-6, 3e-6])]
    assert torch.allclose(out.weights[-3:], torch.tensor(expected), rtol=1e-5, atol=0)


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


def cumulative_product_route(sigmas: torch.Tensor, deltas: torch.Tensor) -> torch.Tensor:
    """w_i = T_i alpha_i with T_i = prod_{j<i} (1 - alpha_j), as the authors' code computes them (R, N)."""
    alphas = 1.0 - torch.exp(-(sigmas.clamp_min(0) * deltas).clamp_max(MAX_OPTICAL_DEPTH))
    survive = torch.cat([torch.ones_like(alphas[..., :1]), torch.cumprod(1.0 - alphas, dim=-1)[..., :-1]], dim=-1)
    return survive * alphas


def as_packed(deltas: torch.Tensor) -> RaySamples:
    """(R, N) stretch lengths -> packed samples tiling each ray from 0."""
    ends = torch.cumsum(deltas, dim=-1)
    return RaySamples.dense(ends - deltas, ends - deltas, ends)


@settings(max_examples=60, deadline=None)
@given(density_rays())
@example(([[0.3, 1e6, 0.2]], [[1.0, 0.01, 1.0]]))  # a large tau after a small one: see the test above
def test_weights_agree_with_the_cumulative_product_route_float32(case):
    sigmas, deltas = (torch.tensor(v, dtype=torch.float32) for v in case)
    samples = as_packed(deltas)
    out = render(sigmas.reshape(-1), torch.zeros(sigmas.numel(), 3), samples)
    lengths = (samples.ends - samples.starts).reshape(deltas.shape)  # what float32 keeps of the deltas
    assert torch.allclose(out.weights, cumulative_product_route(sigmas, lengths).reshape(-1), rtol=1e-5, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(density_rays(), st.integers(0, 2**31 - 1))
def test_volume_render_equals_the_alpha_route_float64(case, seed):
    # rgb by the cumulative-product route of the authors' code, plus (1 - acc) background.
    sigmas, deltas = (torch.tensor(v, dtype=torch.float64) for v in case)
    g = torch.Generator().manual_seed(seed)
    colors = torch.rand(*sigmas.shape, 3, generator=g, dtype=torch.float64)
    background = torch.rand(3, generator=g, dtype=torch.float64)
    out = render(sigmas.reshape(-1), colors.reshape(-1, 3), as_packed(deltas), background=background)
    weights = cumulative_product_route(sigmas, deltas)
    acc = weights.sum(-1)
    rgb = (weights.unsqueeze(-1) * colors).sum(-2) + (1 - acc).unsqueeze(-1) * background
    assert torch.allclose(out.weights, weights.reshape(-1), rtol=1e-10, atol=1e-13)
    assert torch.allclose(out.acc, acc, rtol=1e-10, atol=1e-13)
    assert torch.allclose(out.rgb, rgb, rtol=1e-10, atol=1e-13)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 6), min_size=1, max_size=6), st.integers(0, 2**31 - 1))
def test_rays_of_different_lengths_render_as_they_do_alone(counts, seed):
    g = torch.Generator().manual_seed(seed)
    rows = [torch.cumsum(0.05 + torch.rand(2 * c, generator=g, dtype=torch.float64), 0) for c in counts]
    samples = packed([r[0::2].tolist() for r in rows], [r[1::2].tolist() for r in rows])
    n = len(samples)
    sigmas, colors = 3 * torch.rand(n, generator=g, dtype=torch.float64), torch.rand(n, 3, generator=g, dtype=torch.float64)
    together = render(sigmas, colors, samples)
    start = 0
    for i, c in enumerate(counts):
        alone = render(sigmas[start:start + c], colors[start:start + c],
                       packed([rows[i][0::2].tolist()], [rows[i][1::2].tolist()]))
        for key in ("rgb", "depth", "acc"):
            assert torch.allclose(getattr(together, key)[i], getattr(alone, key)[0], rtol=1e-12, atol=1e-14), key
        assert torch.allclose(together.weights[start:start + c], alone.weights, rtol=1e-12, atol=1e-14)
        start += c


def test_volume_render_gradcheck_float64():
    g = torch.Generator().manual_seed(0)
    sigmas = (0.2 + 1.5 * torch.rand(7, generator=g, dtype=torch.float64)).requires_grad_()
    colors = torch.rand(7, 3, generator=g, dtype=torch.float64).requires_grad_()
    background = torch.rand(3, generator=g, dtype=torch.float64).requires_grad_()
    edges = torch.cumsum(0.1 + torch.rand(9, generator=g, dtype=torch.float64), dim=0)
    samples = packed([edges[:3].tolist(), edges[4:8].tolist()], [edges[1:4].tolist(), edges[5:9].tolist()])

    def fn(s, c, bg):
        r = render(s, c, samples, background=bg)
        return r.rgb, r.depth, r.disparity, r.acc, r.weights

    assert torch.autograd.gradcheck(fn, (sigmas, colors, background), eps=1e-6, atol=1e-8)


def test_volume_render_gradcheck_wrt_the_stretches_float64():
    g = torch.Generator().manual_seed(1)
    sigmas = 0.2 + torch.rand(4, generator=g, dtype=torch.float64)
    colors = torch.rand(4, 3, generator=g, dtype=torch.float64)
    starts = torch.tensor([1.0, 1.7, 2.1, 3.0], dtype=torch.float64, requires_grad=True)
    ends = torch.tensor([1.6, 2.0, 2.9, 3.5], dtype=torch.float64, requires_grad=True)

    def fn(s, e):
        samples = RaySamples(torch.zeros(4, dtype=torch.long), s, s, e, 1)
        r = render(sigmas, colors, samples, near=t64([0.5]), far=t64([4.0]))
        return r.rgb, r.depth, r.disparity

    assert torch.autograd.gradcheck(fn, (starts, ends), eps=1e-6, atol=1e-8)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_output_dtypes(dtype):
    samples = packed([[1.0, 2.0]], [[2.0, 3.0]], dtype)
    out = render(torch.ones(2, dtype=dtype), torch.zeros(2, 3, dtype=dtype), samples,
                 near=torch.zeros(1, dtype=dtype), far=torch.full((1,), 3.0, dtype=dtype))
    for value in (out.rgb, out.depth, out.disparity, out.acc, out.weights):
        assert value.dtype == dtype
    half = render(torch.ones(2, dtype=torch.bfloat16), torch.zeros(2, 3, dtype=torch.bfloat16),
                  packed([[1.0, 2.0]], [[2.0, 3.0]], torch.bfloat16), near=torch.zeros(1), far=torch.full((1,), 3.0))
    assert half.rgb.dtype == half.weights.dtype == torch.float32  # bf16 in, composited in float32


# -- mip-NeRF 360's distortion loss -----------------------------------------------------------------


def spanned(starts: list[list[float]], ends: list[list[float]]) -> RaySamples:
    samples = packed(starts, ends, torch.float32)
    samples.spans = (samples.starts, samples.ends)
    return samples


def test_distortion_by_hand_and_against_the_double_sum() -> None:
    # all weight in one interval of length 0.1: only the within term, 1/3 * 1^2 * 0.1
    one = distortion(torch.tensor([1.0]), spanned([[0.0]], [[0.1]]))
    assert one.item() == pytest.approx(0.1 / 3)
    # half at each end of the ray: 2 * 0.5 * 0.5 * |0.05 - 0.95| + 1/3 * (0.25 * 0.1 + 0.25 * 0.1)
    split = distortion(torch.tensor([0.5, 0.5]), spanned([[0.0, 0.9]], [[0.1, 1.0]]))
    assert split.item() == pytest.approx(0.45 + 0.05 / 3)
    # random sorted intervals on rays of different lengths, against the double sum ray by ray
    g = torch.Generator().manual_seed(0)
    rows = [torch.sort(torch.rand(2 * c, generator=g), dim=-1).values for c in (6, 1, 0, 4)]
    samples = spanned([r[0::2].tolist() for r in rows], [r[1::2].tolist() for r in rows])
    w = torch.rand(len(samples), generator=g) / 6
    got = distortion(w, samples)
    start = 0
    for i, r in enumerate(rows):
        c = len(r) // 2
        wi, s, e = w[start:start + c], r[0::2], r[1::2]
        mid = (s + e) / 2
        brute = (wi[:, None] * wi[None, :] * (mid[:, None] - mid[None, :]).abs()).sum() + (wi**2 * (e - s)).sum() / 3
        torch.testing.assert_close(got[i], brute)
        start += c


def test_distortion_gradients_pull_split_weight_together() -> None:
    w = torch.tensor([0.45, 0.1, 0.45], requires_grad=True)
    loss = distortion(w, spanned([[0.0, 0.45, 0.9]], [[0.1, 0.55, 1.0]]))
    loss.sum().backward()
    assert torch.isfinite(w.grad).all()
    assert w.grad[1] < w.grad[0]  # moving weight to the middle costs less than adding to an end


def test_selecting_by_a_mask_or_by_its_indices_picks_the_same_samples() -> None:
    """``RaySamples.select`` turns a mask into indices once: the same samples, spans and known values either way,
    in order, and an all-false mask picks none."""
    t = torch.arange(6, dtype=torch.float32)
    samples = RaySamples(torch.tensor([0, 0, 1, 1, 1, 2]), t, t - 0.5, t + 0.5, 3, (t / 6, (t + 1) / 6),
                         (t * 10, t.unsqueeze(-1).repeat(1, 2)))
    mask = torch.tensor([True, False, True, True, False, True])
    by_mask, by_index = samples.select(mask), samples.select(mask.nonzero().squeeze(-1))
    for a, b in ((by_mask.ray, by_index.ray), (by_mask.t, by_index.t), (by_mask.spans[1], by_index.spans[1]),
                 (by_mask.known[1], by_index.known[1])):
        assert torch.equal(a, b)
    assert by_mask.t.tolist() == [0.0, 2.0, 3.0, 5.0] and by_mask.n_rays == 3
    assert len(samples.select(torch.zeros(6, dtype=torch.bool))) == 0
