"""Colour models and Pillow's word on a photo: a TIFF's colour model made true (CMYK converted, a 4th channel
that is no alpha dropped, a model neither decoder converts refused), and Pillow's warnings as log lines that
name the photo."""

from __future__ import annotations

import contextlib
import io
import logging
import threading
import warnings
from pathlib import Path
from typing import Iterator

import numpy as np

from nerfpipe.pipeline.errors import BadPhotoError

log = logging.getLogger("nerfpipe")


@contextlib.contextmanager
def pillow_warnings(path: Path | None) -> Iterator[None]:
    """Pillow's warnings (corrupt EXIF, truncated metadata) as log lines naming the photo, not as Python warnings
    that name a file inside Pillow. ``warnings.catch_warnings`` is process-wide: ingest's threads take turns."""
    with _PILLOW_LOCK, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    for warning in caught:
        log.warning("%s: %s", path if path is not None else "a photo", warning.message)


_PILLOW_LOCK = threading.Lock()


# Pillow's modes of a TIFF whose 4th channel is alpha (ExtraSamples 1 or 2), and those OpenCV decodes as they are
_TIFF_ALPHA_MODES = frozenset({"RGBA", "RGBa", "LA", "La", "PA"})
_TIFF_PLAIN_MODES = frozenset({"1", "L", "P", "RGB", "RGBX", "YCbCr", "I", "I;16", "I;16B", "I;16L", "I;16N", "F",
                               *_TIFF_ALPHA_MODES})


def tiff_colour_model(path: Path, data: bytes, stored: np.ndarray) -> np.ndarray:
    """OpenCV's decoding of a TIFF, made true to its colour model (its header, read by Pillow): CMYK converted
    to RGB (OpenCV passes it as BGR plus a constant 255 that reads as alpha), a 4th channel that is no alpha
    (RGBX) dropped, and a model neither converts (CIE Lab, ...) refused rather than shown in false colours."""
    from PIL import Image

    try:
        with pillow_warnings(path), Image.open(io.BytesIO(data)) as image:
            mode = image.mode
            if mode == "CMYK":
                rgb = np.asarray(image.convert("RGB"))
                return np.ascontiguousarray(rgb[:, :, ::-1])  # as OpenCV's BGR
    except (OSError, ValueError):  # a TIFF Pillow cannot parse but OpenCV decoded: as OpenCV has it
        return stored
    if mode not in _TIFF_PLAIN_MODES:
        raise BadPhotoError(path, f"is a TIFF in the {mode} colour model", "export it as RGB (8 or 16 bits)")
    if stored.ndim == 3 and stored.shape[2] == 4 and mode not in _TIFF_ALPHA_MODES:
        return np.ascontiguousarray(stored[:, :, :3])
    return stored


def to_rgb(path: Path, stored: np.ndarray) -> np.ndarray:
    """OpenCV's (H, W), (H, W, 2/3/4) BGR(A) array as (H, W, 3) RGB or (H, W, 4) RGBA, uint8 or uint16.

    Float samples (HDR / scientific TIFF) are clipped to [0, 1] and stored as uint16, so every consumer deals
    with two dtypes only.
    """
    if stored.dtype.kind == "f":
        brightest = float(np.nanmax(stored)) if stored.size else 0.0
        if brightest > 1.0:
            clipped = float(np.mean(stored > 1.0))
            log.warning("%s: float samples up to %.3g, above 1.0 (HDR): %.1f %% of them clipped to white; tone-map "
                        "it to [0, 1] first to keep its highlights", path, brightest, 100 * clipped)
        stored = np.round(np.clip(np.nan_to_num(stored, nan=0.0), 0.0, 1.0) * 65535.0).astype(np.uint16)
    elif stored.dtype not in (np.uint8, np.uint16):
        raise BadPhotoError(
            path,
            f"has an unsupported sample format ({stored.dtype})",
            "export it as an 8- or 16-bit unsigned integer or a float image",
        )
    if stored.ndim == 2:
        stored = stored[:, :, np.newaxis]
    channels = stored.shape[2]
    if channels == 1:
        return np.ascontiguousarray(np.repeat(stored, 3, axis=2))
    if channels == 2:
        gray, alpha = stored[:, :, :1], stored[:, :, 1:]
        return np.ascontiguousarray(np.concatenate([gray, gray, gray, alpha], axis=2))
    if channels == 3:
        return np.ascontiguousarray(stored[:, :, ::-1])
    if channels == 4:
        return np.ascontiguousarray(stored[:, :, [2, 1, 0, 3]])
    raise BadPhotoError(path, f"has {channels} channels", "export it as an RGB or RGBA image (3 or 4 channels)")
