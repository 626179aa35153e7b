"""Volume rendering by alpha compositing, the quadrature of Eq. 3 and the weights of Eq. 5.

Everything runs in float32 (or float64 when given float64), whatever autocast does around it: densities
of 1e10 overflow float16 and bf16 loses the small transmittances that decide the weights.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

MAX_OPTICAL_DEPTH = 1e4  # exp(-1e4) is 0 in float64 too; capping keeps sigma * delta = inf * 0 out of gradients
ACC_EPS = 1e-10  # accumulated opacity below this counts as "the ray hit nothing"


def _float(x: Tensor) -> Tensor:
    return x if x.dtype == torch.float64 else x.float()


def sample_deltas(t: Tensor, far: Tensor) -> Tensor:
    """delta_i = t_{i+1} - t_i (Eq. 3); the last sample's interval ends at the far bound.

    The authors' code closes the last interval with 1e10 instead, which makes every ray opaque at its end
    and would hide the background the scene analysis asks to composite onto.

    Args:
        t: (R, N) sorted sample depths; far: (R,).
    Returns:
        deltas: (R, N) >= 0.
    """
    t, far = _float(t), _float(far)
    deltas = torch.cat([t[..., 1:] - t[..., :-1], far.unsqueeze(-1) - t[..., -1:]], dim=-1)
    return deltas.clamp_min(0.0)


def optical_depth(sigmas: Tensor, deltas: Tensor) -> Tensor:
    """sigma_i delta_i, with densities clamped at 0 and the product capped at ``MAX_OPTICAL_DEPTH``.

    Args:
        sigmas, deltas: (R, N).
    Returns:
        (R, N).
    """
    return (_float(sigmas).clamp_min(0.0) * _float(deltas)).clamp_max(MAX_OPTICAL_DEPTH)


def alphas_from_density(sigmas: Tensor, deltas: Tensor) -> Tensor:
    """alpha_i = 1 - exp(-sigma_i delta_i) (Section 4), as -expm1 so tiny densities keep their value.

    Args:
        sigmas, deltas: (R, N).
    Returns:
        alphas: (R, N) in [0, 1].
    """
    return -torch.expm1(-optical_depth(sigmas, deltas))


def transmittance(sigmas: Tensor, deltas: Tensor) -> Tensor:
    """T_i = exp(-sum_{j<i} sigma_j delta_j), Eq. 3, from the exclusive cumulative sum of optical depth.

    Args:
        sigmas, deltas: (R, N).
    Returns:
        T: (R, N) in [0, 1], T_1 = 1.
    """
    tau = optical_depth(sigmas, deltas)
    # Shifted, not cumsum(tau) - tau: subtracting a large tau_i (up to the cap) from the running sum
    # loses the small optical depth before it, off by up to half an ulp of 1e4 in float32.
    exclusive = torch.cat([torch.zeros_like(tau[..., :1]), torch.cumsum(tau, dim=-1)[..., :-1]], dim=-1)
    return torch.exp(-exclusive)


def transmittance_from_alphas(alphas: Tensor) -> Tensor:
    """T_i = prod_{j<i} (1 - alpha_j): the same transmittance by cumulative product (the route of the
    authors' code), kept as a second route that tests compare with ``transmittance``.

    Args:
        alphas: (R, N).
    Returns:
        T: (R, N).
    """
    survive = 1.0 - _float(alphas)
    return torch.cat([torch.ones_like(survive[..., :1]), torch.cumprod(survive, dim=-1)[..., :-1]], dim=-1)


def compositing_weights(sigmas: Tensor, deltas: Tensor) -> Tensor:
    """w_i = T_i (1 - exp(-sigma_i delta_i)), Eq. 5.

    Args:
        sigmas, deltas: (R, N).
    Returns:
        weights: (R, N) >= 0 with sum <= 1.
    """
    return transmittance(sigmas, deltas) * alphas_from_density(sigmas, deltas)


def termination_depths(sigmas: Tensor, t: Tensor, far: Tensor) -> Tensor:
    """Where a ray that terminates at sample i stops, on average: the depth ``composite`` weights by w_i.

    Sample i stands for the stretch of ray closer to it than to its neighbours (the midpoint rule), from
    s_i = (t_{i-1} + t_i) / 2 (t_0 for the first) to e_i = (t_i + t_{i+1}) / 2 (``far`` for the last), with
    constant density sigma_i there. A ray stopping in a stretch of length L and optical depth
    tau = sigma_i L stops on average L (1/tau - 1/(e^tau - 1)) past s_i: L/2 where the stretch is nearly
    transparent, 1/sigma_i where it is opaque. Taking t_i itself instead, as the paper's code does, puts an
    opaque surface that lies anywhere before t_i at t_i, up to one sample spacing too deep; this puts it
    within half a spacing of the truth.

    Args:
        sigmas: (R, N) densities; t: (R, N) sorted sample depths; far: (R,).
    Returns:
        (R, N) depths, s_i <= depth_i <= e_i.
    """
    t, far = _float(t), _float(far)
    mid = 0.5 * (t[..., 1:] + t[..., :-1])
    start = torch.cat([t[..., :1], mid], dim=-1)
    end = torch.cat([mid, torch.maximum(far.unsqueeze(-1), t[..., -1:])], dim=-1)
    return interval_stop_depths(sigmas, start, end)


def interval_stop_depths(sigmas: Tensor, starts: Tensor, ends: Tensor) -> Tensor:
    """Mean stopping depth of a ray that terminates in the interval [start_i, end_i] of constant density
    sigma_i: start + L (1/tau - 1/(e^tau - 1)) with L = end - start, tau = sigma_i L (``termination_depths``).

    Args:
        sigmas, starts, ends: (R, N).
    Returns:
        (R, N) depths, start_i <= depth_i <= end_i.
    """
    start, end = _float(starts), _float(ends)
    length = (end - start).clamp_min(0.0)
    # not optical_depth: its cap (1e4) would put an opaque stretch's stop at L / 1e4 rather than 1 / sigma
    tau = _float(sigmas).clamp(0.0, 1e30) * length
    # 1/tau - 1/expm1(tau) loses digits to cancellation for small tau, where its series is 1/2 - tau/12 + tau^3/720;
    # past tau = 30, e^-tau is below float32's resolution of 1/tau and expm1 would overflow (and its gradient)
    small, large = tau < 0.1, tau > 30.0
    moderate = tau.clamp(0.1, 30.0)
    exact = 1.0 / moderate - 1.0 / torch.expm1(moderate)
    series = 0.5 - tau / 12.0 + tau**3 / 720.0
    g = torch.where(small, series, torch.where(large, 1.0 / tau.clamp_min(30.0), exact))
    return start + length * g


@dataclass
class Composite:
    """What compositing one set of samples gives, per ray.

    rgb: (R, 3) colour, composited onto the background; depth: (R,) expected depth sum_i w_i z_i / sum_i w_i
    with z_i the mean stopping depth of sample i's stretch of ray (``termination_depths``; ``far`` where
    nothing was hit); disparity: (R,) 1 / depth (0 where depth is infinite); acc: (R,)
    accumulated opacity sum_i w_i; weights: (R, N); intervals: (R, N) starts and ends of the samples'
    stretches in a normalized distance, where the sampler measured them (``distortion_loss``), else None.
    """

    rgb: Tensor
    depth: Tensor
    disparity: Tensor
    acc: Tensor
    weights: Tensor
    intervals: tuple[Tensor, Tensor] | None = None

    def distortion_loss(self) -> Tensor | None:
        """(R,) mip-NeRF 360's distortion of the weights over ``intervals`` (``distortion``), computed only when
        asked (training with the loss on), None where the sampler gave no intervals."""
        return None if self.intervals is None else distortion(self.weights, *self.intervals)


def composite(
    sigmas: Tensor,
    colors: Tensor,
    t: Tensor,
    far: Tensor,
    background: Tensor | None = None,
    deltas: Tensor | None = None,
    intervals: tuple[Tensor, Tensor] | None = None,
) -> Composite:
    """C = sum_i T_i (1 - exp(-sigma_i delta_i)) c_i, Eq. 3, plus (1 - sum_i w_i) times the background.

    The background term is Porter-Duff "over" onto a constant colour: the scene analysis asks for it when
    the photos have alpha (composited onto the same colour) or a constant-colour backdrop. ``None``
    composites onto black, the paper's choice for real scenes.

    Args:
        sigmas: (R, N) densities; colors: (R, N, 3); t: (R, N) sorted sample depths; far: (R,).
        background: (3,) or (R, 3) colour, or None.
        deltas: (R, N) interval lengths, if not the spacing of ``t`` (``sample_deltas``).
        intervals: (starts, ends), each (R, N): the stretch of ray each sample stands for, when the samples
            do not tile [t_1, far] (marching through an occupancy grid leaves gaps, and pads rays with
            empty intervals, start = end). Sets the deltas and where a ray stopping at a sample stops.
    Returns:
        Composite.
    """
    t = _float(t)
    if intervals is not None:
        starts, ends = _float(intervals[0]), _float(intervals[1])
        deltas = (ends - starts).clamp_min(0.0)
    else:
        deltas = sample_deltas(t, far) if deltas is None else _float(deltas)
    weights = compositing_weights(sigmas, deltas)
    acc = weights.sum(dim=-1)
    rgb = (weights.unsqueeze(-1) * _float(colors)).sum(dim=-2)
    if background is not None:
        rgb = rgb + (1.0 - acc).clamp_min(0.0).unsqueeze(-1) * _float(background).to(rgb.device)
    hit = acc > ACC_EPS
    safe_acc = torch.where(hit, acc, torch.ones_like(acc))
    stops = termination_depths(sigmas, t, far) if intervals is None else interval_stop_depths(sigmas, starts, ends)
    depth = torch.where(hit, (weights * stops).sum(dim=-1) / safe_acc, _float(far).expand_as(acc))
    depth = torch.minimum(torch.maximum(depth, t[..., 0]), torch.maximum(_float(far), t[..., -1]))
    positive = depth > 0
    disparity = torch.where(positive, 1.0 / torch.where(positive, depth, torch.ones_like(depth)), torch.zeros_like(depth))
    return Composite(rgb, depth, disparity, acc, weights)


def distortion(weights: Tensor, starts: Tensor, ends: Tensor) -> Tensor:
    """mip-NeRF 360's distortion loss (Barron et al. 2022, Eq. 15) of each ray's weights over its intervals:

        L = sum_i sum_j w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 (e_i - s_i),   m_i = (s_i + e_i) / 2,

    small when a ray's weight sits in one short stretch, large when it is spread out or split (floaters in
    front of a surface). The double sum is computed in O(N) for sorted intervals as
    2 sum_i w_i (m_i W_i - S_i), W_i and S_i the sums of w_j and w_j m_j over j < i.

    Args:
        weights: (R, N); starts, ends: (R, N) sorted, non-overlapping intervals in a normalized distance
            (mip-NeRF 360's s; here the marching steps' own, in which the steps are of equal length).
    Returns:
        (R,) the loss of each ray.
    """
    w, s, e = _float(weights), _float(starts), _float(ends)
    mid = 0.5 * (s + e)
    before_w = torch.cumsum(w, dim=-1) - w
    before_wm = torch.cumsum(w * mid, dim=-1) - w * mid
    across = 2.0 * (w * (mid * before_w - before_wm)).sum(dim=-1)
    within = (w * w * (e - s)).sum(dim=-1) / 3.0
    return across + within
