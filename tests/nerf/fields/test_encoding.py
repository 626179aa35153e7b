"""Positional encoding, Eq. 4: hand values, the documented ordering and the output width."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import example, given, settings
from hypothesis import strategies as st

from nerfpipe.nerf.fields.encoding import encoded_size, positional_encoding

R2 = math.sqrt(0.5)


def test_single_coordinate_hand_values():
    # p = 0.25, L = 2: sin(pi/4), cos(pi/4), sin(pi/2), cos(pi/2) = r, r, 1, 0 with r = 1/sqrt(2).
    out = positional_encoding(torch.tensor([[0.25]], dtype=torch.float64), 2)
    assert torch.allclose(out, torch.tensor([[R2, R2, 1.0, 0.0]], dtype=torch.float64), rtol=0, atol=1e-15)


def test_include_input_prepends_p():
    out = positional_encoding(torch.tensor([[0.25]], dtype=torch.float64), 2, include_input=True)
    assert torch.allclose(out, torch.tensor([[0.25, R2, R2, 1.0, 0.0]], dtype=torch.float64), rtol=0, atol=1e-15)


def test_three_coordinates_are_interleaved_inside_each_term():
    # x, y, z = 0.25, 0.5, -0.5 and L = 2, include_input: the documented order is
    # [x y z | sin(pi x) sin(pi y) sin(pi z) | cos(pi .) x3 | sin(2 pi .) x3 | cos(2 pi .) x3]
    # sin(pi .)   = r, 1, -1        cos(pi .)   = r, 0, 0
    # sin(2 pi .) = 1, 0, 0         cos(2 pi .) = 0, -1, -1
    p = torch.tensor([[0.25, 0.5, -0.5]], dtype=torch.float64)
    out = positional_encoding(p, 2, include_input=True)
    expected = [0.25, 0.5, -0.5, R2, 1.0, -1.0, R2, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0, -1.0]
    assert torch.allclose(out, torch.tensor([expected], dtype=torch.float64), rtol=0, atol=1e-15)


@pytest.mark.parametrize("num_freqs", [0, 1, 4, 10])
@pytest.mark.parametrize("include_input", [False, True])
@pytest.mark.parametrize("dims", [1, 3])
def test_encoded_size_matches_output_width(num_freqs, include_input, dims):
    out = positional_encoding(torch.zeros(5, 2, dims), num_freqs, include_input)
    assert out.shape == (5, 2, encoded_size(num_freqs, include_input, dims))
    assert encoded_size(num_freqs, include_input, dims) == dims * (2 * num_freqs + int(include_input))


def test_zero_frequencies():
    x = torch.tensor([[0.1, 0.2, 0.3]])
    assert torch.equal(positional_encoding(x, 0, include_input=True), x)
    empty = positional_encoding(x, 0, include_input=False)
    assert empty.shape == (1, 0)
    assert encoded_size(0, False) == 0


def test_negative_frequencies_rejected():
    with pytest.raises(ValueError):
        positional_encoding(torch.zeros(1, 3), -1)


def test_paper_widths():
    # Section 5.1: L = 10 for x and L = 4 for d: 60 and 24 values (without p itself, as in Fig. 7).
    assert positional_encoding(torch.zeros(2, 3), 10).shape[-1] == 60
    assert positional_encoding(torch.zeros(2, 3), 4).shape[-1] == 24


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0, width=32), min_size=3, max_size=3), st.integers(1, 10))
@example([0.0, 0.0, -0.8795238137245178], 10)  # remainder(p, 2) = p + 2 rounded p's last bit: 1e-4 off at k = 9
def test_matches_direct_formula_float64(coords, num_freqs):
    # Two routes: the reduced phase of the module in float32 vs sin(2^k pi p) computed directly in float64.
    x32 = torch.tensor([coords], dtype=torch.float32)
    x64 = x32.double()
    out = positional_encoding(x32, num_freqs, include_input=True)
    parts = [x64]
    for k in range(num_freqs):
        parts += [torch.sin(2.0**k * math.pi * x64), torch.cos(2.0**k * math.pi * x64)]
    direct = torch.cat(parts, dim=-1)
    assert out.dtype == torch.float32
    assert torch.allclose(out.double(), direct, rtol=0, atol=1e-5)


def test_gradient_is_the_chain_rule():
    # d/dp sin(2^k pi p) = 2^k pi cos(2^k pi p); at p = 0.25, L = 2 the sum over the four terms is
    # pi (cos(pi/4) - sin(pi/4)) + 2 pi (cos(pi/2) - sin(pi/2)) = 0 - 2 pi.
    p = torch.tensor([[0.25]], dtype=torch.float64, requires_grad=True)
    positional_encoding(p, 2).sum().backward()
    assert p.grad.item() == pytest.approx(-2 * math.pi, abs=1e-12)


def test_gradcheck_float64():
    p = torch.tensor([[0.3, -0.7, 0.9], [0.1, 0.2, -0.4]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: positional_encoding(x, 4, True), (p,), eps=1e-6, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(width=32, allow_nan=False, allow_infinity=False), min_size=1, max_size=4), st.integers(1, 12))
def test_odd_and_even_symmetry_is_exact(coords, num_freqs):
    # sin is odd and cos even: gamma(-p) has the sines of gamma(p) negated and the same cosines, bit for bit
    # (the reduction of the phase is exact, so it cannot break the symmetry).
    x = torch.tensor([coords], dtype=torch.float32)
    pos = positional_encoding(x, num_freqs).reshape(1, num_freqs, 2, -1)
    neg = positional_encoding(-x, num_freqs).reshape(1, num_freqs, 2, -1)
    assert torch.equal(neg[:, :, 0], -pos[:, :, 0])
    assert torch.equal(neg[:, :, 1], pos[:, :, 1])
