"""Per-image appearance: each training photo's exposure and white balance, learned with the field.

A camera records linear light times a gain per colour channel (exposure time x ISO / f-number^2 for all
three, white balance for their ratios), clips what saturates and applies its tone curve. So a photo's
appearance is modelled as exactly that: three gains on linear light, clipping at 1, and the sRGB curve
(none for linear RAW), applied to what the field renders. Three numbers per photo cannot explain away
geometry or view-dependent colour, as a free embedding fed to the colour MLP (NeRF-W, nerfacto) can, and
they leave the field's outputs in the units of the photos.

Gauge: the gains of all training photos have a geometric mean of 1 per channel (``ExposureGains.gains``),
so the field renders the training photos' mean appearance, which is what novel views show.
"""

from __future__ import annotations

import kornia
import torch
from torch import Tensor, nn


def apply_gains(rgb: Tensor, gains: Tensor, linear: bool) -> Tensor:
    """The colours a camera with per-channel ``gains`` records of the light the field renders as ``rgb``.

    Args:
        rgb: (R, 3) in [0, 1]: sRGB-encoded, or linear when ``linear`` (RAW).
        gains: (R, 3) or (3,) > 0, multiplying linear light.
    Returns:
        (R, 3) in [0, 1]: clip(gains * decode(rgb), 0, 1), encoded as ``rgb`` is.
    """
    as_image = rgb.reshape(-1, 3, 1, 1)  # kornia's colour functions take (*, 3, H, W)
    light = as_image if linear else kornia.color.rgb_to_linear_rgb(as_image.clamp(0.0, 1.0))
    recorded = (light * gains.reshape(-1, 3, 1, 1)).clamp(0.0, 1.0)
    out = recorded if linear else kornia.color.linear_rgb_to_rgb(recorded)
    return out.reshape(rgb.shape)


class ExposureGains(nn.Module):
    """Per training image, log2 gains (I, 3) on linear light; the photos' known exposure, else zero (gain 1),
    at initialisation."""

    def __init__(self, images: int, linear: bool, stops: list[float] | None = None) -> None:
        """``stops``: each image's exposure in stops where known (the scene analysis measures it from EXIF or
        from the brightness of the same points), where training starts from; else every gain starts at 1."""
        super().__init__()
        self.linear = linear
        self.start_stops = None if stops is None else [float(v) for v in stops]  # where training started (its spec)
        start = torch.zeros(images, 3) if stops is None else torch.tensor(stops, dtype=torch.float32)[:, None].repeat(1, 3)
        self.log2_gains = nn.Parameter(start)

    def gains(self) -> Tensor:
        """(I, 3): 2^(log2 gains - their mean over the images): geometric mean 1 per channel."""
        centred = self.log2_gains - self.log2_gains.mean(dim=0, keepdim=True)
        return torch.exp2(centred)

    def forward(self, rgb: Tensor, image: Tensor) -> Tensor:
        """rgb (R, 3) rendered for rays of training images ``image`` (R,) -> as those photos recorded it."""
        return apply_gains(rgb, self.gains()[image], self.linear)

    def stops(self) -> Tensor:
        """(I, 3) each image's gains in stops (log2), centred as ``gains``: what the report shows."""
        return torch.log2(self.gains()).detach()


def fit_gains(render: Tensor, target: Tensor, linear: bool, iterations: int = 60) -> Tensor:
    """The gains (3,) under which ``render`` (N, 3) best matches ``target`` (N, 3) in squared error: a held-out
    photo's exposure and white balance, fitted on part of it (``nerfpipe.nerf.train.evaluation``). L-BFGS on
    log2 gains from 0; pixels saturated in either image carry no gradient, as they carry no exposure."""
    log2 = torch.zeros(3, dtype=torch.float32, requires_grad=True)
    render, target = render.detach().float(), target.detach().float()
    optimizer = torch.optim.LBFGS([log2], lr=0.5, max_iter=iterations, line_search_fn="strong_wolfe")

    def closure() -> Tensor:
        optimizer.zero_grad()
        loss = ((apply_gains(render, torch.exp2(log2), linear) - target) ** 2).mean()
        loss.backward()
        return loss

    if len(render):
        optimizer.step(closure)
    return torch.exp2(log2.detach())
