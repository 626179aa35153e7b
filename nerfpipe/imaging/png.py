"""The pipeline's own images: PNG read and write (8 or 16 bit, RGB, RGBA or one channel) and the sRGB curve.

Both go through bytes (``cv2.imencode`` / ``imdecode``), so any path name works.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nerfpipe.pipeline.errors import StageError


def write_png(path: Path, rgb: np.ndarray) -> None:
    """Write RGB(A) or single-channel pixels as PNG, making the parent folder."""
    import cv2

    if rgb.ndim == 3:
        rgb = cv2.cvtColor(rgb, cv2.COLOR_RGBA2BGRA if rgb.shape[2] == 4 else cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", rgb, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise RuntimeError(f"PNG encoding failed for {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(buf.tobytes())


def read_png(path: Path) -> np.ndarray:
    """RGB(A) or single-channel pixels of a PNG the pipeline wrote, 8 or 16 bit."""
    import cv2

    pixels = cv2.imdecode(np.fromfile(path, np.uint8), cv2.IMREAD_UNCHANGED)
    if pixels is None:
        raise StageError(f"{path}: cannot decode this ingest image; rerun ingest with --force ingest")
    if pixels.ndim == 3:
        pixels = cv2.cvtColor(pixels, cv2.COLOR_BGRA2RGBA if pixels.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return pixels


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1) for previews of linear renders."""
    linear = np.clip(linear, 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """The inverse of ``srgb_encode``: sRGB values in [0, 1] to linear light."""
    encoded = np.clip(encoded, 0.0, 1.0)
    return np.where(encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4)
