"""Positional encoding, Eq. 4 of Section 5.1."""

from __future__ import annotations

import math

import torch
from torch import Tensor


def encoded_size(num_freqs: int, include_input: bool, dims: int = 3) -> int:
    """Width of ``positional_encoding``'s output for ``dims`` input coordinates."""
    return dims * (2 * num_freqs + int(include_input))


def positional_encoding(x: Tensor, num_freqs: int, include_input: bool = False) -> Tensor:
    """gamma(p) = (sin(2^0 pi p), cos(2^0 pi p), ..., sin(2^(L-1) pi p), cos(2^(L-1) pi p)), Eq. 4,
    applied to each coordinate separately; ``include_input`` prepends p itself (the authors' code does,
    Fig. 7 of the paper does not).

    The phase 2^k p is reduced modulo 2 before it is multiplied by pi. Both steps are exact in floating
    point (``fmod`` is exact and 2^k only changes the exponent), so the result equals Eq. 4 for
    every finite input, stays finite and within [-1, 1] for coordinates of any size (where sin(2^k pi p)
    evaluated directly would overflow to inf and give NaN), and is more accurate than the direct form.

    Args:
        x: (..., D) coordinates, normalized to [-1, 1] in the paper.
        num_freqs: L >= 0.
    Returns:
        (..., D * (2 L + include_input)), ordered [p, sin(2^0 pi p), cos(2^0 pi p), sin(2^1 pi p), ...]
        with the D coordinates interleaved inside each term.
    """
    if num_freqs < 0:
        raise ValueError(f"num_freqs must be >= 0, got {num_freqs}")
    parts = [x] if include_input else []
    if num_freqs:
        # fmod, not remainder: remainder(p, 2) = p + 2 for p in (-1, 0) rounds away p's last bit in float32.
        base = torch.fmod(x, 2.0)
        scales = 2.0 ** torch.arange(num_freqs, dtype=x.dtype, device=x.device)
        phase = torch.fmod(base.unsqueeze(-2) * scales.unsqueeze(-1), 2.0) * math.pi  # (..., L, D), in (-2 pi, 2 pi)
        trig = torch.stack([torch.sin(phase), torch.cos(phase)], dim=-2)  # (..., L, 2, D)
        parts.append(trig.reshape(*x.shape[:-1], 2 * num_freqs * x.shape[-1]))
    if not parts:
        return x[..., :0]
    return torch.cat(parts, dim=-1)
