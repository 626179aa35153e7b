"""The MLP of Section 3 / Fig. 7: layer shapes, output ranges, the ablations of Table 2 and its cost."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from tests.nerf.fieldfns import paper_mlp
from nerfpipe.nerf.fields.mlp import NerfField

TINY = paper_mlp(depth=2, width=16, view_width=8, pos_freqs=2, dir_freqs=1)


@pytest.fixture(scope="module")
def paper_field() -> NerfField:
    torch.manual_seed(0)
    return NerfField(paper_mlp())


def shapes(module: nn.Module) -> list[tuple[int, int]]:
    return [(m.in_features, m.out_features) for m in module.modules() if isinstance(m, nn.Linear)]


def test_paper_config_layer_shapes(paper_field):
    # gamma(x): 3 * 2 * 10 = 60 inputs (no raw p, as Fig. 7); gamma(d): 3 * 2 * 4 = 24.
    # Trunk: 60 -> 256, then 256 -> 256 x 4; after the fifth layer (index 4) the input is concatenated
    # again, so layer 6 takes 256 + 60 = 316; then 256 -> 256 twice more.
    trunk = [(layer.in_features, layer.out_features) for layer in paper_field.trunk]
    assert trunk == [(60, 256)] + [(256, 256)] * 4 + [(316, 256)] + [(256, 256)] * 2
    assert (paper_field.density.in_features, paper_field.density.out_features) == (256, 1)
    assert (paper_field.feature.in_features, paper_field.feature.out_features) == (256, 256)
    # the view branch: feature 256 + gamma(d) 24 = 280 -> 128 -> rgb 3
    assert (paper_field.view.in_features, paper_field.view.out_features) == (280, 128)
    assert (paper_field.rgb.in_features, paper_field.rgb.out_features) == (128, 3)


def test_paper_config_outputs_in_range(paper_field):
    g = torch.Generator().manual_seed(1)
    x = torch.rand(64, 3, generator=g) * 2 - 1
    d = nn.functional.normalize(torch.randn(64, 3, generator=g), dim=-1)
    with torch.no_grad():
        rgb, sigma = paper_field(x, d)
    assert rgb.shape == (64, 3) and sigma.shape == (64,)
    assert ((rgb > 0) & (rgb < 1)).all()
    assert (sigma >= 0).all() and torch.isfinite(sigma).all()


def test_paper_flops_by_hand(paper_field):
    # 60*256 + 4*256*256 + 316*256 + 2*256*256 (trunk) + 256 (sigma) + 256*256 (feature)
    # + 280*128 + 128*3, times 2.
    mults = 60 * 256 + 4 * 256 * 256 + 316 * 256 + 2 * 256 * 256 + 256 + 256 * 256 + 280 * 128 + 128 * 3
    assert paper_field.flops_per_sample() == 2 * mults


def test_tiny_flops_by_hand():
    # depth 2, width 4, skip after layer 0, view 3, L = 1 for x and d: gamma widths 6 and 6.
    # trunk 6 -> 4, (4 + 6) -> 4; sigma 4 -> 1; feature 4 -> 4; view (4 + 6) -> 3; rgb 3 -> 3.
    # sum(in * out) = 24 + 40 + 4 + 16 + 30 + 9 = 123; flops = 246.
    field = NerfField(paper_mlp(depth=2, width=4, skip_after=1, view_width=3, pos_freqs=1, dir_freqs=1))
    assert shapes(field) == [(6, 4), (10, 4), (4, 1), (4, 4), (10, 3), (3, 3)]
    assert field.flops_per_sample() == 246


def test_view_independent_ignores_directions():
    torch.manual_seed(0)
    field = NerfField(paper_mlp(depth=2, width=16, view_width=8, view_dependence=False))
    assert field.view.in_features == 16  # the feature alone
    x = torch.rand(10, 3)
    d1 = nn.functional.normalize(torch.randn(10, 3), dim=-1)
    d2 = -d1
    with torch.no_grad():
        a, b, c = field(x, d1), field(x, d2), field(x, None)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1]) and torch.equal(a[0], c[0])


def test_view_dependent_uses_directions():
    torch.manual_seed(0)
    field = NerfField(TINY)
    x = torch.rand(10, 3)
    d = nn.functional.normalize(torch.randn(10, 3), dim=-1)
    with torch.no_grad():
        (rgb1, sigma1), (rgb2, sigma2) = field(x, d), field(x, -d)
    assert torch.equal(sigma1, sigma2)  # density depends on x only (Section 3)
    assert not torch.equal(rgb1, rgb2)


def test_view_dependent_needs_directions():
    with pytest.raises(ValueError):
        NerfField(TINY)(torch.zeros(2, 3))


def test_no_positional_encoding_uses_raw_xyz():
    field = NerfField(paper_mlp(depth=2, width=8, view_width=4, skip_after=1, pos_freqs=0, dir_freqs=0))
    # raw x (3) in; skip concatenates x again: 8 + 3; the view branch gets the raw d: 8 + 3.
    assert shapes(field) == [(3, 8), (11, 8), (8, 1), (8, 8), (11, 4), (4, 3)]
    rgb, sigma = field(torch.rand(5, 3), torch.rand(5, 3))
    assert rgb.shape == (5, 3) and sigma.shape == (5,)


def test_include_input_widens_the_first_layer():
    config = paper_mlp(depth=1, width=8, view_width=4, pos_freqs=2, dir_freqs=1, include_input=True)
    field = NerfField(config)
    # 3 * (2 * 2 + 1) = 15 and 3 * (2 * 1 + 1) = 9
    assert field.trunk[0].in_features == 15
    assert field.view.in_features == 8 + 9


def test_query_density_equals_forward_sigma():
    torch.manual_seed(0)
    field = NerfField(TINY)
    x, d = torch.rand(7, 3), torch.rand(7, 3)
    with torch.no_grad():
        assert torch.equal(field.query_density(x), field(x, d)[1])


def test_softplus_density_is_positive_and_shifted():
    field = NerfField(paper_mlp(depth=1, width=4, view_width=4, density_activation="softplus"))
    # softplus(raw - 1): raw 1 -> ln 2, raw -> -inf -> 0 but positive.
    raw = torch.tensor([1.0, -30.0, 5.0])
    out = field.density_activation(raw)
    assert out[0].item() == pytest.approx(torch.log(torch.tensor(2.0)).item(), rel=1e-6)
    assert (out > 0).all()
    relu_field = NerfField(paper_mlp(depth=1, width=4, view_width=4))
    assert torch.equal(relu_field.density_activation(raw), torch.tensor([1.0, 0.0, 5.0]))


def test_density_noise_only_when_asked():
    torch.manual_seed(0)
    field = NerfField(TINY)
    x, d = torch.rand(50, 3), torch.rand(50, 3)
    with torch.no_grad():
        clean1, clean2 = field(x, d)[1], field(x, d, density_noise=0.0)[1]
        noisy = field(x, d, density_noise=10.0)[1]
    assert torch.equal(clean1, clean2)
    assert not torch.equal(clean1, noisy)
    assert (noisy >= 0).all()


def test_field_gradients_reach_every_parameter():
    torch.manual_seed(0)
    field = NerfField(paper_mlp(depth=2, width=16, view_width=8, skip_after=1, density_activation="softplus"))
    rgb, sigma = field(torch.rand(32, 3) * 2 - 1, nn.functional.normalize(torch.randn(32, 3), dim=-1))
    (rgb.sum() + sigma.sum()).backward()
    for name, param in field.named_parameters():
        assert param.grad is not None, name
        assert torch.isfinite(param.grad).all(), name
        assert param.grad.abs().sum() > 0, name
