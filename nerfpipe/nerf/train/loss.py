"""The loss of a training step: Eq. 6's squared error of every rendering the sampler made (coarse and fine),
as a mean over the batch's rays, plus mip-NeRF 360's distortion where asked for. One function, whichever way
the step runs (eagerly, or compiled at fixed shapes with padded rays that count for nothing)."""

from __future__ import annotations

from torch import Tensor

from nerfpipe.nerf.render.volume import RenderOutput


def step_loss(out: RenderOutput, target: Tensor, share: Tensor, weight: Tensor | None,
              distortion: float) -> tuple[Tensor, Tensor, Tensor]:
    """Eq. 6 over ``out``'s passes, each ray's squared error averaged over its channels and weighted by its
    ``share`` of the batch; ``distortion`` times the distortion's mean over the rays (0: none).

    Args:
        out: R rays' rendering; target: (R, 3); share: (R,) 1 / (the batch's rays) on each ray of the batch, 0 on
            a ray that only pads it; weight: (R,) each ray's loss weight (drawn by the error map: its
            uniform probability over its own), or None for 1.
    Returns:
        (the loss, the last pass's weighted mean squared error, whose PSNR the log reports, and its squared
        error per ray (R,) unweighted, which the error map records).
    """
    scale = share if weight is None else share * weight
    per_ray = [((o.rgb - target) ** 2).mean(-1) for o in out.passes()]  # (R,) each
    losses = [(scale * e).sum() for e in per_ray]
    loss = sum(losses[1:], losses[0])
    if distortion > 0:
        measured = [(share * d).sum() for d in (o.distortion() for o in out.passes()) if d is not None]
        if measured:
            loss = loss + distortion * sum(measured[1:], measured[0])
    return loss, losses[-1], per_ray[-1]
