"""MP4s read back with the frames, size and colour written; depth colours are black where empty and
run monotonically from red (near) to blue (far)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from nerfpipe.export.video import colorize_depth, turbo_lut, write_mp4
from nerfpipe.pipeline.errors import StageError
from tests.helpers import VideoInfo, read_mp4, video_info


def test_mp4_has_the_frames_size_and_colour_written(tmp_path: Path) -> None:
    colour = np.array([200, 100, 50], dtype=np.uint8)
    frames = [np.broadcast_to(colour, (48, 64, 3)).copy() for _ in range(10)]
    assert write_mp4(frames, tmp_path / "a.mp4", fps=12) == 10
    capture = cv2.VideoCapture(str(tmp_path / "a.mp4"))
    assert capture.get(cv2.CAP_PROP_FPS) == pytest.approx(12.0)
    capture.release()
    back = read_mp4(tmp_path / "a.mp4")
    assert len(back) == 10
    assert all(f.shape == (48, 64, 3) for f in back)
    # H.264 keeps a flat colour to a few levels (YUV 4:2:0 round trip and quantization)
    for frame in back:
        assert np.all(np.abs(frame.reshape(-1, 3).mean(axis=0) - colour) < 8)


def test_mp4_is_h264_in_yuv420p_with_its_index_first(tmp_path: Path) -> None:
    """What browsers decode (MPEG-4 Part 2, OpenCV's 'mp4v', they do not), starting before the file is in."""
    frames = [np.full((24, 32, 3), 10 * i, np.uint8) for i in range(7)]
    assert write_mp4(frames, tmp_path / "b.mp4", fps=20) == 7
    assert video_info(tmp_path / "b.mp4") == VideoInfo("h264", "yuv420p", 7, 32, 24, index_first=True)


def test_mp4_from_an_iterator_and_an_odd_size(tmp_path: Path) -> None:
    """A generator is consumed once; a 33 x 25 frame is padded to 34 x 26 instead of cropped."""
    def frames():
        for level in (0, 128, 255):
            frame = np.full((25, 33, 3), level, dtype=np.uint8)
            frame[:, -1] = 255 - level  # the last column, which cropping would lose
            yield frame

    assert write_mp4(frames(), tmp_path / "odd.mp4", fps=5) == 3
    back = read_mp4(tmp_path / "odd.mp4")
    assert len(back) == 3 and back[0].shape == (26, 34, 3)
    # the padded column repeats the last one: both bright in the first frame, dark in the third
    assert back[0][:, -2:].mean() > 200 and back[2][:, -2:].mean() < 60
    assert back[1][:, :20].mean() == pytest.approx(128, abs=8)


def test_mp4_refuses_bad_frames_and_paths(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no frames"):
        write_mp4([], tmp_path / "empty.mp4", fps=10)
    with pytest.raises(ValueError, match="first frame"):
        write_mp4([np.zeros((8, 8, 3), np.uint8), np.zeros((8, 10, 3), np.uint8)], tmp_path / "sizes.mp4", fps=10)
    with pytest.raises(ValueError, match="uint8"):
        write_mp4([np.zeros((8, 8, 3), np.float32)], tmp_path / "float.mp4", fps=10)
    missing = tmp_path / "no such folder" / "x.mp4"
    with pytest.raises(StageError, match="no such folder"):
        write_mp4([np.zeros((8, 8, 3), np.uint8)], missing, fps=10)


def test_depth_colours_black_where_empty_and_monotone() -> None:
    lut = turbo_lut().astype(np.int64)
    depth = np.linspace(1.0, 3.0, 64)[None, :].repeat(2, axis=0)
    acc = np.ones_like(depth)
    acc[1, ::2] = 0.4  # every other pixel of the second row is empty
    rgb = colorize_depth(depth, acc, lo=1.0, hi=3.0)
    assert rgb.shape == (2, 64, 3) and rgb.dtype == np.uint8
    assert np.all(rgb[1, ::2] == 0) and np.all(rgb[1, 1::2].max(axis=-1) > 0)
    # lo is the red end of turbo (its last entry), hi the blue end (its first)
    assert np.array_equal(rgb[0, 0], lut[255]) and np.array_equal(rgb[0, -1], lut[0])
    # reading each colour back as its position in the colormap: strictly decreasing with depth
    index = np.argmin(((rgb[0][:, None, :].astype(np.int64) - lut[None]) ** 2).sum(-1), axis=1)
    assert np.all(np.diff(index) < 0)
    # beyond [lo, hi] the end colours; a non-finite depth is black
    clipped = colorize_depth(np.array([[0.5, 9.0, np.nan, np.inf]]), np.ones((1, 4)), 1.0, 3.0)
    assert np.array_equal(clipped[0, 0], lut[255]) and np.array_equal(clipped[0, 1], lut[0])
    assert np.all(clipped[0, 2:] == 0)
    with pytest.raises(ValueError, match="lo < hi"):
        colorize_depth(depth, acc, 2.0, 2.0)
