"""Camera RAW developed with rawpy (LibRaw): linear or sRGB, the camera's or a set white balance, highlights
clipped or rebuilt, refused when LibRaw cannot read it or it is over the size limits."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np

from nerfpipe.imaging.exif import ExifSummary
from nerfpipe.imaging.photo import HIGHLIGHT_MODES, DecodedPhoto, RawOptions, SizeLimits, check_size
from nerfpipe.pipeline.errors import BadPhotoError


def develop_raw(path: Path, data: bytes, exif: ExifSummary, options: RawOptions, limits: SizeLimits) -> DecodedPhoto:
    """Develop a camera RAW with LibRaw into (H, W, 3) uint16 sRGB; LibRaw applies the RAW's own flip."""
    # rawpy loads LibRaw (a large native library); only pay for it when a RAW file shows up.
    import rawpy

    try:
        with rawpy.imread(io.BytesIO(data)) as raw_image:
            check_size(path, (raw_image.sizes.width, raw_image.sizes.height), limits)
            pixels = raw_image.postprocess(**postprocess_args(rawpy, options))
    except (rawpy.LibRawError, rawpy.NotSupportedError) as err:
        raise BadPhotoError(
            path,
            f"cannot be decoded by LibRaw ({type(err).__name__}: {libraw_message(err)})",
            "check that it opens in the camera maker's software; if it does, convert it to DNG "
            "(Adobe DNG Converter) or export a 16-bit TIFF",
        ) from err
    if pixels.ndim == 2:
        # Monochrome sensors come out with one channel.
        pixels = np.repeat(pixels[:, :, np.newaxis], 3, axis=2)
    pixels = np.ascontiguousarray(pixels, dtype=np.uint16)
    return DecodedPhoto(
        pixels=pixels,
        bit_depth=16,
        has_alpha=False,
        exif=exif,
        is_raw=True,
        linear=options.linear,
        source_size=(pixels.shape[1], pixels.shape[0]),
    )


def postprocess_args(rawpy: Any, options: RawOptions) -> dict[str, Any]:
    """Keyword arguments of ``rawpy.RawPy.postprocess`` for ``options`` (rawpy passed in: it is imported late)."""
    args: dict[str, Any] = {
        "output_bps": 16,
        "output_color": rawpy.ColorSpace.sRGB,
        "highlight_mode": getattr(rawpy.HighlightMode, HIGHLIGHT_MODES[options.highlight_mode]),
        # Neither flag set means LibRaw's daylight multipliers.
        "use_camera_wb": options.white_balance == "camera",
        "use_auto_wb": options.white_balance == "auto",
    }
    if options.linear:
        args["gamma"] = (1.0, 1.0)
        args["no_auto_bright"] = True
    return args


def libraw_message(err: Exception) -> str:
    """LibRaw's error text (rawpy passes it as bytes)."""
    message = err.args[0] if err.args else ""
    if isinstance(message, bytes):
        message = message.decode("utf-8", errors="replace")
    return str(message) or "no details"
