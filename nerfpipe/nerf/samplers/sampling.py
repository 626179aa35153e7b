"""Where along each ray the field is evaluated: stratified sampling (Eq. 2) and hierarchical sampling by
inverse transform sampling from the coarse weights (Section 5.2, Eq. 5)."""

from __future__ import annotations

import torch
from torch import Tensor

DISPARITY_EPS = 1e-6  # the smallest near bound linear-in-disparity sampling will divide by


def stratified_samples(
    near: Tensor,
    far: Tensor,
    num_samples: int,
    perturb: bool = True,
    lindisp: bool = False,
    generator: torch.Generator | None = None,
) -> Tensor:
    """t_i ~ U[t_n + (i-1)/N (t_f - t_n), t_n + i/N (t_f - t_n)], Eq. 2.

    With ``perturb=False`` each sample is the centre of its bin (deterministic rendering). With
    ``lindisp`` the bins are even in disparity 1/t instead of depth (as the authors' code offers for
    scenes whose content spans a large depth range); near is then clamped to ``DISPARITY_EPS``.

    Args:
        near, far: (R,) bounds, far >= near; near == far gives N equal samples.
        num_samples: N >= 1.
    Returns:
        t: (R, N), sorted, inside [near, far].
    """
    if num_samples < 1:
        raise ValueError(f"num_samples must be >= 1, got {num_samples}")
    edges = torch.linspace(0.0, 1.0, num_samples + 1, device=near.device, dtype=near.dtype)
    if perturb:
        u = torch.rand((near.shape[0], num_samples), generator=generator, device=near.device, dtype=near.dtype)
    else:
        u = torch.full((near.shape[0], num_samples), 0.5, device=near.device, dtype=near.dtype)
    s = edges[:-1] + u * (edges[1:] - edges[:-1])  # (R, N) in [0, 1]
    near_, far_ = near.unsqueeze(-1), far.unsqueeze(-1)
    if lindisp:
        inv_near = 1.0 / near_.clamp_min(DISPARITY_EPS)
        inv_far = 1.0 / far_.clamp_min(DISPARITY_EPS)
        t = 1.0 / (inv_near * (1.0 - s) + inv_far * s)
    else:
        t = near_ + (far_ - near_) * s
    return torch.minimum(torch.maximum(t, near_), far_)  # rounding must not step outside the bounds


def sample_intervals(t: Tensor, near: Tensor, far: Tensor) -> Tensor:
    """Edges of the interval each sample stands for: near, the midpoints between samples, far.

    Args:
        t: (R, N) sorted samples; near, far: (R,).
    Returns:
        edges: (R, N + 1); sample i owns [edges_i, edges_{i+1}].
    """
    mids = 0.5 * (t[..., 1:] + t[..., :-1])
    return torch.cat([near.unsqueeze(-1), mids, far.unsqueeze(-1)], dim=-1)


def sample_pdf(
    edges: Tensor,
    weights: Tensor,
    num_samples: int,
    deterministic: bool = False,
    generator: torch.Generator | None = None,
    eps: float = 1e-5,
) -> Tensor:
    """Inverse transform sampling of the piecewise-constant PDF w_hat_i = w_i / sum_j w_j (Section 5.2).

    Bin i spans [edges_i, edges_{i+1}] and has probability w_hat_i. ``eps`` is added to every weight
    (and the PDF renormalized) so a ray whose coarse weights are all zero samples uniformly rather than
    dividing by zero. Differentiable with respect to ``edges`` and ``weights`` for fixed u (the renderer
    detaches the result, as the paper's fine samples carry no gradient to the coarse network).

    Args:
        edges: (R, B + 1) sorted bin edges; weights: (R, B) >= 0.
        num_samples: N_f >= 1.
        deterministic: u evenly spaced (bin centres of [0, 1]) instead of uniform random.
    Returns:
        t: (R, N_f), sorted, inside [edges_0, edges_B].
    """
    weights = weights.clamp_min(0.0) + eps
    pdf = weights / weights.sum(dim=-1, keepdim=True)
    cdf = torch.cumsum(pdf, dim=-1)
    cdf = torch.cat([torch.zeros_like(cdf[..., :1]), cdf], dim=-1)  # (R, B + 1)
    cdf = cdf / cdf[..., -1:].detach()  # exactly 1 at the end, whatever the rounding
    shape = (*cdf.shape[:-1], num_samples)
    if deterministic:
        u = (torch.arange(num_samples, device=cdf.device, dtype=cdf.dtype) + 0.5) / num_samples
        u = u.expand(shape).contiguous()
    else:
        u = torch.rand(shape, generator=generator, device=cdf.device, dtype=cdf.dtype).sort(dim=-1).values
    index = torch.searchsorted(cdf.detach().contiguous(), u, right=True)
    below = (index - 1).clamp(0, cdf.shape[-1] - 2)
    above = below + 1
    cdf_lo, cdf_hi = torch.gather(cdf, -1, below), torch.gather(cdf, -1, above)
    bin_lo, bin_hi = torch.gather(edges, -1, below), torch.gather(edges, -1, above)
    span = cdf_hi - cdf_lo
    frac = ((u - cdf_lo) / torch.where(span > 0, span, torch.ones_like(span))).clamp(0.0, 1.0)
    t = bin_lo + frac * (bin_hi - bin_lo)
    return torch.minimum(torch.maximum(t, edges[..., :1]), edges[..., -1:])
