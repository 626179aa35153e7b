"""Which training pixels a step draws its rays from: uniformly, or in proportion to where the field is still
wrong (Instant-NGP's error map, ``sample_image_proportional_to_error``).

``ErrorMap`` remembers the squared error of the rays drawn from each tile of ``TILE`` x ``TILE`` pixels of each
training photo and draws tiles in proportion to it, mixed with uniform draws, then a pixel uniformly within the
tile. Each ray's share of the loss is weighted by the ratio of its probability under uniform draws to its
probability here (importance sampling), so the loss is still, in expectation, the mean squared error over every
training pixel (Eq. 6): what changes is where its samples come from, more of them where the error is large, and
so the variance of the gradient for the same number of rays.

Pixels are stored image after image, row after row (``ImageLoader.pixel_set``), so a tile and a pixel within it
give the pixel's index by arithmetic, without sorting the tens of millions of training pixels.
"""

from __future__ import annotations

import torch
from torch import Tensor

TILE = 16  # pixels a side of a tile of the error map (Instant-NGP's error map: 128 x 128 cells an image)
UNIFORM_SHARE = 0.5  # of the draws, uniform over the pixels whatever the error, so that no tile starves
EMA = 0.5  # a tile's error moves this far towards each new measurement of it
# Tiles are drawn in proportion to their mean squared error to this power. The variance of an importance-sampled
# gradient is least at 0.5 (each pixel drawn in proportion to its residual |C - c|), but at equal time the cup scored
# 25.54 dB at 0.5 and 25.66-25.76 at 1 (25.23-25.37 drawn uniformly); beer lost either way (docs/benchmarks.md).
FOCUS = 1.0
DRAWS = ("rays drawn half uniformly, half in proportion to each 16-pixel tile's recent error (Instant-NGP's error "
         "map), each ray's loss weighted to keep the loss unbiased")  # the train log's line


class ErrorMap:
    """Error-proportional draws over the training pixels of images of ``sizes`` (I, 2) (width, height), stored
    image after image, row-major (P = sum w h pixels).

    State: ``error`` (T,) float32, the last measured mean squared error of each tile's rays (a running mean with
    ``EMA``), -1 for a tile never drawn; a tile never drawn counts at the largest error known, so the first draws
    sweep the photos.
    """

    def __init__(self, sizes: Tensor, tile: int = TILE, uniform_share: float = UNIFORM_SHARE) -> None:
        sizes = sizes.long().cpu()
        if sizes.ndim != 2 or sizes.shape[1] != 2 or not bool((sizes > 0).all()):
            raise ValueError(f"image sizes must be (I, 2) positive widths and heights, got {tuple(sizes.shape)}")
        self.uniform_share = float(uniform_share)
        width, height = sizes[:, 0], sizes[:, 1]
        across, down = (width + tile - 1) // tile, (height + tile - 1) // tile
        per_image = across * down
        first_pixel = torch.cumsum(width * height, 0) - width * height
        image = torch.repeat_interleave(torch.arange(len(sizes)), per_image)  # (T,)
        local = torch.arange(int(per_image.sum())) - (torch.cumsum(per_image, 0) - per_image)[image]
        ty, tx = local // across[image], local % across[image]
        self.x0, self.y0 = tx * tile, ty * tile
        self.cols = torch.minimum(width[image] - self.x0, torch.tensor(tile))
        self.rows = torch.minimum(height[image] - self.y0, torch.tensor(tile))
        self.row_start = first_pixel[image] + self.y0 * width[image] + self.x0  # index of the tile's first pixel
        self.width = width[image]
        self.pixels = (self.cols * self.rows).double()  # (T,)
        self.total = float(width.mul(height).sum())
        self.error = torch.full((len(image),), -1.0)

    def __len__(self) -> int:
        return self.error.shape[0]

    def to(self, device: torch.device | str) -> "ErrorMap":
        for name in ("x0", "y0", "cols", "rows", "row_start", "width", "pixels", "error"):
            setattr(self, name, getattr(self, name).to(device))
        return self

    def probabilities(self) -> Tensor:
        """(T,) float64 probability of drawing each tile: ``uniform_share`` by its pixels, the rest by its pixels
        times its error (a tile never drawn at the largest error known; all at 1 before any is known)."""
        seen = self.error >= 0
        top = float(self.error.max()) if bool(seen.any()) else 1.0
        error = torch.where(seen, self.error, torch.full_like(self.error, top)).double().clamp_min(0.0)
        uniform = self.pixels / self.total
        weighted = self.pixels * error ** FOCUS
        mass = float(weighted.sum())
        if not mass > 0:
            return uniform
        return self.uniform_share * uniform + (1.0 - self.uniform_share) * weighted / mass

    def draw(self, count: int, generator: torch.Generator) -> tuple[Tensor, Tensor, Tensor]:
        """``count`` pixel indices (int64), their tiles, and each ray's loss weight (float32): its probability
        under uniform draws over its probability here, so that a weighted mean of squared errors is unbiased."""
        p = self.probabilities()
        tiles = torch.multinomial(p, count, replacement=True, generator=generator)
        u = torch.rand((count, 2), generator=generator, device=self.error.device, dtype=torch.float64)
        dx = (u[:, 0] * self.cols[tiles]).long().clamp_max(self.cols[tiles] - 1)
        dy = (u[:, 1] * self.rows[tiles]).long().clamp_max(self.rows[tiles] - 1)
        index = self.row_start[tiles] + dy * self.width[tiles] + dx
        weight = (self.pixels[tiles] / (self.total * p[tiles])).float()
        return index, tiles, weight

    def record(self, tiles: Tensor, squared_error: Tensor) -> None:
        """Fold the squared errors (R,) of rays drawn from ``tiles`` (R,) into their tiles' error: each tile's
        mean over this batch, taken whole where the tile was never measured, else a step of ``EMA`` towards it."""
        error = squared_error.detach().float().to(self.error.device)
        sums = torch.zeros_like(self.error).index_add_(0, tiles, error)
        counts = torch.bincount(tiles, minlength=len(self)).to(self.error.dtype)
        hit = counts > 0
        mean = sums[hit] / counts[hit]
        old = self.error[hit]
        self.error[hit] = torch.where(old < 0, mean, old + EMA * (mean - old))

    def state_dict(self) -> dict[str, Tensor]:
        return {"error": self.error.clone()}

    def load_state_dict(self, state: dict[str, Tensor]) -> None:
        error = state["error"]
        if error.shape != self.error.shape:
            raise ValueError(f"an error map of {error.shape[0]} tiles does not fit these photos' {len(self)}")
        self.error.copy_(error.to(self.error.device))


def image_sizes(image: Tensor, uv: Tensor, images: int) -> Tensor:
    """(I, 2) width and height of each training image, from its pixels' image index (P,) and centres (P, 2)
    (the largest centre plus half a pixel)."""
    top = torch.zeros((images, 2), dtype=uv.dtype, device=uv.device)
    top = top.scatter_reduce(0, image.unsqueeze(-1).expand(-1, 2), uv, reduce="amax")
    return (top + 0.5).round().long()
