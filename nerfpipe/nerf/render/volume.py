"""Volume rendering by alpha compositing, the quadrature of Eq. 3 and the weights of Eq. 5, over packed
samples: every sampler (``nerfpipe.nerf.samplers.base``) says where along the rays to look as ``RaySamples``,
the samples of all rays one after the other with the index of their ray (nerfacc's layout), and
``volume_render`` composites them. Nothing else composites.

Everything runs in float32 (or float64 when given float64), whatever autocast does around it: densities
of 1e10 overflow float16 and bf16 loses the small transmittances that decide the weights.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
from torch import Tensor

MAX_OPTICAL_DEPTH = 1e4  # exp(-1e4) is 0 in float64 too; capping keeps sigma * delta = inf * 0 out of gradients
ACC_EPS = 1e-10  # accumulated opacity below this counts as "the ray hit nothing"


def _float(x: Tensor) -> Tensor:
    return x if x.dtype == torch.float64 else x.float()


def optical_depth(sigmas: Tensor, deltas: Tensor) -> Tensor:
    """sigma_i delta_i, with densities clamped at 0 and the product capped at ``MAX_OPTICAL_DEPTH``.

    Args:
        sigmas, deltas: (...) alike.
    Returns:
        (...).
    """
    return (_float(sigmas).clamp_min(0.0) * _float(deltas)).clamp_max(MAX_OPTICAL_DEPTH)


def interval_stop_depths(sigmas: Tensor, starts: Tensor, ends: Tensor) -> Tensor:
    """Mean stopping depth of a ray that terminates in the interval [start_i, end_i] of constant density
    sigma_i: start + L (1/tau - 1/(e^tau - 1)) with L = end - start, tau = sigma_i L: L/2 where the stretch
    is nearly transparent, 1/sigma_i where it is opaque. Taking a sample's own t instead puts an opaque
    surface anywhere in its stretch at the sample, up to a stretch too deep.

    Args:
        sigmas, starts, ends: (...) alike.
    Returns:
        (...) depths, start_i <= depth_i <= end_i.
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
class RaySamples:
    """N samples of R rays, packed ray after ray in order of depth (nerfacc's layout).

    ray: (N,) int64, the ray of each sample, non-decreasing; t: (N,) the ray parameter the field is
    evaluated at; starts, ends: (N,) the stretch of ray [start, end] the sample stands for (its delta_i of
    Eq. 3 is end - start), t inside it. Stretches of one ray do not overlap; they may leave gaps (empty space
    a sampler skipped). ``spans``: (starts, ends) (N,) of the same stretches in a distance normalized along
    the ray, where the sampler measures one (mip-NeRF 360's s, for ``distortion``), else None. ``known``:
    (sigma (N,), features (N, F)) of the first field at the samples, where the sampler evaluated them
    without gradients (``Field.density_features``), for rendering to reuse, else None.
    """

    ray: Tensor
    t: Tensor
    starts: Tensor
    ends: Tensor
    n_rays: int
    spans: tuple[Tensor, Tensor] | None = None
    known: tuple[Tensor, Tensor] | None = None

    def __len__(self) -> int:
        return self.ray.shape[0]

    @staticmethod
    def dense(t: Tensor, starts: Tensor, ends: Tensor, spans: tuple[Tensor, Tensor] | None = None) -> "RaySamples":
        """The same number of samples on every ray: t, starts, ends (R, K) (and spans)."""
        n_rays, per_ray = t.shape
        ray = torch.arange(n_rays, device=t.device).repeat_interleave(per_ray)
        flat = None if spans is None else (spans[0].reshape(-1), spans[1].reshape(-1))
        return RaySamples(ray, t.reshape(-1), starts.reshape(-1), ends.reshape(-1), n_rays, flat)

    def select(self, index: Tensor) -> "RaySamples":
        """The samples ``index`` picks (a mask (N,), or increasing indices), in their order. A mask becomes indices
        once (each of the six arrays indexed by the mask would scan it again)."""
        if isinstance(index, Tensor) and index.dtype == torch.bool:
            index = index.nonzero().squeeze(-1)
        spans = None if self.spans is None else (self.spans[0][index], self.spans[1][index])
        known = None if self.known is None else (self.known[0][index], self.known[1][index])
        return RaySamples(self.ray[index], self.t[index], self.starts[index], self.ends[index], self.n_rays, spans,
                          known)

    def leading(self, n_rays: int) -> "RaySamples":
        """The samples of the first ``n_rays`` rays (a prefix: samples are packed ray after ray)."""
        end = int(torch.searchsorted(self.ray, torch.tensor([n_rays], device=self.ray.device)).item())
        cut = self.select(slice(0, end))
        return dataclasses.replace(cut, n_rays=n_rays)

    def counts(self) -> Tensor:
        """(R,) samples of each ray."""
        return torch.bincount(self.ray, minlength=self.n_rays)

    def exclusive_sums(self, values: Tensor) -> Tensor:
        """sum_{j before i on i's ray} values_j for each sample i (N,) -> (N,): a cumulative sum over all
        samples in float64 less its value where the ray begins, so that rays of any length cost one pass."""
        wide = values.double()
        before = torch.cumsum(wide, dim=0) - wide
        return (before - before[self.firsts()]).to(_float(values).dtype)

    def firsts(self) -> Tensor:
        """(N,) the index of the first sample of each sample's ray: the largest index at or before it where a ray
        begins. Shapes that depend on N alone (no count per ray), so a compiled step sees fixed shapes."""
        index = torch.arange(len(self), device=self.ray.device)
        begins = torch.ones_like(self.ray, dtype=torch.bool)
        begins[1:] = self.ray[1:] != self.ray[:-1]
        return torch.cummax(torch.where(begins, index, torch.zeros_like(index)), dim=0).values

    def per_ray(self, values: Tensor) -> Tensor:
        """The sum over each ray's samples of ``values`` (N, ...) -> (R, ...)."""
        out = values.new_zeros((self.n_rays, *values.shape[1:]))
        return out.index_add(0, self.ray, values)


@dataclass
class RenderOutput:
    """What rendering rays gives (``volume_render``), the one thing the trainer, evaluation, every export
    and the viewer read.

    rgb: (R, 3) colour; depth: (R,) expected ray parameter at which a ray stops, sum_i w_i z_i / sum_i w_i
    with z_i the mean stopping depth within sample i's stretch (``interval_stop_depths``), ``far`` where
    nothing was hit; acc: (R,) accumulated opacity sum_i w_i; weights: (N,) w_i of Eq. 5 of ``samples``.
    evaluated: field evaluations spent, including a sampler's own passes. earlier: the renderings a sampler
    made on its way to these samples that the loss also fits (Section 5.2's coarse pass, Eq. 6).
    """

    rgb: Tensor
    depth: Tensor
    acc: Tensor
    weights: Tensor
    samples: RaySamples
    evaluated: int = 0
    earlier: tuple["RenderOutput", ...] = ()

    def __len__(self) -> int:
        return self.rgb.shape[0]

    @property
    def disparity(self) -> Tensor:
        """(R,) 1 / depth, 0 where depth is not positive."""
        return self.inverse(self.depth)

    @staticmethod
    def inverse(depth: Tensor) -> Tensor:
        """1 / depth, 0 where depth is not positive: (R,) -> (R,)."""
        positive = depth > 0
        return torch.where(positive, 1.0 / torch.where(positive, depth, torch.ones_like(depth)), torch.zeros_like(depth))

    @staticmethod
    def blend(rgb: Tensor, acc: Tensor, background: Tensor | None) -> Tensor:
        """Porter-Duff "over": rgb (R, 3) with opacity acc (R,) onto ``background`` (3,) or (R, 3) (None: as it is)."""
        if background is None:
            return rgb
        colour = _float(background)
        behind = colour if colour.dim() == 1 else colour[:len(rgb)]
        return rgb + (1.0 - acc).clamp_min(0.0).unsqueeze(-1) * behind.to(rgb.device)

    def passes(self) -> tuple["RenderOutput", ...]:
        """Every rendering the loss fits: the earlier ones, then this one."""
        return (*self.earlier, self)

    def map_rgb(self, fn) -> "RenderOutput":
        """This output with ``fn`` applied to the colour of every pass (``appearance``, ``over``)."""
        return dataclasses.replace(self, rgb=fn(self.rgb, self), earlier=tuple(e.map_rgb(fn) for e in self.earlier))

    def over(self, background: Tensor | None) -> "RenderOutput":
        """Porter-Duff "over" onto ``background`` (3,) or (R, 3): rgb + (1 - acc) background, every pass."""
        if background is None:
            return self
        return self.map_rgb(lambda rgb, out: self.blend(rgb, out.acc, background))

    def distortion(self) -> Tensor | None:
        """(R,) mip-NeRF 360's distortion of the weights over the samples' spans (``distortion``); None
        where the sampler measured no spans."""
        return None if self.samples.spans is None else distortion(self.weights, self.samples)


def volume_render(sigmas: Tensor, colors: Tensor, samples: RaySamples, near: Tensor, far: Tensor,
                  background: Tensor | None = None) -> RenderOutput:
    """C = sum_i T_i (1 - exp(-sigma_i delta_i)) c_i, Eq. 3, over each ray's packed samples, with
    delta_i = end_i - start_i and T_i = exp(-sum_{j<i} sigma_j delta_j); plus (1 - sum_i w_i) times the
    background (Porter-Duff "over" onto a constant colour; None composites onto black, the paper's choice
    for real scenes).

    Args:
        sigmas: (N,) densities; colors: (N, 3); samples: the N samples of R rays; near, far: (R,).
        background: (3,) or (R, 3) colour, or None.
    Returns:
        RenderOutput.
    """
    starts, ends = _float(samples.starts), _float(samples.ends)
    tau = optical_depth(sigmas, (ends - starts).clamp_min(0.0))
    # T_i from the exclusive sum of optical depth, not cumprod(1 - alpha): alpha = 1 - exp(-tau) rounds to 1
    # long before tau stops growing, and the products lose the transmittance behind it
    weights = torch.exp(-samples.exclusive_sums(tau)) * -torch.expm1(-tau)
    acc = samples.per_ray(weights)
    rgb = samples.per_ray(weights.unsqueeze(-1) * _float(colors))
    near, far = _float(near), _float(far)
    hit = acc > ACC_EPS
    stops = samples.per_ray(weights * interval_stop_depths(sigmas, starts, ends))
    depth = torch.where(hit, stops / torch.where(hit, acc, torch.ones_like(acc)), far)
    depth = torch.minimum(torch.maximum(depth, near), torch.maximum(far, near))
    return RenderOutput(rgb, depth, acc, weights, samples).over(background)


def distortion(weights: Tensor, samples: RaySamples) -> Tensor:
    """mip-NeRF 360's distortion loss (Barron et al. 2022, Eq. 15) of each ray's weights over its spans:

        L = sum_i sum_j w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 (e_i - s_i),   m_i = (s_i + e_i) / 2,

    small when a ray's weight sits in one short stretch, large when it is spread out or split (floaters in
    front of a surface). The double sum is computed in O(N) for sorted spans as
    2 sum_i w_i (m_i W_i - S_i), W_i and S_i the sums of w_j and w_j m_j over j < i on the same ray.

    Args:
        weights: (N,); samples: with ``spans``, sorted non-overlapping stretches in a normalized distance
            (mip-NeRF 360's s; here the marching steps' own, in which the steps are of equal length).
    Returns:
        (R,) the loss of each ray.
    """
    s, e = _float(samples.spans[0]), _float(samples.spans[1])
    w = _float(weights)
    mid = 0.5 * (s + e)
    across = 2.0 * samples.per_ray(w * (mid * samples.exclusive_sums(w) - samples.exclusive_sums(w * mid)))
    within = samples.per_ray(w * w * (e - s)) / 3.0
    return across + within
