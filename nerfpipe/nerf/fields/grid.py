"""A fast radiance field: multiresolution dense feature grids and a small MLP, in plain PyTorch.

The field of Instant-NGP (Mueller et al. 2022, Sections 3-4) with its hash tables replaced by dense
grids: at the resolutions a CPU can train (up to 128^3), a dense grid is a hash table without collisions.
Each level holds ``features`` values per grid vertex, trilinearly interpolated; the levels' features go
through a one-layer density MLP (density = exp of its first output, Instant-NGP's activation), whose other
outputs and the viewing direction go through a two-layer colour MLP: d itself by default, or Eq. 4 of the
NeRF paper with L = ``dir_freqs`` > 0, whose sines let the colour of sparse photos fit each photo's own
direction (the temple's 14, 22 degrees apart: 1.9 dB lower held out at L = 4). So it answers the same
question as ``NerfField`` -- (x, d) -> (c, sigma), Section 3 -- with the MLP's work moved into memory.

Memory layout: each level is a (vertices, features) table, channels last, so one trilinear corner is one
contiguous row. On the CPU the native kernels of ``nerfpipe.nerf.native`` make each point's corners and sum their
rows in one pass, and make them again to scatter the gradient (``_NativeGrid``; on beer's samples 0.41 ms forward and
1.5 ms backward where torch's operators took 1.6 and 3.1: ``scripts/bench_grid_kernels.py``). Elsewhere, and where the points train: ``F.embedding_bag`` over each point's
corners (gather and weighted sum in one pass: 2x faster than a gather and an ``einsum`` on the CPU), the backward pass
a scatter-add of rows (``_Trilinear``: the native ``scatter_bags`` on the CPU, else ``index_add_``);
``F.grid_sample``'s channels-first volumes measured 4-5x slower here, forward and backward.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from nerfpipe.nerf import native
from nerfpipe.nerf.fields.configs import GridConfig
from nerfpipe.nerf.fields.encoding import encoded_size, positional_encoding

Box = tuple[tuple[float, ...], tuple[float, ...]]
MAX_LOG_DENSITY = 15.0  # exp(15) = 3.3e6: opaque within 1e-6 of any step, and no overflow


def add_corners_(table_grad: Tensor, bags: Tensor, weights: Tensor, grad: Tensor) -> None:
    """table_grad[bags[i, c]] += weights[i, c] grad[i] for (N, C) bags and weights and (N, F) grad: the native
    ``scatter_bags`` where it runs, else the products and ``index_add_``."""
    if not native.scatter_bags(table_grad, bags, weights, grad):
        contributions = (grad.unsqueeze(1) * weights.to(grad.dtype).unsqueeze(-1)).reshape(-1, grad.shape[-1])
        table_grad.index_add_(0, bags.reshape(-1), contributions)


class _Trilinear(torch.autograd.Function):
    """sum_c w_c table[index_c]: forward by ``F.embedding_bag`` (each point's corners one weighted bag, the gather
    and the weighted sum in one pass), backward by row scatter-adds into the table's gradient (the native
    kernel where it runs, else ``index_add_``; and by row gathers into the weights', when the points themselves
    train)."""

    @staticmethod
    def forward(ctx, table: Tensor, index: Tensor, weights: Tensor) -> Tensor:  # (V, F), (L, C, M) x 2 -> (M, L, F)
        levels, corners, m = index.shape
        bags = index.permute(2, 0, 1).reshape(-1, corners)  # (M L, C): point-major, as the output is
        bag_weights = weights.permute(2, 0, 1).reshape(-1, corners).to(table.dtype)
        ctx.rows = table.shape[0]
        # the points train too (camera refinement): d out / d w_c = table[index_c], gathered again in backward
        ctx.save_for_backward(bags, bag_weights, table if ctx.needs_input_grad[2] else None)
        ctx.shape, ctx.weights_dtype = (levels, corners, m), weights.dtype
        out = F.embedding_bag(bags, table, per_sample_weights=bag_weights, mode="sum")
        return out.view(m, levels, table.shape[1])

    @staticmethod
    def backward(ctx, grad: Tensor):  # (M, L, F)
        bags, bag_weights, table = ctx.saved_tensors
        levels, corners, m = ctx.shape
        per_bag = grad.reshape(-1, 1, grad.shape[-1])  # (M L, 1, F)
        table_grad = torch.zeros((ctx.rows, grad.shape[-1]), dtype=grad.dtype, device=grad.device)
        add_corners_(table_grad, bags, bag_weights, per_bag.view(-1, grad.shape[-1]))
        weights_grad = None
        if ctx.needs_input_grad[2]:
            rows = table.index_select(0, bags.reshape(-1)).view(*bags.shape, table.shape[1]).to(grad.dtype)  # (M L, C, F)
            weights_grad = (rows * per_bag).sum(-1).view(m, levels, corners).permute(1, 2, 0).to(ctx.weights_dtype)
        return table_grad, None, weights_grad


class _Refused(Exception):
    """The native grid kernels declined these inputs (see ``nerfpipe.nerf.native.grid_gather``)."""


class _NativeGrid(torch.autograd.Function):
    """A grid field's features of points x in the native kernels: forward makes each point's corners and sums them
    (``native.grid_gather``), backward makes them again and scatters into the table's gradient
    (``native.grid_scatter``), so nothing of points x levels x 8 is made or kept. The points take no gradient (a
    field whose points train, under camera refinement, goes through ``_Trilinear``)."""

    @staticmethod
    def forward(ctx, table: Tensor, x: Tensor, lo: Tensor, hi: Tensor, resolutions: Tensor,  # (V, F), (M, 3)
                offsets: Tensor, sizes: Tensor, corners: Any) -> tuple[Tensor, Tensor]:  # -> (M, L, F), (M,)
        fused = native.grid_gather(table, x, lo, hi, resolutions, offsets, sizes)
        if fused is None:
            raise _Refused
        ctx.save_for_backward(x, lo, hi, resolutions, offsets, sizes)
        ctx.rows, ctx.corners = table.shape[0], corners
        ctx.mark_non_differentiable(fused[1])
        return fused

    @staticmethod
    def backward(ctx, grad: Tensor, _inside: Tensor | None):  # (M, L, F)
        x, lo, hi, resolutions, offsets, sizes = ctx.saved_tensors
        table_grad = torch.zeros((ctx.rows, grad.shape[-1]), dtype=grad.dtype, device=grad.device)
        if not native.grid_scatter(table_grad, x, lo, hi, resolutions, offsets, grad, sizes):
            index, weights = ctx.corners((x - lo) / (hi - lo))  # (L, 8, M): the field's own corners
            add_corners_(table_grad, index.permute(2, 0, 1).reshape(-1, 8), weights.permute(2, 0, 1).reshape(-1, 8),
                         grad.reshape(-1, grad.shape[-1]))  # point-major, as grad is
        return table_grad, None, None, None, None, None, None, None


def natively_cornered(field: Any) -> bool:
    """Whether the native kernels make ``field``'s corners: a field class says so by naming its own ``corners`` in
    ``native_corners`` (the dense grid's, and the hash grid's, whose levels the kernels hash where their tables have
    fewer rows than vertices); a subclass that makes them otherwise (planes) inherits a name that is not its own."""
    return getattr(type(field), "native_corners", None) is type(field).corners


def native_features(field: "GridField", x: Tensor) -> tuple[Tensor, Tensor] | None:
    """``field``'s features (M, L, F) of points x (M, 3) and whether each is inside its box, by the native kernels;
    None where they do not serve: a field that makes its corners otherwise (planes), points that train,
    inside ``torch.compile`` (whose own fused kernel serves), no native library, inputs it refuses."""
    if not natively_cornered(field) or x.requires_grad or torch.compiler.is_compiling() or native.library() is None:
        return None
    try:
        return _NativeGrid.apply(field.table, x, field.lo, field.hi, field.resolutions, field.offsets, field.sizes,
                                 field.corners)
    except _Refused:
        return None


def gather_corners(table: Tensor, index: Tensor, weights: Tensor) -> Tensor:
    """sum_c weights_c table[index_c] of each point: (V, F) table, (L, C, M) rows and weights -> (M, L, F).

    Eagerly ``_Trilinear`` (``F.embedding_bag`` and row scatter-adds: the fastest pair on a CPU). Inside
    ``torch.compile`` the same sum as plain indexing, which the compiler fuses into one gather-and-sum kernel
    whose backward is atomic adds into the table's gradient (Instant-NGP's encoding kernel), where the
    ``autograd.Function`` would split the graph. The sum over the corners is written out term by term: as a
    reduction (``sum`` over a corner axis) inductor's C++ code opens a parallel region for each point's 8 corners,
    30 times slower than the eager pair on this project's CPU; term by term it is one loop over the points, 1.4x
    faster than the eager pair (docs/benchmarks.md)."""
    if torch.compiler.is_compiling():
        weights = weights.to(table.dtype)
        out = table[index[:, 0]] * weights[:, 0, :, None]  # (L, M, F)
        for corner in range(1, index.shape[1]):
            out = out + table[index[:, corner]] * weights[:, corner, :, None]
        return out.transpose(0, 1).contiguous()  # (M, L, F)
    return _Trilinear.apply(table, index, weights)


def grid_cells(u: Tensor, resolutions: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The cell each of (M, 3) box coordinates u (clamped to [0, 1]) falls in on grids of (L,) ``resolutions``
    cells a side: its lowest vertex (L, 3, M) as integers, the point's fraction across it (L, 3, M), and
    the vertices a side (L, 1)."""
    r = resolutions.to(u.dtype).view(-1, 1, 1)
    p = u.clamp(0.0, 1.0).t().unsqueeze(0) * r  # (L, 3, M)
    i0 = torch.minimum(p.floor(), r - 1)
    return i0.long(), p - i0, (resolutions + 1).view(-1, 1)


def trilinear_corners(u: Tensor, resolutions: Tensor, offsets: Tensor) -> tuple[Tensor, Tensor]:
    """Vertices and weights of trilinear interpolation on grids of several resolutions at once.

    Args:
        u: (M, 3) in [0, 1] (clamped); on a grid of r cells a side, vertex (i, j, k) sits at (i, j, k) / r.
        resolutions: (L,) cells a side of each grid; offsets: (L,) row of each grid's vertex (0, 0, 0) in
            the stacked table, whose grid l holds vertex (i, j, k) at offset_l + (i (r+1) + j) (r+1) + k.
    Returns:
        index: (L, 8, M) rows of the stacked table; weights: (L, 8, M), summing to 1 over the 8 corners
        (corner c = 4 dx + 2 dy + dz). Points run along the last axis, so every step is a long
        contiguous vector operation.
    """
    i0, f, n = grid_cells(u, resolutions)
    base = (i0[:, 0] * n + i0[:, 1]) * n + i0[:, 2] + offsets.view(-1, 1)  # (L, M): corner (0, 0, 0)
    d = CORNERS.to(u.device)
    step = (d[:, 0] * n + d[:, 1]) * n + d[:, 2]  # (L, 8): each corner's row after corner (0, 0, 0)'s
    return base.unsqueeze(1) + step.unsqueeze(-1), corner_weights(f)


CORNERS = torch.tensor([[dx, dy, dz] for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)])  # (8, 3): 4 dx + 2 dy + dz


def corner_weights(f: Tensor) -> Tensor:
    """Trilinear weights (L, 8, M) of the 8 corners (corner c = 4 dx + 2 dy + dz) of points a fraction
    f (L, 3, M) across their cells: products of (1 - f) or f along each axis, by broadcasting (two
    multiplications rather than a loop over the corners)."""
    wx, wy, wz = (torch.stack([1.0 - f[:, a], f[:, a]], dim=1) for a in range(3))  # (L, 2, M) each
    wxy = (wx.unsqueeze(2) * wy.unsqueeze(1)).flatten(1, 2)  # (L, 4, M): 2 dx + dy
    return (wxy.unsqueeze(2) * wz.unsqueeze(1)).flatten(1, 2)


class GridField(nn.Module):
    """(x, d) -> (rgb, sigma) from multiresolution dense grids over the box [lo, hi] and a small MLP.

    Points outside the box have density 0 (the box is the scene: the scene box, or NDC's frustum).
    """

    compiles = True  # rendering evaluates it compiled (``nerfpipe.nerf.kernels``)

    @classmethod
    def from_config(cls, config: GridConfig, box: Box | None) -> "GridField":
        if box is None:
            raise ValueError(f"the {config.kind} field spans a bounded box, and was given none")
        return cls(tuple(box[0]), tuple(box[1]), config)

    def box(self) -> Box:
        return tuple(self.lo.tolist()), tuple(self.hi.tolist())

    def __init__(self, lo: tuple[float, ...], hi: tuple[float, ...], config: GridConfig = GridConfig()) -> None:
        super().__init__()
        self.config = config
        self.register_buffer("lo", torch.tensor(lo, dtype=torch.float32))
        self.register_buffer("hi", torch.tensor(hi, dtype=torch.float32))
        resolutions = config.resolutions()
        sizes = config.level_sizes()
        # every level in one (vertices, features) table: one gather and one scatter for all levels
        self.table = nn.Parameter(torch.empty(sum(sizes), config.features).uniform_(-config.init_scale, config.init_scale))
        self.register_buffer("resolutions", torch.tensor(resolutions), persistent=False)
        self.register_buffer("offsets", torch.tensor([0, *sizes[:-1]]).cumsum(0), persistent=False)
        self.register_buffer("sizes", torch.tensor(sizes), persistent=False)
        width = config.levels * config.features
        hidden = config.width
        self.density_net = nn.Sequential(nn.Linear(width, hidden), nn.ReLU(), nn.Linear(hidden, 1 + config.geo_features))
        dir_dim = encoded_size(config.dir_freqs, True) if config.view_dependence else 0
        self.color_net = nn.Sequential(
            nn.Linear(config.geo_features + dir_dim, hidden), nn.ReLU(),
            nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 3),
        )

    def feature_tables(self) -> list[nn.Parameter]:
        """The parameters that are feature tables (trained at their own rate, ``nerfpipe.nerf.train.trainer``)."""
        return [self.table]

    def encode(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """(M, 3) -> features (M, levels * features) and whether each point is inside the box (M,)."""
        fused = native_features(self, x)
        if fused is not None:
            return self.combine(fused[0]), fused[1]
        u = (x - self.lo) / (self.hi - self.lo)
        inside = ((u >= 0) & (u <= 1)).all(dim=-1)
        index, weights = self.corners(u)
        return self.combine(gather_corners(self.table, index, weights)), inside

    def combine(self, features: Tensor) -> Tensor:
        """(M, L, F) samples of the levels -> (M, L F), what the MLP reads (a field whose corners come in
        other groups than levels combines them here)."""
        return features.flatten(-2)

    def corners(self, u: Tensor) -> tuple[Tensor, Tensor]:
        """Rows and weights of the trilinear corners of (M, 3) box coordinates u on every level (L, 8, M)."""
        return trilinear_corners(u, self.resolutions, self.offsets)

    native_corners = corners  # the native kernels make these corners (``natively_cornered``)

    def _density(self, x: Tensor) -> tuple[Tensor, Tensor]:
        features, inside = self.encode(x)
        h = self.density_net(features)
        raw = h[:, 0].float().clamp(max=MAX_LOG_DENSITY)
        return torch.where(inside, torch.exp(raw), torch.zeros_like(raw)), h[:, 1:]

    def forward(self, x: Tensor, d: Tensor | None = None, density_noise: float = 0.0) -> tuple[Tensor, Tensor]:
        """x: (M, 3) field-space positions; d: (M, 3) unit viewing directions. Returns rgb (M, 3) in (0, 1)
        and sigma (M,) >= 0. ``density_noise`` is accepted for ``NerfField``'s signature and not used: the
        grid's density has no pre-activation that noise regularizes the same way."""
        sigma, geo = self._density(x)
        return self.colour(geo, d), sigma

    def density_features(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """sigma (M,) and the features ``colour`` reads (M, geo_features), of (M, 3) positions."""
        return self._density(x)

    def colour(self, features: Tensor, d: Tensor | None) -> Tensor:
        """rgb (M, 3) in (0, 1) from ``density_features``' features and unit viewing directions d (M, 3)."""
        if self.config.view_dependence:
            if d is None:
                raise ValueError("a view-dependent field needs viewing directions d")
            features = torch.cat([features, positional_encoding(d, self.config.dir_freqs, True).to(features.dtype)], dim=-1)
        return torch.sigmoid(self.color_net(features).float())

    def query_density(self, x: Tensor) -> Tensor:
        """sigma(x) alone: (M, 3) -> (M,)."""
        return self._density(x)[0]
