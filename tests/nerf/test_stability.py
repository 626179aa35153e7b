"""Numerical stability of the NeRF maths at the edges: extreme densities, empty intervals, degenerate bounds,
one sample per ray, empty or peaked coarse weights, huge coordinates, rays parallel to the image plane, and the
native C kernels (the table gradient, the contracted march's steps) at extreme tables and far bounds.

Every case runs in float32 and, where it applies, under CPU autocast to bfloat16 (and float16 when this torch
supports it on the CPU), and checks concrete bounds, not just "does not crash".
"""

from __future__ import annotations

import contextlib
import dataclasses
import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch import nn

from nerfpipe.nerf.fields.encoding import positional_encoding

from tests.nerf.fieldfns import paper_mlp
from nerfpipe.nerf.fields.mlp import NerfField
from nerfpipe.nerf.spaces.rays import RayBatch, ndc_rays
from nerfpipe.nerf.render.volume import RaySamples, optical_depth, volume_render
from nerfpipe.nerf.samplers.configs import HierarchicalConfig
from nerfpipe.nerf.samplers.hierarchical import HierarchicalSampler
from nerfpipe.nerf.samplers.sampling import sample_intervals, sample_pdf, stratified_samples
from tests.nerf.fieldfns import render_fields

EXTREME_DENSITIES = [0.0, 1e-8, 1e6, 1e10]


@dataclasses.dataclass
class Dense:
    """A ``RenderOutput`` of rays with the same number of samples, weights as (R, N)."""

    rgb: torch.Tensor
    depth: torch.Tensor
    disparity: torch.Tensor
    acc: torch.Tensor
    weights: torch.Tensor


def composite(sigmas, colors, t, far, background=None, deltas=None) -> Dense:
    """``volume_render`` of (R, N) samples at sorted ``t``: each standing for the stretch nearest it (from t_1,
    through the midpoints, to ``far``), as ``HierarchicalSampler`` lays them out; or [t_i, t_i + deltas_i]."""
    if deltas is None:
        edges = sample_intervals(t, t[:, 0], far)
        starts, ends = edges[:, :-1], edges[:, 1:]
    else:
        starts, ends = t, t + deltas
    samples = RaySamples.dense(t, starts, ends)
    out = volume_render(sigmas.reshape(-1), colors.reshape(-1, 3), samples, t[:, 0], far, background)
    return Dense(out.rgb, out.depth, out.disparity, out.acc, out.weights.reshape(t.shape))
F32_MAX = torch.finfo(torch.float32).max


def _cpu_autocast_works(dtype: torch.dtype) -> str | None:
    """None if CPU autocast to ``dtype`` runs a Linear layer here, else why not."""
    try:
        with torch.autocast("cpu", dtype=dtype):
            out = nn.Linear(3, 2)(torch.ones(1, 3))
        return None if out.dtype == dtype else f"CPU autocast to {dtype} leaves Linear in {out.dtype}"
    except RuntimeError as error:  # older torch warns and leaves autocast off instead: the dtype check above
        return f"CPU autocast to {dtype} unsupported: {error}"


MODES = [
    pytest.param("float32", id="float32"),
    pytest.param("bfloat16", id="autocast-bf16"),
    pytest.param("float16", id="autocast-fp16"),
]


def precision(mode: str):
    """The context a case runs in: plain float32, or CPU autocast to bf16 / fp16 (skipped if unsupported)."""
    if mode == "float32":
        return contextlib.nullcontext()
    dtype = getattr(torch, mode)
    reason = _cpu_autocast_works(dtype)
    if reason is not None:
        pytest.skip(reason)
    return torch.autocast("cpu", dtype=dtype)


def assert_sane(result, background=None, colors_max: float = 1.0) -> None:
    """The bounds every composite must keep, whatever went in."""
    w = result.weights
    assert w.dtype in (torch.float32, torch.float64)
    assert torch.isfinite(w).all()
    assert (w >= 0).all() and (w <= 1).all()
    per_ray = w.sum(-1) if isinstance(result, Dense) else result.samples.per_ray(w)
    assert (per_ray <= 1 + 1e-6).all()
    assert torch.isfinite(result.acc).all() and (result.acc >= 0).all() and (result.acc <= 1 + 1e-6).all()
    assert torch.isfinite(result.rgb).all()
    assert (result.rgb >= 0).all() and (result.rgb <= colors_max + 1e-6).all()
    assert torch.isfinite(result.depth).all() and torch.isfinite(result.disparity).all()
    assert (result.disparity >= 0).all()


def assert_finite_grads(*tensors: torch.Tensor) -> None:
    for tensor in tensors:
        assert tensor.grad is not None
        assert torch.isfinite(tensor.grad).all()


def scene(density: float, n_rays: int = 3, n_samples: int = 8):
    """Samples at the bin centres of [2, 6], constant ``density``, colours and background in [0, 1]."""
    g = torch.Generator().manual_seed(0)
    near, far = torch.full((n_rays,), 2.0), torch.full((n_rays,), 6.0)
    t = stratified_samples(near, far, n_samples, perturb=False)
    sigmas = torch.full((n_rays, n_samples), density, requires_grad=True)
    colors = torch.rand(n_rays, n_samples, 3, generator=g).requires_grad_()
    background = torch.rand(3, generator=g).requires_grad_()
    return sigmas, colors, t, far, background


def loss_of(result) -> torch.Tensor:
    return result.rgb.sum() + result.depth.sum() + result.disparity.sum() + result.acc.sum() + result.weights.sum()


# --- extreme densities -------------------------------------------------------------------------------


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("density", EXTREME_DENSITIES)
def test_extreme_density_composite(density, mode):
    sigmas, colors, t, far, background = scene(density)
    reference = composite(sigmas, colors, t, far, background)
    with precision(mode):
        result = composite(sigmas, colors, t, far, background)
    assert_sane(result)
    # compositing ignores autocast: the same float32 numbers inside it as outside
    assert result.rgb.dtype == torch.float32
    for key in ("rgb", "depth", "disparity", "acc", "weights"):
        assert torch.equal(getattr(result, key), getattr(reference, key)), key
    loss_of(result).backward()
    assert_finite_grads(sigmas, colors, background)


@pytest.mark.parametrize("mode", MODES[1:])
@pytest.mark.parametrize("density", EXTREME_DENSITIES)
def test_extreme_density_half_precision_inputs(density, mode):
    # A network in reduced precision hands over bf16 densities and colours (bf16 holds 1e10; fp16 would
    # not, so only bf16 inputs here). Compositing upcasts them: same result as from their float32 values.
    sigmas, colors, t, far, background = scene(density)
    s16 = sigmas.detach().to(torch.bfloat16).requires_grad_()
    c16 = colors.detach().to(torch.bfloat16).requires_grad_()
    with precision(mode):
        result = composite(s16, c16, t, far, background.detach())
    reference = composite(s16.detach().float(), c16.detach().float(), t, far, background.detach())
    assert result.rgb.dtype == torch.float32
    assert_sane(result)
    assert torch.equal(result.rgb, reference.rgb) and torch.equal(result.weights, reference.weights)
    loss_of(result).backward()
    assert_finite_grads(s16, c16)


def test_tiny_density_alpha_keeps_its_value():
    # sigma 1e-8, delta 0.5: alpha = 1 - exp(-5e-9) = 5e-9 to 1e-3, where 1 - exp() in float32 would give 0.
    sigmas, colors, t, far, background = scene(1e-8)
    samples = RaySamples.dense(t, t, t + 0.5)
    out = volume_render(sigmas.detach().reshape(-1), colors.detach().reshape(-1, 3), samples, t[:, 0], far)
    assert torch.allclose(out.weights[:8], torch.full((8,), 5e-9), rtol=1e-3, atol=0)
    assert float(optical_depth(torch.tensor(1e-8), torch.tensor(0.5))) == pytest.approx(5e-9, rel=1e-6)
    # and with the stretches nearest each sample: t = 2.25, 2.75, ..., 5.75 stand for [2.25, 2.5], six of 0.5,
    # and [5.5, 6]: the first weight is alpha_1 = 1e-8 * 0.25 (T_1 = 1), acc = 1e-8 * 3.75
    result = composite(sigmas.detach(), colors.detach(), t, far, background.detach())
    assert torch.allclose(result.weights[:, 0], torch.full((3,), 2.5e-9), rtol=1e-3, atol=0)
    assert torch.allclose(result.acc, torch.full((3,), 3.75e-8), rtol=1e-3, atol=0)


def test_huge_density_first_sample_takes_all():
    sigmas, colors, t, far, background = scene(1e10)
    result = composite(sigmas, colors, t, far, background)
    expected = torch.zeros(3, 8)
    expected[:, 0] = 1.0
    assert torch.equal(result.weights, expected)
    assert torch.equal(result.acc, torch.ones(3))
    assert torch.allclose(result.rgb, colors[:, 0].detach(), rtol=0, atol=1e-7)
    assert torch.allclose(result.depth, t[:, 0], rtol=0, atol=1e-6)


def test_huge_density_behind_empty_space():
    # empty up to sample 5, then 1e10: sample 5 takes all the weight; depth is where its stretch of ray
    # starts, halfway from sample 4, plus the mean free path 1e-10.
    sigmas, colors, t, far, background = scene(0.0)
    sigmas = sigmas.detach().clone()
    sigmas[:, 5:] = 1e10
    sigmas.requires_grad_()
    result = composite(sigmas, colors, t, far, background)
    assert torch.equal(result.weights.argmax(-1), torch.full((3,), 5))
    assert torch.allclose(result.weights[:, 5], torch.ones(3), rtol=0, atol=0)
    assert torch.allclose(result.depth, 0.5 * (t[:, 4] + t[:, 5]), rtol=0, atol=1e-6)
    loss_of(result).backward()
    assert_finite_grads(sigmas, colors, background)


densities = st.one_of(st.just(0.0), st.floats(-10.0, 12.0).map(lambda e: 10.0**e))
spacings = st.one_of(st.just(0.0), st.floats(-8.0, 1.0).map(lambda e: 10.0**e))


@settings(max_examples=50, deadline=None)
@given(
    st.integers(1, 16).flatmap(lambda n: st.tuples(st.lists(densities, min_size=n, max_size=n),
                                                   st.lists(spacings, min_size=n, max_size=n))),
    st.floats(0.0, 1.0),
    st.integers(0, 2**31 - 1),
)
def test_random_wide_range_densities_and_deltas(case, bg, seed):
    sig, dts = case
    sigmas = torch.tensor([sig], requires_grad=True)
    deltas = torch.tensor([dts])
    t = 1.0 + torch.cumsum(deltas, -1) - deltas  # t_1 = 1, spaced by the deltas
    far = t[:, -1] + deltas[:, -1]
    colors = torch.rand(1, len(sig), 3, generator=torch.Generator().manual_seed(seed)).requires_grad_()
    background = torch.full((3,), bg, requires_grad=True)
    result = composite(sigmas, colors, t, far, background, deltas=deltas)
    assert_sane(result)
    assert (result.depth >= t[:, 0] - 1e-6).all() and (result.depth <= far + 1e-6).all()
    loss_of(result).backward()
    assert_finite_grads(sigmas, colors, background)


# --- empty intervals and degenerate bounds --------------------------------------------------------------


def assert_only_background(result, background, far) -> None:
    """Nothing was hit: opacity 0, the background colour exactly, depth at far and disparity 1 / far."""
    n = far.shape[0]
    assert torch.equal(result.acc, torch.zeros(n))
    assert torch.equal(result.rgb, background.detach().expand(n, 3))
    assert torch.equal(result.depth, far) and torch.equal(result.disparity, 1.0 / far)


@pytest.mark.parametrize("density", EXTREME_DENSITIES)
def test_zero_length_intervals_show_the_background(density):
    sigmas, colors, t, far, background = scene(density)
    result = composite(sigmas, colors, t, far, background, deltas=torch.zeros(3, 8))
    assert torch.equal(result.weights, torch.zeros(3, 8))
    assert_only_background(result, background, far)
    loss_of(result).backward()
    assert_finite_grads(sigmas, colors, background)


@pytest.mark.parametrize("perturb", [False, True])
@pytest.mark.parametrize("lindisp", [False, True])
@pytest.mark.parametrize("density", EXTREME_DENSITIES)
def test_near_equals_far(perturb, lindisp, density):
    near = far = torch.tensor([3.0, 0.5])
    t = stratified_samples(near, far, 5, perturb=perturb, lindisp=lindisp, generator=torch.Generator().manual_seed(0))
    assert torch.equal(t, near[:, None].expand(2, 5))
    sigmas = torch.full((2, 5), density, requires_grad=True)
    colors = torch.rand(2, 5, 3, requires_grad=True)
    background = torch.tensor([0.25, 0.5, 0.75], requires_grad=True)
    result = composite(sigmas, colors, t, far, background)
    assert_only_background(result, background, far)
    loss_of(result).backward()
    assert_finite_grads(sigmas, colors, background)


@pytest.mark.parametrize("perturb", [False, True])
def test_one_sample_per_ray(perturb):
    near, far = torch.tensor([2.0, 0.0]), torch.tensor([6.0, 1.0])
    t = stratified_samples(near, far, 1, perturb=perturb, generator=torch.Generator().manual_seed(0))
    assert t.shape == (2, 1)
    assert (t[:, 0] >= near).all() and (t[:, 0] <= far).all()
    if not perturb:
        assert torch.equal(t[:, 0], torch.tensor([4.0, 0.5]))
    # one sample, delta = far - t; sigma ln 2 / delta makes alpha 1/2
    sigmas = (math.log(2.0) / (far - t[:, 0])).unsqueeze(-1).requires_grad_()
    colors = torch.ones(2, 1, 3, requires_grad=True)
    result = composite(sigmas, colors, t, far, torch.zeros(3))
    assert torch.allclose(result.acc, torch.full((2,), 0.5), rtol=1e-6)
    assert torch.allclose(result.rgb, torch.full((2, 3), 0.5), rtol=1e-6)
    # the one stretch is [t, far] with optical depth ln 2: depth = t + (far - t) (1/ln2 - 1/(2 - 1))
    expected = t[:, 0] + (far - t[:, 0]) * (1 / math.log(2.0) - 1)
    assert torch.allclose(result.depth, expected, rtol=1e-6, atol=0)
    loss_of(result).backward()
    assert_finite_grads(sigmas, colors)
    # one bin for inverse transform sampling: [near, far]
    edges = sample_intervals(t, near, far)
    assert edges.shape == (2, 2)
    for deterministic in (True, False):
        fine = sample_pdf(edges, result.weights.detach(), 6, deterministic, torch.Generator().manual_seed(1))
        assert torch.isfinite(fine).all()
        assert (fine >= near[:, None]).all() and (fine <= far[:, None]).all()
        assert (fine[:, 1:] >= fine[:, :-1]).all()


# --- inverse transform sampling of degenerate weights -------------------------------------------------------


PDF_WEIGHTS = {
    "all-zero": [0.0] * 8,
    "one-bin": [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
    "one-bin-huge": [0.0] * 7 + [1e30],
    "tiny": [1e-30] * 8,
    "first-bin": [1.0] + [0.0] * 7,
}


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("deterministic", [True, False])
@pytest.mark.parametrize("kind", list(PDF_WEIGHTS))
def test_sample_pdf_degenerate_weights(kind, deterministic, mode):
    near, far = torch.tensor([2.0, 0.1]), torch.tensor([6.0, 100.0])
    t = stratified_samples(near, far, 8, perturb=False)
    edges = sample_intervals(t, near, far)
    weights = torch.tensor([PDF_WEIGHTS[kind]] * 2)
    with precision(mode):
        fine = sample_pdf(edges, weights, 32, deterministic, torch.Generator().manual_seed(0))
    assert fine.dtype == torch.float32
    assert torch.isfinite(fine).all()
    assert (fine[:, 1:] >= fine[:, :-1]).all()
    assert (fine >= near[:, None]).all() and (fine <= far[:, None]).all()
    if kind == "one-bin" and deterministic:
        # u in [1/64, 63/64]; the seven empty bins hold 7e-5 / (1 + 8e-5) of the mass together: all in bin 3
        assert (fine >= edges[:, 3:4]).all() and (fine <= edges[:, 4:5]).all()
    if kind == "one-bin-huge":
        assert (fine >= edges[:, 7:8]).all()
    if kind in ("all-zero", "tiny") and deterministic:
        # uniform: 32 samples evenly over [near, far]
        expected = near[:, None] + (far - near)[:, None] * (torch.arange(32) + 0.5) / 32
        assert torch.allclose(fine, expected, rtol=1e-5, atol=1e-5)


# --- network gradients at extreme densities ------------------------------------------------------------------


def scaled_field(scale: float) -> tuple[NerfField, callable]:
    torch.manual_seed(0)
    net = NerfField(paper_mlp(depth=2, width=16, view_width=8, density_activation="softplus"))

    def field(points, viewdirs):
        rgb, sigma = net(points, viewdirs)
        return rgb, sigma * scale

    return net, field


def ray_batch(n: int, near: float, far: float) -> RayBatch:
    g = torch.Generator().manual_seed(2)
    origins = torch.rand(n, 3, generator=g) - 0.5
    directions = nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    return RayBatch(origins, directions, directions, torch.full((n,), near), torch.full((n,), far))


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("scale", [0.0, 1e-8, 1.0, 1e6, 1e10])
@pytest.mark.parametrize(
    "bounds, n_coarse",
    [((0.5, 2.5), 8), ((1.0, 1.0), 8), ((0.5, 2.5), 1)],
    ids=["ordinary", "near-equals-far", "one-sample"],
)
def test_network_gradients_finite(mode, scale, bounds, n_coarse):
    net, field = scaled_field(scale)
    rays = ray_batch(4, *bounds)
    target = torch.full((4, 3), 0.5)
    with precision(mode):
        out = render_fields(field, None, rays, HierarchicalSampler(HierarchicalConfig(n_coarse=n_coarse, n_fine=4)),
                            torch.ones(3), train=True, generator=torch.Generator().manual_seed(0))
        loss = sum(((level.rgb - target) ** 2).mean() + level.depth.mean() + level.disparity.mean() + level.acc.mean()
                   for level in out.passes())
    for level in out.passes():
        assert_sane(level)
    assert torch.isfinite(loss)
    loss.backward()
    for name, param in net.named_parameters():
        assert param.grad is not None, name
        assert torch.isfinite(param.grad).all(), name
    # the colour path is live whenever something is hit
    if scale >= 1.0 and bounds[0] < bounds[1]:
        assert net.rgb.weight.grad.abs().sum() > 0


# --- positional encoding of huge coordinates ------------------------------------------------------------------


def huge(dtype: torch.dtype) -> list[float]:
    top = torch.finfo(dtype).max  # the float32 maximum would round to inf in bf16
    return [1e6, 1e10, 1e30, top, -1e6, -1e10, -1e30, -top, 1e6 + 0.25, -(1e6 + 0.25)]


# bf16 coordinates under fp16 autocast are left out: torch's CPU autocast itself rejects that mix in
# torch.stack (at::autocast::prioritize), and no nerfpipe path produces it.
@pytest.mark.parametrize(
    "mode, dtype",
    [(m, d) for m in ("float32", "bfloat16", "float16") for d in (torch.float32, torch.bfloat16)
     if not (m == "float16" and d == torch.bfloat16)],
)
def test_encoding_of_huge_coordinates(mode, dtype):
    x = torch.tensor(huge(dtype), dtype=dtype).reshape(-1, 1)
    assert torch.isfinite(x).all()
    with precision(mode):
        out = positional_encoding(x, 10, include_input=False)
    assert torch.isfinite(out).all()
    assert (out.abs() <= 1).all()
    if dtype == torch.float32:
        # 1e6 + 0.25 (exact in float32): 2^k 1e6 is even, so the phases are those of 0.25:
        # k = 0: sin(pi/4), cos(pi/4); k = 1: 1, 0; k = 2: 0, -1; k >= 3: 0, 1.
        r = math.sqrt(0.5)
        expected = [r, r, 1.0, 0.0, 0.0, -1.0] + [0.0, 1.0] * 7
        assert torch.allclose(out[8], torch.tensor(expected), rtol=0, atol=1e-6)
        # -(1e6 + 0.25): sines negated, cosines the same
        assert torch.allclose(out[9], torch.tensor(expected) * torch.tensor([-1.0, 1.0] * 10), rtol=0, atol=1e-6)
        # whole even numbers (all of 1e10, 1e30 and the float32 maximum are): sin 0, cos 1 at every frequency
        assert torch.equal(out[:8].abs(), torch.tensor([0.0, 1.0] * 10).expand(8, 20))


def test_encoding_equals_direct_formula_for_moderate_coordinates():
    # every float32 on a fine grid of [-1, 1] (negatives included) against sin(2^k pi p) in float64
    x32 = torch.linspace(-1.0, 1.0, 4001).unsqueeze(-1)
    x32 = torch.cat([x32, x32.nextafter(torch.tensor(2.0)), x32.nextafter(torch.tensor(-2.0))])
    out = positional_encoding(x32, 10).double()
    x64 = x32.double()
    direct = torch.cat([f(2.0**k * math.pi * x64) for k in range(10) for f in (torch.sin, torch.cos)], dim=-1)
    assert torch.allclose(out, direct, rtol=0, atol=1e-5)


def test_encoding_gradient_of_huge_coordinates_is_finite():
    x = torch.tensor([[1e30, -F32_MAX, 1e6 + 0.25]], requires_grad=True)
    positional_encoding(x, 10).sum().backward()
    assert torch.isfinite(x.grad).all()


# --- NDC for rays parallel to the image plane ---------------------------------------------------------------


@pytest.mark.parametrize("dz", [0.0, -0.0, 1e-12, -1e-12, 1e-7])
def test_ndc_parallel_rays_are_finite(dz):
    origins = torch.tensor([[0.0, 0.0, 0.0], [0.3, -0.2, -1.0], [1.0, 1.0, -5.0]])
    directions = torch.tensor([[1.0, 0.0, dz], [0.0, 1.0, dz], [0.6, 0.8, dz]], requires_grad=True)
    o, d = ndc_rays(origins, directions, focal=500.0, width=640, height=480)
    assert torch.isfinite(o).all() and torch.isfinite(d).all()
    (o.sum() + d.sum()).backward()
    assert torch.isfinite(directions.grad).all()


def test_ndc_parallel_ray_in_the_near_plane_is_finite():
    # a ray already in z = -near with dz = 0: the origin does not move, oz = -1 exactly.
    o, d = ndc_rays(torch.tensor([[0.5, 0.5, -1.0]]), torch.tensor([[1.0, 0.0, 0.0]]), 100.0, 200, 200)
    assert torch.isfinite(o).all() and torch.isfinite(d).all()
    assert torch.allclose(o, torch.tensor([[0.5, 0.5, -1.0]]), rtol=0, atol=1e-6)


# --- depth and disparity when nothing is hit ------------------------------------------------------------------


@pytest.mark.parametrize("density", [0.0, 1e-30])
def test_depth_and_disparity_of_an_empty_ray(density):
    # acc = 0 (or below ACC_EPS): depth = far = 5, disparity = 1/5, gradients finite, also w.r.t. t and far.
    sigmas = torch.full((2, 4), density, requires_grad=True)
    colors = torch.rand(2, 4, 3, requires_grad=True)
    t = torch.tensor([[1.0, 2.0, 3.0, 4.0]] * 2, requires_grad=True)
    far = torch.tensor([5.0, 5.0], requires_grad=True)
    result = composite(sigmas, colors, t, far)
    assert torch.equal(result.depth, torch.tensor([5.0, 5.0]))
    assert torch.equal(result.disparity, torch.tensor([0.2, 0.2]))
    (result.depth.sum() + result.disparity.sum() + result.rgb.sum()).backward()
    assert_finite_grads(sigmas, colors, t, far)
    assert torch.equal(far.grad, torch.tensor([1 - 1 / 25.0] * 2))  # d(far + 1/far)/d far


def test_depth_just_above_the_hit_threshold():
    # sigma 1e-8: acc about 4e-8, above ACC_EPS: depth is the weighted mean, inside [t_1, far]. The stretches
    # are [1, 1.5], [1.5, 2.5], [2.5, 3.5], [3.5, 5], nearly transparent: weights in proportion to their
    # lengths 0.5, 1, 1, 1.5, each ray stopping in a stretch's middle: (0.625 + 2 + 3 + 6.375) / 4 = 3.
    sigmas = torch.full((1, 4), 1e-8, requires_grad=True)
    t = torch.tensor([[1.0, 2.0, 3.0, 4.0]])
    result = composite(sigmas, torch.rand(1, 4, 3), t, torch.tensor([5.0]))
    assert result.acc.item() > 1e-10
    assert result.depth.item() == pytest.approx(3.0, rel=1e-4)
    assert result.disparity.item() == pytest.approx(1 / 3.0, rel=1e-4)
    (result.depth.sum() + result.disparity.sum()).backward()
    assert_finite_grads(sigmas)


def test_disparity_of_zero_depth_is_finite():
    # near = far = 0: depth 0, disparity 0 rather than inf.
    result = composite(torch.ones(1, 2), torch.rand(1, 2, 3), torch.zeros(1, 2), torch.zeros(1))
    assert result.depth.item() == 0.0
    assert result.disparity.item() == 0.0


# -- empty-space skipping and early termination -----------------------------------------------------


class _Constant(nn.Module):
    """A field of one density and colour everywhere, with gradients to both."""

    def __init__(self, density: float) -> None:
        super().__init__()
        self.raw = nn.Parameter(torch.tensor(float(density)))
        self.color = nn.Parameter(torch.tensor([0.2, 0.5, 0.8]))

    def forward(self, x, d=None, density_noise=0.0):
        return self.color.expand(len(x), 3) * torch.ones_like(x[:, :1]), self.raw.expand(len(x)) * torch.ones_like(x[:, 0])

    def query_density(self, x):
        return self(x)[1]

    def density_features(self, x):
        return self(x)[1], x

    def colour(self, x, d=None):
        return self(x)[0]


def _box_rays(n: int = 16) -> RayBatch:
    from nerfpipe.nerf.spaces.rays import intersect_box

    g = torch.Generator().manual_seed(0)
    o = torch.tensor([0.0, 0.0, 3.0]).expand(n, 3).clone()
    d = torch.nn.functional.normalize(torch.rand((n, 3), generator=g) * torch.tensor([0.4, 0.4, 0.0]) - torch.tensor([0.2, 0.2, 1.0]), dim=-1)
    enter, exit_ = intersect_box(o, d, -torch.ones(3), torch.ones(3))
    return RayBatch(o, d, d, enter, exit_)


def _marching(field: nn.Module, grid, config, space=None):
    from nerfpipe.nerf.model import RadianceModel
    from nerfpipe.nerf.spaces.ray_space import BoxSpace
    from nerfpipe.nerf.samplers.marching import MarchingSampler

    return RadianceModel(field, None, MarchingSampler(grid, config), space or BoxSpace(), None)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("density", EXTREME_DENSITIES)
def test_marching_keeps_bounds_and_gradients_at_extreme_densities(mode: str, density: float) -> None:
    from nerfpipe.nerf.samplers.configs import MarchingConfig
    from nerfpipe.nerf.samplers.occupancy import OccupancyGrid

    field = _Constant(density)
    grid = OccupancyGrid((-1.0,) * 3, (1.0,) * 3, 8)
    model = _marching(field, grid, MarchingConfig(steps=64, early_stop=1e-4))
    rays = _box_rays()
    white = torch.ones(3)
    with precision(mode):
        result = model.render(rays, train=True, generator=torch.Generator().manual_seed(0), background=white)
    assert_sane(result, white)
    # the distortion loss of the marched weights: finite, at most the ray's weight squared times its length
    # (here at most 1 x the whole march), and with finite gradients too
    loss = result.distortion()
    assert loss.shape == result.acc.shape and bool(torch.isfinite(loss).all())
    assert bool(((loss >= -1e-6) & (loss <= 1.0 + 1e-6)).all())
    (result.rgb.sum() + loss.sum()).backward()
    assert torch.isfinite(field.raw.grad) and bool(torch.isfinite(field.color.grad).all())
    # early termination: an opaque field stops each ray after its first sample or two; a clear one never
    if density >= 1e6:
        assert result.evaluated <= 2 * len(rays)
    elif density <= 1e-8:
        assert result.evaluated > 60 * len(rays) // 2
    with torch.no_grad(), precision(mode):
        rendered = model.render_rays(rays, background=white)
    assert bool(torch.isfinite(rendered["rgb"]).all()) and bool(((rendered["acc"] >= 0) & (rendered["acc"] <= 1 + 1e-6)).all())
    assert bool(((rendered["depth"] >= rays.near - 1e-5) & (rendered["depth"] <= rays.far + 1e-5)).all())
    torch.testing.assert_close(rendered["acc"], result.acc.detach(), atol=2e-4, rtol=0)


def test_marching_degenerate_rays_give_the_background() -> None:
    """Zero-length rays (near == far), rays outside the box and an all-empty grid: no samples, the
    background colour, zero opacity, depth at far, and no NaN anywhere, gradients included."""
    from nerfpipe.nerf.samplers.configs import MarchingConfig
    from nerfpipe.nerf.samplers.occupancy import OccupancyGrid

    field = _Constant(10.0)
    grid = OccupancyGrid((-1.0,) * 3, (1.0,) * 3, 4)
    model = _marching(field, grid, MarchingConfig(steps=32))
    o = torch.tensor([[0.0, 0.0, 3.0], [5.0, 5.0, 5.0], [0.0, 0.0, 0.5]])
    d = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    near = torch.tensor([2.0, 1.0, 0.0])
    far = torch.tensor([2.0, 1.0, 1.0])  # zero length; outside the box; inside but the grid is empty
    rays = RayBatch(o, d, d, near, far)
    grid.occupied.zero_()
    grey = torch.tensor([0.5, 0.5, 0.5])
    result = model.render(rays, train=True, background=grey)
    assert result.evaluated == 0
    torch.testing.assert_close(result.rgb, grey.expand(3, 3))
    assert result.acc.tolist() == [0.0, 0.0, 0.0] and torch.equal(result.depth, far)
    result.rgb.sum().backward()
    assert field.color.grad is None or bool(torch.isfinite(field.color.grad).all())
    rendered = model.render_rays(rays, background=grey)
    assert float(rendered["samples"]) == 0 and torch.equal(rendered["depth"], far)
    assert torch.allclose(rendered["rgb"], grey.expand(3, 3))
    # and an empty batch
    none = model.render_rays(rays.slice(0, 0), background=grey)
    assert none["rgb"].shape == (0, 3)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("density", EXTREME_DENSITIES)
def test_contracted_marching_keeps_bounds_and_gradients(mode: str, density: float) -> None:
    """World rays from outside the scene box to far bounds up to 1e6 through contracted space, at every
    extreme density: a bounded number of steps, sane composites, finite gradients, depth within [near, far]."""
    from nerfpipe.nerf.samplers.configs import MarchingConfig
    from nerfpipe.nerf.samplers.occupancy import OccupancyGrid
    from nerfpipe.nerf.spaces.ray_space import ContractedSpace

    field = _Constant(density)
    grid = OccupancyGrid((-2.0,) * 3, (2.0,) * 3, 8)
    config = MarchingConfig(steps=64, early_stop=1e-4)
    model = _marching(field, grid, config, ContractedSpace(((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))))
    box = _box_rays()
    o = box.origins * 2.0  # cameras at 6 units, outside the box, in the contracted shell
    near = torch.full((len(o),), 0.1)
    far = torch.logspace(0, 6, len(o))  # 1 .. 1e6 units away
    rays = RayBatch(o, box.directions, box.viewdirs, near, far)
    white = torch.ones(3)
    with precision(mode):
        result = model.render(rays, train=True, generator=torch.Generator().manual_seed(0), background=white)
    assert_sane(result, white)
    assert result.evaluated <= len(o) * (4 * config.steps + 1)
    result.rgb.sum().backward()
    assert torch.isfinite(field.raw.grad) and bool(torch.isfinite(field.color.grad).all())
    with torch.no_grad(), precision(mode):
        rendered = model.render_rays(rays, background=white)
    assert bool(torch.isfinite(rendered["rgb"]).all())
    assert bool(((rendered["depth"] >= near - 1e-4) & (rendered["depth"] <= far * (1 + 1e-5))).all())
    torch.testing.assert_close(rendered["acc"], result.acc.detach(), atol=2e-4, rtol=0)


def test_contraction_of_extreme_coordinates_is_finite_with_finite_gradients() -> None:
    from nerfpipe.nerf.spaces.contraction import Contraction, contract

    x = torch.tensor([[0.0, 0.0, 0.0], [1e-30, 0.0, 0.0], [1.0, 1.0, 1.0], [F32_MAX, -F32_MAX, 0.0], [3e38, 1.0, 1.0]],
                     requires_grad=True)
    y = contract(x)
    y.sum().backward()
    assert bool(torch.isfinite(y).all()) and float(y.detach().abs().max()) <= 2.0 and bool(torch.isfinite(x.grad).all())
    steps = Contraction.step_scale(y.detach())
    assert bool(torch.isfinite(steps).all()) and float(steps.min()) == 1.0


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("linear", [False, True])
def test_exposure_gains_stay_finite_at_black_white_and_extreme_gains(mode: str, linear: bool) -> None:
    """Per-image appearance (``nerfpipe.nerf.appearance``): identity at initialisation; colours in [0, 1] and
    finite gradients for black, white and tiny colours under gains from 2^-40 to 2^40."""
    from nerfpipe.nerf.appearance import ExposureGains

    rgb = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1e-12, 1e-8, 1e-30], [0.5, 0.0031308, 0.04045]] * 3,
                       requires_grad=True)
    gains = ExposureGains(3, linear)
    image = torch.arange(12) // 4
    with precision(mode):
        assert torch.allclose(gains(rgb, image).float(), rgb.detach(), atol=1e-6)  # identity at initialisation
    with torch.no_grad():
        gains.log2_gains.copy_(torch.tensor([[-40.0] * 3, [0.0] * 3, [40.0] * 3]))
    with precision(mode):
        out = gains(rgb, image)
    assert bool(((out >= 0) & (out <= 1)).all())
    assert torch.equal(out[:4].detach(), torch.zeros(4, 3)) or float(out[:4].detach().max()) < 1e-6  # 2^-80 relative: black
    out.sum().backward()
    assert bool(torch.isfinite(rgb.grad).all()) and bool(torch.isfinite(gains.log2_gains.grad).all())


@pytest.mark.parametrize("mode", MODES)
def test_camera_refinement_is_the_identity_at_first_with_finite_gradients_through_a_grid_field(mode: str) -> None:
    """Camera refinement (``nerfpipe.nerf.refinement``): no change at initialisation (So3.exp at a zero
    vector), and finite, non-zero gradients from a grid field's colours back to the corrections, there and
    after large corrections (a half turn)."""
    from nerfpipe.nerf.fields.configs import GridConfig
    from nerfpipe.nerf.fields.grid import GridField
    from nerfpipe.nerf.spaces.rays import camera_rays
    from nerfpipe.nerf.refinement import PoseRefinement

    torch.manual_seed(0)
    field = GridField((-1.0,) * 3, (1.0,) * 3, GridConfig(levels=2, min_resolution=8, max_resolution=16))
    torch.nn.init.uniform_(field.table, -0.3, 0.3)
    c2w = torch.eye(4).repeat(3, 1, 1)
    c2w[:, 2, 3] = -3.0  # looking down +z at the box from z = -3
    refinement = PoseRefinement(3)
    assert torch.equal(refinement(c2w), c2w)
    uv = torch.rand(64, 2) * 32
    k = torch.tensor([32.0, 32.0, 16.0, 16.0]).expand(64, 4)
    image = torch.arange(64) % 3
    for tangent in (torch.zeros(3, 6), torch.tensor([[math.pi, 0, 0, 0.5, 0, 0], [0, 0, 0, 0, 0, 0], [0, 1e-20, 0, 0, 0, 0]])):
        with torch.no_grad():
            refinement.tangent.copy_(tangent)
        refinement.zero_grad()
        with precision(mode):
            origins, directions = camera_rays(uv, k, refinement(c2w)[image])
            points = origins + 3.0 * directions
            rgb, sigma = field(points, torch.nn.functional.normalize(directions, dim=-1))
            loss = rgb.float().sum() + sigma.float().sum() + refinement.penalty()
        loss.backward()
        grad = refinement.tangent.grad
        assert bool(torch.isfinite(grad).all()) and float(grad.abs().sum()) > 0


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("value", [0.0, 1e-8, 1e4, -1e4])
@pytest.mark.parametrize("kind", ["grid", "hash"])
def test_the_native_kernels_keep_a_grid_field_finite_in_contracted_space(mode: str, value: float, kind: str) -> None:
    """The native C kernels (``nerfpipe.nerf.native``: the dense and the hashed grid's gather and scatter, the
    contracted march's steps) at the edges: a grid field whose table holds one extreme value everywhere
    (densities of exp(+-1e4) clamp at the field's cap or vanish), rays from outside the box to far bounds up to 1e6.
    The field's kernels and the steps' run (counted); the steps are torch's loop's to float rounding, finite and
    within [near, far]; the composite is sane and the table's gradient finite. (The same features and gradients
    native or not, on the same samples: tests/nerf/test_native.py.)"""
    from nerfpipe.nerf import native
    from nerfpipe.nerf.compiling import VARIABLE
    from nerfpipe.nerf.fields.configs import GridConfig, HashConfig
    from nerfpipe.nerf.fields.grid import GridField
    from nerfpipe.nerf.fields.hash import HashGridField
    from nerfpipe.nerf.samplers.configs import MarchingConfig
    from nerfpipe.nerf.samplers.occupancy import OccupancyGrid
    from nerfpipe.nerf.spaces.ray_space import ContractedSpace

    if native.library() is None:
        pytest.skip("no native kernels on this machine (no C compiler, or NERFPIPE_COMPILE=off)")
    field_kernels = ("grid_gather", "grid_scatter")
    calls = dict.fromkeys((*field_kernels, "contracted_steps"), 0)

    def counted(name):
        fn = getattr(native, name)

        def call(*args):
            result = fn(*args)
            calls[name] += result is not None and result is not False
            return result
        return call

    box = _box_rays()
    rays = RayBatch(box.origins * 2.0, box.directions, box.viewdirs, torch.full((16,), 0.1), torch.logspace(0, 6, 16))
    space = ContractedSpace(((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)))
    if kind == "grid":
        field = GridField((-2.0,) * 3, (2.0,) * 3, GridConfig(levels=2, min_resolution=8, max_resolution=16))
    else:
        field = HashGridField((-2.0,) * 3, (2.0,) * 3, HashConfig(levels=2, min_resolution=8, max_resolution=64,
                                                                  log2_table=10))
    with torch.no_grad():
        field.table.fill_(value)
    model = _marching(field, OccupancyGrid((-2.0,) * 3, (2.0,) * 3, 8), MarchingConfig(steps=64, early_stop=1e-4), space)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(VARIABLE, "off")
        native.library.cache_clear()
        torch_steps = space.steps(rays.origins, rays.directions, rays.near, rays.far, 0.05, 257)
        patch.setenv(VARIABLE, "native")
        native.library.cache_clear()
        for name in calls:
            patch.setattr(native, name, counted(name))
        starts, ends = space.steps(rays.origins, rays.directions, rays.near, rays.far, 0.05, 257)
        with precision(mode):
            result = model.render(rays, train=True, generator=torch.Generator().manual_seed(0), background=torch.ones(3))
        assert_sane(result, torch.ones(3))
        result.rgb.sum().backward()
    native.library.cache_clear()
    assert all(calls[name] >= 1 for name in field_kernels) and calls["contracted_steps"] >= 2
    torch.testing.assert_close((starts, ends), torch_steps, rtol=1e-4, atol=1e-5)
    assert bool(torch.isfinite(ends).all()) and bool((starts >= rays.near[:, None]).all())
    assert bool((ends <= rays.far[:, None]).all()) and torch.equal(ends[:, -1], rays.far)
    assert field.table.grad is not None and bool(torch.isfinite(field.table.grad).all())


@pytest.mark.parametrize("value", [0.0, 1e-8, 1e4, -1e4])
@pytest.mark.parametrize("contracted", [True, False])
@pytest.mark.parametrize("kind", ["grid", "hash"])
def test_rendering_in_one_loop_a_ray_stays_finite_at_the_edges(value: float, contracted: bool, kind: str) -> None:
    """The native renderer (``nerfpipe.nerf.fused``, render.c) at the edges: a table of one extreme value everywhere
    (densities clamp at the field's cap or vanish, the colour MLP's sums of 1e4s), rays from outside the box to far
    bounds up to 1e6. It runs (not torch's path), and what it gives keeps the bounds every composite keeps: opacity
    and colour in [0, 1], depth within [near, far], every value finite. (Torch's results to float rounding:
    tests/nerf/test_fused.py.)"""
    from nerfpipe.nerf import native
    from nerfpipe.nerf.fields.configs import GridConfig, HashConfig
    from nerfpipe.nerf.fields.grid import GridField
    from nerfpipe.nerf.fields.hash import HashGridField
    from nerfpipe.nerf.fused import marched_grid
    from nerfpipe.nerf.samplers.configs import MarchingConfig
    from nerfpipe.nerf.samplers.occupancy import OccupancyGrid
    from nerfpipe.nerf.spaces.ray_space import BoxSpace, ContractedSpace

    if native.library() is None:
        pytest.skip("no native kernels on this machine (no C compiler, or NERFPIPE_COMPILE=off)")
    box = _box_rays()
    unit = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
    if contracted:
        rays = RayBatch(box.origins * 2.0, box.directions, box.viewdirs, torch.full((16,), 0.1), torch.logspace(0, 6, 16))
        space, lo, hi = ContractedSpace(unit), (-2.0,) * 3, (2.0,) * 3
    else:
        rays, space, lo, hi = box, BoxSpace(unit), (-1.0,) * 3, (1.0,) * 3
    field = (GridField(lo, hi, GridConfig(levels=2, min_resolution=8, max_resolution=16)) if kind == "grid" else
             HashGridField(lo, hi, HashConfig(levels=2, min_resolution=8, max_resolution=64, log2_table=10)))
    with torch.no_grad():
        field.table.fill_(value)
    model = _marching(field, OccupancyGrid(lo, hi, 8), MarchingConfig(steps=64, early_stop=1e-4), space)
    grid = marched_grid(model)
    assert grid is not None
    rgb, depth, acc, counts = native.render_marched(grid, rays.origins, rays.directions, rays.viewdirs, rays.near,
                                                    rays.far)
    assert all(bool(torch.isfinite(x).all()) for x in (rgb, depth, acc))
    assert bool((acc >= 0).all() and (acc <= 1 + 1e-6).all() and (rgb >= 0).all() and (rgb <= 1 + 1e-6).all())
    assert bool((depth >= rays.near).all() and (depth <= rays.far).all() and (counts >= 0).all())
    out = model.render_rays(rays)
    assert torch.equal(out["rgb"], rgb) and bool(torch.isfinite(out["disparity"]).all())


@pytest.mark.parametrize("contracted", [True, False])
def test_training_s_native_march_stays_within_its_rays_at_the_edges(contracted: bool, monkeypatch) -> None:
    """Training's march in one loop a ray (``native.march_marched``) at the edges: rays from outside the box to far
    bounds up to 1e6, rays whose near is their far, directions of 1e-6 and 1e6 units, every cell occupied. It runs,
    and every sample is finite, lies within its ray's [near, far] in order, takes at most the march's steps, and the
    budget holds."""
    from nerfpipe.nerf import native
    from nerfpipe.nerf.samplers.march import march
    from nerfpipe.nerf.samplers.occupancy import OccupancyGrid
    from nerfpipe.nerf.spaces.ray_space import BoxSpace, ContractedSpace

    if native.library() is None:
        pytest.skip("no native kernels on this machine (no C compiler, or NERFPIPE_COMPILE=off)")
    box = _box_rays()
    unit = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
    scale = torch.tensor([1e-6, 1.0, 1e6, 1.0] * 4).unsqueeze(-1)
    far = torch.logspace(0, 6, 16) if contracted else box.far
    near = torch.where(torch.arange(16) % 5 == 0, far, torch.full((16,), 0.1) if contracted else box.near)
    rays = RayBatch(box.origins * (2.0 if contracted else 1.0), box.directions * scale, box.viewdirs, near, far)
    space, lo, hi = (ContractedSpace(unit), (-2.0,) * 3, (2.0,) * 3) if contracted else (BoxSpace(unit), (-1.0,) * 3, (1.0,) * 3)
    grid = OccupancyGrid(lo, hi, 8)
    called = []
    kernel = native.march_marched
    monkeypatch.setattr(native, "march_marched", lambda *a: called.append(1) or kernel(*a))
    samples = march(rays, space, grid, 64, True, torch.Generator().manual_seed(0), budget=2000)
    assert called and len(samples) <= 2000 + 4 * 64 + 1
    ray = samples.ray
    assert all(bool(torch.isfinite(x).all()) for x in (samples.t, samples.starts, samples.ends, *samples.spans))
    assert bool((samples.starts >= rays.near[ray]).all() and (samples.ends <= rays.far[ray]).all())
    assert bool((samples.starts <= samples.t).all() and (samples.t <= samples.ends).all())
    assert bool((samples.counts() <= 4 * 64 + 1).all()) and bool((samples.spans[1] <= (4 * 64 + 1) / 64).all())
    assert not bool((ray % 5 == 0).any()), "a ray whose near is its far has no steps"
