"""Frames to video, and depth to colour, for looking at a radiance field.

MP4s go through OpenCV's ``VideoWriter`` with the 'mp4v' (MPEG-4 Part 2) codec: the encoder every
``opencv-*-headless`` wheel carries, with no system ffmpeg or H.264 licence needed; any player opens it.

Depth colour convention (one for every depth picture nerfpipe writes): the value is mapped linearly from
[lo, hi] onto matplotlib's 'turbo' colormap reversed, so near is red and far is blue; values outside
[lo, hi] take the end colours, and pixels the field leaves empty (acc < 0.5) are black. Any quantity that
grows with distance keeps that order: a forward-facing model's NDC depth t' = 1 - near / z (in [0, 1],
linear in disparity) coloured as is over [0, 1] gives a disparity-linear map, the near plane red and
infinity blue.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np

from nerfpipe.pipeline.errors import StageError

# Pixels whose accumulated opacity is below this show no surface: the ray mostly reached the background.
EMPTY_ACC = 0.5


def _even_size(frame: np.ndarray) -> np.ndarray:
    """MPEG-4 encodes whole 2x2 chroma blocks: the encoder silently crops an odd width or height, so an odd
    side is padded with a copy of its last row / column instead, keeping every rendered pixel."""
    h, w = frame.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return frame
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def write_mp4(frames: Iterable[np.ndarray], path: Path, fps: float) -> int:
    """Write RGB frames to an MP4 ('mp4v') at ``fps`` frames per second.

    Args:
        frames: a list or an iterator (so a caller can render and write one frame at a time) of (H, W, 3)
            uint8 RGB, all of one size; an odd H or W is padded by one edge pixel (see ``_even_size``).
        path: the file to write; its folder must exist.
    Returns:
        the number of frames written.
    Raises:
        ValueError: no frames, or a frame of another shape or dtype.
        StageError: OpenCV cannot open a writer at ``path``.
    """
    import cv2

    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    path = Path(path)
    writer = None
    size: tuple[int, ...] = ()
    count = 0
    try:
        for frame in frames:
            frame = np.asarray(frame)
            if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
                raise ValueError(f"frame {count}: expected (H, W, 3) uint8 RGB, got {frame.shape} {frame.dtype}")
            if writer is None:
                size = frame.shape
                padded = _even_size(frame).shape
                writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (padded[1], padded[0]))
                if not writer.isOpened():
                    raise StageError(f"{path}: OpenCV cannot open an MP4 ('mp4v') writer here; check that the folder "
                                     "exists and is writable, and that this OpenCV build has FFMPEG video I/O")
            elif frame.shape != size:
                # VideoWriter drops a frame of another size without a word; refuse it instead
                raise ValueError(f"frame {count} is {frame.shape}, the first frame was {size}")
            writer.write(cv2.cvtColor(np.ascontiguousarray(_even_size(frame)), cv2.COLOR_RGB2BGR))
            count += 1
    finally:
        if writer is not None:
            writer.release()
    if count == 0:
        raise ValueError(f"{path}: no frames to write")
    return count


def turbo_lut() -> np.ndarray:
    """(256, 3) uint8: matplotlib's 'turbo' colormap, dark blue (0) to dark red (255)."""
    import matplotlib

    return np.round(matplotlib.colormaps["turbo"](np.linspace(0.0, 1.0, 256))[:, :3] * 255).astype(np.uint8)


def colorize_depth(depth: np.ndarray, acc: np.ndarray, lo: float, hi: float, acc_threshold: float = EMPTY_ACC) -> np.ndarray:
    """Colour a depth map: turbo, red at ``lo`` to blue at ``hi`` (linear in depth), black where acc is below
    ``acc_threshold`` (0.5).

    Args:
        depth: (H, W) float, world depth or NDC t' (see the module docstring); non-finite values are black.
        acc: (H, W) accumulated opacity in [0, 1].
        lo, hi: the depths of the red and the blue ends, lo < hi.
    Returns:
        (H, W, 3) uint8 RGB.
    """
    depth = np.asarray(depth, dtype=np.float64)
    acc = np.asarray(acc, dtype=np.float64)
    if depth.ndim != 2 or acc.shape != depth.shape:
        raise ValueError(f"depth and acc must both be (H, W), got {depth.shape} and {acc.shape}")
    if not lo < hi:
        raise ValueError(f"need lo < hi, got lo {lo}, hi {hi}")
    finite = np.isfinite(depth)
    nearness = 1.0 - np.clip((np.where(finite, depth, hi) - lo) / (hi - lo), 0.0, 1.0)  # 1 at lo, 0 at hi
    rgb = turbo_lut()[np.round(nearness * 255).astype(np.int64)]
    rgb[(acc < acc_threshold) | ~finite] = 0
    return rgb
