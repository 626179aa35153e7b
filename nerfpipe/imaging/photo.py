"""What decoding a photo takes and gives: how a RAW is developed (``RawOptions``), the sizes refused
(``SizeLimits``, ``check_size``) and the decoded photo (``DecodedPhoto``). Shared by ``decode`` and ``raw``,
which import it and not each other's."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from nerfpipe.imaging.exif import ExifSummary
from nerfpipe.pipeline.errors import BadPhotoError

# RawOptions.highlight_mode names to rawpy.HighlightMode members (LibRaw's -H 0, 1, 2, 5).
HIGHLIGHT_MODES = {"clip": "Clip", "ignore": "Ignore", "blend": "Blend", "reconstruct": "ReconstructDefault"}
_WHITE_BALANCES = ("camera", "auto", "daylight")


@dataclass(frozen=True)
class RawOptions:
    """How LibRaw develops a camera RAW file.

    ``linear``: gamma 1 and no auto-brightening, so pixel values stay proportional to scene radiance (for HDR
    and exposure-aware training); otherwise the sRGB-like gamma (2.222, 4.5) and LibRaw's auto-brightening.
    ``highlight_mode``: what to do with clipped highlights, one of ``clip``, ``ignore``, ``blend``,
    ``reconstruct``. ``white_balance``: ``camera`` (as shot), ``auto`` (gray world over the image) or
    ``daylight`` (the camera's daylight multipliers, the same for every photo of a capture).
    """

    linear: bool = False
    highlight_mode: str = "clip"
    white_balance: str = "camera"

    def __post_init__(self) -> None:
        if self.highlight_mode not in HIGHLIGHT_MODES:
            raise ValueError(
                f"highlight_mode must be one of {', '.join(HIGHLIGHT_MODES)}, got {self.highlight_mode!r}"
            )
        if self.white_balance not in _WHITE_BALANCES:
            raise ValueError(
                f"white_balance must be one of {', '.join(_WHITE_BALANCES)}, got {self.white_balance!r}"
            )


@dataclass(frozen=True)
class SizeLimits:
    """Photos ``read_photo`` refuses from their header, before decoding a pixel.

    ``min_side``: the shorter side must be at least this (a thumbnail or a 1x1 placeholder gives SfM nothing).
    ``max_pixels``: at most this many pixels, so a small file that claims a huge image (a decompression bomb)
    cannot take gigabytes of memory; 0 means no limit. Pillow warns above 89.5 MP and refuses above 179 MP;
    photos from today's cameras and phones reach 200 MP, so the limit is the caller's to choose.
    """

    min_side: int = 0
    max_pixels: int = 0


class PhotoSizeError(BadPhotoError):
    """A photo outside ``SizeLimits``: ``too`` is ``"small"`` or ``"large"``, ``size`` its (width, height)."""

    def __init__(self, path: Path, size: tuple[int, int], too: Literal["small", "large"], advice: str = "") -> None:
        self.size, self.too = size, too
        width, height = size
        if too == "small":
            problem = f"is only {width}x{height} pixels"
        else:
            problem = f"is {width}x{height} pixels ({width * height / 1e6:.0f} megapixels)"
        super().__init__(path, problem, advice)


def check_size(path: Path, size: tuple[int, int], limits: SizeLimits) -> None:
    """Raise ``PhotoSizeError`` when a photo of ``size`` (width, height) is outside ``limits``."""
    width, height = size
    if limits.min_side and min(width, height) < limits.min_side:
        raise PhotoSizeError(path, size, "small")
    if limits.max_pixels and width * height > limits.max_pixels:
        raise PhotoSizeError(path, size, "large")


@dataclass
class DecodedPhoto:
    """One decoded photo.

    ``pixels``: (H, W, 3) RGB or (H, W, 4) RGBA, uint8 (``bit_depth`` 8) or uint16 (``bit_depth`` 16), already
    upright: the EXIF orientation is applied for JPEG/PNG/TIFF, and LibRaw applies a RAW's own flip.
    ``exif`` is the metadata as stored in the file (its ``orientation`` says what was applied, not what is left
    to do). ``linear`` is True only for RAW developed with ``RawOptions(linear=True)``. ``source_size`` is
    (width, height) of ``pixels``, i.e. after orientation.
    """

    pixels: np.ndarray
    bit_depth: int
    has_alpha: bool
    exif: ExifSummary
    is_raw: bool
    linear: bool
    source_size: tuple[int, int]
