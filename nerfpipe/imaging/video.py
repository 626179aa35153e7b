"""Frames of a video for reconstruction: about ``count`` of them, evenly spread, each the sharpest of its
stretch of the video, upright.

The video is split into ``count`` equal windows of frames, and from each the frame with the largest variance
of the Laplacian (the usual sharpness measure, e.g. nerfstudio's and COLMAP's video tools) is kept, which
skips the motion-blurred frames a handheld phone video is full of. Frames are decoded by FFmpeg through
PyAV, in one pass, holding one candidate frame per window; the display rotation phones record is applied,
as players do. A video that cannot be opened, holds no video stream, or decodes to far fewer frames than
its header states (cut off) raises ``BadPhotoError`` naming it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from nerfpipe.pipeline.errors import BadPhotoError

VIDEO_EXTENSIONS = frozenset(
    {".mp4", ".mov", ".avi", ".mkv", ".m4v", ".mts", ".m2ts", ".3gp", ".webm", ".wmv", ".mpg", ".mpeg"}
)
# Sharpness is measured on a grey copy at most this wide: enough for blur, and cheap for 4K video.
SHARPNESS_WIDTH = 480
# A file decoding to less than this share of the frames its header states is taken to be cut off.
MIN_DECODED_SHARE = 0.9


@dataclass(frozen=True)
class VideoFrame:
    """One kept frame: ``pixels`` (H, W, 3) uint8 RGB, upright (shrunk as asked); its ``index`` among the
    video's frames, its time in seconds, its sharpness (variance of the Laplacian of the grey frame), and the
    (width, height) it was decoded at, upright."""

    pixels: np.ndarray
    index: int
    time_s: float
    sharpness: float
    source_size: tuple[int, int]


def sharpness(rgb: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image, at most ``SHARPNESS_WIDTH`` wide: high when sharp."""
    import cv2

    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    if grey.shape[1] > SHARPNESS_WIDTH:
        height = max(1, round(grey.shape[0] * SHARPNESS_WIDTH / grey.shape[1]))
        grey = cv2.resize(grey, (SHARPNESS_WIDTH, height), interpolation=cv2.INTER_AREA)
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


def upright(rgb: np.ndarray, rotation: int) -> np.ndarray:
    """Apply a display rotation (degrees counter-clockwise, a multiple of 90, as FFmpeg reports it)."""
    return np.ascontiguousarray(np.rot90(rgb, round(rotation / 90) % 4))


def sharpest_frames(path: Path, count: int, shrink: Callable[[np.ndarray], np.ndarray] = lambda rgb: rgb
                    ) -> tuple[list[VideoFrame], int, float]:
    """The sharpest frame of each of ``count`` equal windows of the video at ``path``.

    Sharpness is measured on each decoded frame; a window's candidate is kept as ``shrink`` makes it (the
    size ingest writes), so 150 windows of a 4K video hold 150 small frames, not 150 4K ones.

    Returns:
        the kept frames in time order (fewer than ``count`` when the video is shorter), the number of frames
        decoded, and the video's frame rate.
    Raises:
        BadPhotoError: the file is not a readable video, or it is cut off.
    """
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    advice = "check that it plays in a video player; if it does, re-export it as MP4 (H.264)"
    stated = _frame_count(path, advice)
    windows = max(1, min(count, stated))
    best: dict[int, VideoFrame] = {}
    decoded = 0
    with _open(path, advice) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        rate = float(stream.average_rate or stream.guessed_rate or 30)
        try:
            for frame in container.decode(stream):
                window = min(decoded * windows // stated, windows - 1)
                rgb = frame.to_ndarray(format="rgb24")
                score = sharpness(rgb)
                if window not in best or score > best[window].sharpness:
                    time_s = float(frame.time) if frame.time is not None else decoded / rate
                    rgb = upright(rgb, frame.rotation or 0)
                    size = (rgb.shape[1], rgb.shape[0])
                    best[window] = VideoFrame(np.ascontiguousarray(shrink(rgb)), decoded, time_s, score, size)
                decoded += 1
        except (av_errors(), OSError) as err:
            raise _cut_off(path, decoded, stated, f" ({_message(err)})") from None
    if decoded == 0:
        raise BadPhotoError(path, "holds no frames that decode", advice)
    if decoded < MIN_DECODED_SHARE * stated:
        raise _cut_off(path, decoded, stated)
    return [best[w] for w in sorted(best)], decoded, rate


def _cut_off(path: Path, decoded: int, stated: int, detail: str = "") -> BadPhotoError:
    return BadPhotoError(path, f"is truncated or damaged: {decoded} of the {stated} frames its header states "
                         f"decode{detail}", "copy it again from the phone or camera")


def av_errors() -> type[Exception]:
    import av

    return av.FFmpegError


def _open(path: Path, advice: str):
    import av

    try:
        container = av.open(str(path))
    except (av.FFmpegError, OSError) as err:
        raise BadPhotoError(path, f"cannot be read as a video ({_message(err)})", advice) from None
    if not container.streams.video:
        container.close()
        raise BadPhotoError(path, "holds no video stream", "pass a video with pictures in it")
    if container.format.name.endswith("_pipe") or container.format.name == "image2":  # FFmpeg's still-image readers
        container.close()
        raise BadPhotoError(path, f"is a still image ({container.format.name.removesuffix('_pipe').upper()}), "
                            "not a video", "give it its image extension and pass the folder that holds it")
    return container


def _frame_count(path: Path, advice: str) -> int:
    """The frames the header states, or, when it states none, the video packets counted without decoding."""
    with _open(path, advice) as container:
        stream = container.streams.video[0]
        if stream.frames:
            return int(stream.frames)
        try:
            return max(1, sum(1 for packet in container.demux(stream) if packet.size))
        except (av_errors(), OSError) as err:
            raise BadPhotoError(path, f"cannot be read as a video ({_message(err)})", advice) from None


def _message(err: Exception) -> str:
    return str(getattr(err, "strerror", None) or err).strip() or type(err).__name__
