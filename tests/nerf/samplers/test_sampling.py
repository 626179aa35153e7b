"""Stratified sampling (Eq. 2) and inverse transform sampling from the coarse weights (Section 5.2)."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from nerfpipe.nerf.samplers.sampling import DISPARITY_EPS, sample_intervals, sample_pdf, stratified_samples


def t64(values) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float64)


# --- Eq. 2 ------------------------------------------------------------------------------------------


def test_stratified_unperturbed_is_bin_centres():
    # near 2, far 6, N 4: bins of width 1 from 2; centres 2.5, 3.5, 4.5, 5.5.
    t = stratified_samples(torch.tensor([2.0]), torch.tensor([6.0]), 4, perturb=False)
    assert torch.equal(t, torch.tensor([[2.5, 3.5, 4.5, 5.5]]))


def test_stratified_unperturbed_per_ray_bounds():
    # ray 1: near 0, far 1, N 2 -> 0.25, 0.75.
    t = stratified_samples(t64([2.0, 0.0]), t64([6.0, 1.0]), 2, perturb=False)
    assert torch.allclose(t, t64([[3.0, 5.0], [0.25, 0.75]]), rtol=0, atol=1e-15)


def test_stratified_lindisp_bin_centres_in_disparity():
    # near 1, far 4, N 2: s = 0.25, 0.75 in disparity between 1/1 and 1/4:
    # t = 1 / (1 (1 - s) + 1/4 s) = 1 / 0.8125 = 16/13 and 1 / 0.4375 = 16/7.
    t = stratified_samples(t64([1.0]), t64([4.0]), 2, perturb=False, lindisp=True)
    assert torch.allclose(t, t64([[16.0 / 13.0, 16.0 / 7.0]]), rtol=0, atol=1e-14)


def test_stratified_lindisp_zero_near_is_clamped():
    # near 0 would divide by zero; it is clamped to DISPARITY_EPS, so samples are finite, inside [0, far].
    t = stratified_samples(torch.tensor([0.0]), torch.tensor([5.0]), 8, perturb=False, lindisp=True)
    assert torch.isfinite(t).all()
    assert (t >= 0).all() and (t <= 5).all()
    # the first centre, s = 1/16: 1 / (1e6 * 15/16 + 0.2 / 16), about 1.07e-6.
    expected = 1.0 / (15.0 / 16.0 / DISPARITY_EPS + 0.2 / 16.0)
    assert t[0, 0].item() == pytest.approx(expected, rel=1e-5)


@settings(max_examples=40, deadline=None)
@given(
    near=st.one_of(st.just(0.0), st.floats(1e-3, 10.0)),
    length=st.one_of(st.just(0.0), st.floats(1e-3, 100.0)),
    n=st.integers(1, 64),
    seed=st.integers(0, 2**31 - 1),
    lindisp=st.booleans(),
)
def test_stratified_perturbed_each_sample_in_its_own_bin(near, length, n, seed, lindisp):
    near_t = torch.tensor([near, near + 0.5], dtype=torch.float64)
    far_t = near_t + length
    g = torch.Generator().manual_seed(seed)
    t = stratified_samples(near_t, far_t, n, perturb=True, lindisp=lindisp, generator=g)
    assert t.shape == (2, n)
    assert (t[:, 1:] >= t[:, :-1]).all()
    assert (t >= near_t[:, None]).all() and (t <= far_t[:, None]).all()
    i = torch.arange(n, dtype=torch.float64)
    if lindisp:
        # bins are even in disparity: s_i = (1/near - 1/t) / (1/near - 1/far) lies in [i/N, (i+1)/N].
        if length == 0:
            return
        # (a near below DISPARITY_EPS is clamped to it, as documented)
        inv_n, inv_f = 1 / near_t[:, None].clamp_min(DISPARITY_EPS), 1 / far_t[:, None]
        s = (inv_n - 1 / t) / (inv_n - inv_f)
        lo, hi = i / n, (i + 1) / n
        assert (s >= lo - 1e-9).all() and (s <= hi + 1e-9).all()
    else:
        # Eq. 2: t_i in [tn + (i-1)/N (tf - tn), tn + i/N (tf - tn)], i counted from 1.
        lo = near_t[:, None] + i / n * length
        hi = near_t[:, None] + (i + 1) / n * length
        assert (t >= lo - 1e-9).all() and (t <= hi + 1e-9).all()


def test_stratified_perturbed_is_random_but_seeded():
    a = stratified_samples(torch.zeros(3), torch.ones(3), 8, generator=torch.Generator().manual_seed(7))
    b = stratified_samples(torch.zeros(3), torch.ones(3), 8, generator=torch.Generator().manual_seed(7))
    c = stratified_samples(torch.zeros(3), torch.ones(3), 8, generator=torch.Generator().manual_seed(8))
    assert torch.equal(a, b)
    assert not torch.equal(a, c)
    # and not the bin centres
    assert not torch.equal(a, stratified_samples(torch.zeros(3), torch.ones(3), 8, perturb=False))


def test_stratified_rejects_zero_samples():
    with pytest.raises(ValueError):
        stratified_samples(torch.zeros(1), torch.ones(1), 0)


def test_sample_intervals_midpoints():
    # t = 1, 2, 4 inside [0, 5]: edges 0, 1.5, 3, 5.
    edges = sample_intervals(t64([[1.0, 2.0, 4.0]]), t64([0.0]), t64([5.0]))
    assert torch.equal(edges, t64([[0.0, 1.5, 3.0, 5.0]]))


# --- inverse transform sampling ------------------------------------------------------------------------


def test_sample_pdf_uniform_weights_evenly_spaced():
    # edges 0..4, equal weights: CDF 0, 1/4, 1/2, 3/4, 1; u = 1/8, 3/8, 5/8, 7/8 -> 0.5, 1.5, 2.5, 3.5
    # (eps is added to every weight equally, so it changes nothing here).
    t = sample_pdf(t64([[0.0, 1.0, 2.0, 3.0, 4.0]]), t64([[1.0, 1.0, 1.0, 1.0]]), 4, deterministic=True)
    assert torch.allclose(t, t64([[0.5, 1.5, 2.5, 3.5]]), rtol=0, atol=1e-12)


def test_sample_pdf_uneven_weights_by_hand():
    # edges 0, 1, 2, weights 1, 3 (eps 0): CDF 0, 1/4, 1; u = (k + 1/2)/8.
    # u = 1/16, 3/16 fall in bin 0: t = u / (1/4) = 0.25, 0.75;
    # u = 5/16 .. 15/16 in bin 1: t = 1 + (u - 1/4) / (3/4) = 1 + 1/12, 1 + 3/12, ..., 1 + 11/12.
    t = sample_pdf(t64([[0.0, 1.0, 2.0]]), t64([[1.0, 3.0]]), 8, deterministic=True, eps=0.0)
    expected = [0.25, 0.75] + [1.0 + k / 12.0 for k in (1, 3, 5, 7, 9, 11)]
    assert torch.allclose(t, t64([expected]), rtol=0, atol=1e-12)
    # with the default eps the same to ~1e-5
    t_eps = sample_pdf(t64([[0.0, 1.0, 2.0]]), t64([[1.0, 3.0]]), 8, deterministic=True)
    assert torch.allclose(t_eps, t64([expected]), rtol=0, atol=1e-4)


def test_sample_pdf_all_weight_in_one_bin():
    # bin 2 = [2, 3] has all the weight: every u in [1/8, 7/8] lands there (the other bins only hold eps).
    edges = t64([[0.0, 1.0, 2.0, 3.0, 4.0]])
    t = sample_pdf(edges, t64([[0.0, 0.0, 1.0, 0.0]]), 16, deterministic=True)
    assert (t >= 2.0).all() and (t <= 3.0).all()
    assert (t[:, 1:] > t[:, :-1]).all()


def test_sample_pdf_zero_weights_sample_uniformly():
    # all zero -> uniform over [0, 4] thanks to eps: same as equal weights.
    t = sample_pdf(t64([[0.0, 1.0, 2.0, 3.0, 4.0]]), t64([[0.0, 0.0, 0.0, 0.0]]), 4, deterministic=True)
    assert torch.allclose(t, t64([[0.5, 1.5, 2.5, 3.5]]), rtol=0, atol=1e-12)


def test_sample_pdf_negative_weights_count_as_zero():
    a = sample_pdf(t64([[0.0, 1.0, 2.0]]), t64([[-5.0, 1.0]]), 6, deterministic=True)
    b = sample_pdf(t64([[0.0, 1.0, 2.0]]), t64([[0.0, 1.0]]), 6, deterministic=True)
    assert torch.equal(a, b)


@st.composite
def pdf_cases(draw):
    bins = draw(st.integers(1, 16))
    rows = draw(st.integers(1, 3))
    start = draw(st.floats(-10.0, 10.0))
    widths = [[draw(st.one_of(st.just(0.0), st.floats(1e-4, 5.0))) for _ in range(bins)] for _ in range(rows)]
    weight = st.one_of(st.just(0.0), st.floats(-8.0, 3.0).map(lambda e: 10.0**e))
    weights = [[draw(weight) for _ in range(bins)] for _ in range(rows)]
    return start, widths, weights


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@settings(max_examples=40, deadline=None)
@given(case=pdf_cases(), n=st.integers(1, 32), deterministic=st.booleans(), seed=st.integers(0, 2**31 - 1))
def test_sample_pdf_sorted_finite_inside(dtype, case, n, deterministic, seed):
    start, widths, weights = case
    edges = start + torch.cat([torch.zeros(len(widths), 1, dtype=torch.float64),
                               torch.cumsum(torch.tensor(widths, dtype=torch.float64), -1)], -1)
    edges, weights = edges.to(dtype), torch.tensor(weights, dtype=dtype)
    g = torch.Generator().manual_seed(seed)
    t = sample_pdf(edges, weights, n, deterministic=deterministic, generator=g)
    assert t.shape == (len(widths), n) and t.dtype == dtype
    assert torch.isfinite(t).all()
    assert (t[:, 1:] >= t[:, :-1]).all()
    assert (t >= edges[:, :1]).all() and (t <= edges[:, -1:]).all()


def test_sample_pdf_random_u_follows_the_pdf():
    # weights 1, 3 on [0, 1], [1, 2]: about a quarter of 4000 random samples land in bin 0.
    g = torch.Generator().manual_seed(0)
    t = sample_pdf(t64([[0.0, 1.0, 2.0]]), t64([[1.0, 3.0]]), 4000, generator=g)
    share = (t < 1.0).double().mean().item()
    assert 0.22 < share < 0.28


def test_sample_pdf_gradcheck_float64():
    # weights 0.1, 0.4, 0.3, 0.2 -> CDF ~0, 0.1, 0.5, 0.8, 1; u = 1/8, 3/8, 5/8, 7/8 sit well inside bins.
    edges = t64([[0.0, 1.0, 2.5, 3.0, 4.0], [1.0, 1.5, 2.0, 4.0, 5.0]]).requires_grad_()
    weights = t64([[0.1, 0.4, 0.3, 0.2], [0.3, 0.3, 0.2, 0.2]]).requires_grad_()

    def fn(e, w):
        return sample_pdf(e, w, 4, deterministic=True)

    assert torch.autograd.gradcheck(fn, (edges, weights), eps=1e-6, atol=1e-8)


def test_sample_pdf_gradient_is_nonzero():
    # a sample in bin [1, 2.5] moves with that bin's edges: d t / d edges is not all zero.
    edges = t64([[0.0, 1.0, 2.5, 3.0, 4.0]]).requires_grad_()
    weights = t64([[0.1, 0.4, 0.3, 0.2]]).requires_grad_()
    sample_pdf(edges, weights, 4, deterministic=True).sum().backward()
    assert edges.grad.abs().sum() > 0 and weights.grad.abs().sum() > 0
