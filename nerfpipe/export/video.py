"""Frames to video, and depth to colour, for looking at a radiance field.

MP4s are H.264 (High profile, yuv420p, even sizes) with the index at the front (``+faststart``), what every
browser plays and starts before the whole file is in: encoded by libx264 through PyAV, whose wheels ship
FFmpeg and x264, so no system ffmpeg is needed. (OpenCV's wheels only carry the MPEG-4 Part 2 'mp4v'
encoder, which Chrome and Firefox do not decode.)

Depth colour convention (one for every depth picture nerfpipe writes): the value is mapped linearly from
[lo, hi] onto matplotlib's 'turbo' colormap reversed, so near is red and far is blue; values outside
[lo, hi] take the end colours, and pixels the field leaves empty (acc < 0.5) are black. Any quantity that
grows with distance keeps that order: a forward-facing model's NDC depth t' = 1 - near / z (in [0, 1],
linear in disparity) coloured as is over [0, 1] gives a disparity-linear map, the near plane red and
infinity blue.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Iterable

import numpy as np

from nerfpipe.pipeline.errors import DISK_FULL_ERRNOS, StageError

# Pixels whose accumulated opacity is below this show no surface: the ray mostly reached the background.
EMPTY_ACC = 0.5


# libx264 settings: constant quality 18 (visually lossless for renders), the default speed preset
X264_OPTIONS = {"crf": "18", "preset": "medium"}


def _even_size(frame: np.ndarray) -> np.ndarray:
    """yuv420p stores chroma for whole 2x2 blocks, so H.264 needs even sides: an odd side is padded with a
    copy of its last row / column, keeping every rendered pixel."""
    h, w = frame.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return frame
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def write_mp4(frames: Iterable[np.ndarray], path: Path, fps: float) -> int:
    """Write RGB frames to an H.264 MP4 (yuv420p, ``+faststart``) at ``fps`` frames per second.

    Args:
        frames: a list or an iterator (so a caller can render and write one frame at a time) of (H, W, 3)
            uint8 RGB, all of one size; an odd H or W is padded by one edge pixel (see ``_even_size``).
        path: the file to write; its folder must exist.
    Returns:
        the number of frames written.
    Raises:
        ValueError: no frames, or a frame of another shape or dtype.
        StageError: the file cannot be written.
    """
    import av

    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    path = Path(path)
    size: tuple[int, ...] = ()
    count = 0
    try:
        with av.open(str(path), mode="w", format="mp4", container_options={"movflags": "+faststart"}) as container:
            stream = None
            for frame in frames:
                frame = np.asarray(frame)
                if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
                    raise ValueError(f"frame {count}: expected (H, W, 3) uint8 RGB, got {frame.shape} {frame.dtype}")
                if stream is None:
                    size = frame.shape
                    stream = container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001),
                                                  options=X264_OPTIONS)
                    stream.height, stream.width = _even_size(frame).shape[:2]
                    stream.pix_fmt = "yuv420p"
                elif frame.shape != size:
                    raise ValueError(f"frame {count} is {frame.shape}, the first frame was {size}")
                picture = av.VideoFrame.from_ndarray(np.ascontiguousarray(_even_size(frame)), format="rgb24")
                container.mux(stream.encode(picture))
                count += 1
            if stream is not None:
                container.mux(stream.encode(None))  # flush the encoder's delayed frames
    except OSError as err:  # PyAV's errors for files are OSErrors: no such folder, permission, a full disk
        path.unlink(missing_ok=True)
        if err.errno in DISK_FULL_ERRNOS:
            raise  # the runner's one line for a full disk
        raise StageError(f"{path}: cannot write the video ({err.strerror or err}); check that the folder exists "
                         "and is writable") from err
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    if count == 0:
        path.unlink(missing_ok=True)
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
