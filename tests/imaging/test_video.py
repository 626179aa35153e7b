"""Frames from a video: the sharpest of each window, upright as players show them, and one clear error for
a cut-off or unreadable file."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
import pytest

from nerfpipe.export.video import write_mp4
from nerfpipe.imaging.video import sharpest_frames, sharpness
from nerfpipe.pipeline.errors import BadPhotoError
from tests.helpers import TEMPLE


def temple_frames(count: int, blur_every: int = 0) -> list[np.ndarray]:
    """``count`` frames panning across a temple photo; every ``blur_every``-th one sharp, the rest blurred."""
    photo = cv2.imread(str(TEMPLE / "templeSR0001.png"))[..., ::-1]
    frames = []
    for i in range(count):
        frame = np.ascontiguousarray(photo[100:340, 100 + 2 * i:420 + 2 * i])
        if blur_every and i % blur_every:
            frame = cv2.GaussianBlur(frame, (0, 0), 3)
        frames.append(frame)
    return frames


def test_the_sharpest_frame_of_each_window_is_kept_with_its_index_and_time(tmp_path: Path) -> None:
    frames = temple_frames(40, blur_every=5)  # frames 0, 5, 10, ... sharp: one in each window of 5
    write_mp4(frames, tmp_path / "pan.mp4", fps=10)
    kept, decoded, rate = sharpest_frames(tmp_path / "pan.mp4", 8)
    assert decoded == 40 and rate == pytest.approx(10)
    assert [f.index for f in kept] == [0, 5, 10, 15, 20, 25, 30, 35]
    assert [f.time_s for f in kept] == pytest.approx([0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5])
    assert all(f.pixels.shape == (240, 320, 3) for f in kept)
    assert sharpness(frames[0]) > 4 * sharpness(frames[1])
    # more frames asked for than the video has: every frame, once
    assert [f.index for f in sharpest_frames(tmp_path / "pan.mp4", 100)[0]] == list(range(40))


def test_the_display_rotation_a_phone_records_is_applied_as_players_do(tmp_path: Path) -> None:
    """A portrait phone video is stored landscape with a rotation; OpenCV's reader applies it too."""
    import av

    frame = temple_frames(1)[0]
    with av.open(str(tmp_path / "phone.mp4"), "w") as container:
        stream = container.add_stream("libx264", rate=Fraction(10))
        stream.width, stream.height, stream.pix_fmt = 320, 240, "yuv420p"
        stream.set_display_rotation(-90)  # as a phone held upright records it
        for _ in range(3):
            container.mux(stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")))
        container.mux(stream.encode(None))
    kept, _, _ = sharpest_frames(tmp_path / "phone.mp4", 1)
    assert kept[0].pixels.shape == (320, 240, 3)  # portrait
    ok, shown = cv2.VideoCapture(str(tmp_path / "phone.mp4")).read()
    assert ok and shown.shape == (320, 240, 3)
    assert np.abs(kept[0].pixels.astype(int) - shown[..., ::-1].astype(int)).mean() < 2


def test_cut_off_and_unreadable_videos_raise_one_clear_error(tmp_path: Path) -> None:
    write_mp4(temple_frames(30), tmp_path / "whole.mp4", fps=10)
    data = (tmp_path / "whole.mp4").read_bytes()
    (tmp_path / "cut.mp4").write_bytes(data[: len(data) // 2])  # index first (faststart): the frames are cut
    with pytest.raises(BadPhotoError, match=r"cut.mp4: is truncated or damaged: \d+ of the 30 frames its header states decode"):
        sharpest_frames(tmp_path / "cut.mp4", 10)
    (tmp_path / "junk.mov").write_bytes(b"not a video" * 50)
    with pytest.raises(BadPhotoError, match="junk.mov: cannot be read as a video"):
        sharpest_frames(tmp_path / "junk.mov", 10)


def test_kept_frames_are_held_shrunk_with_the_size_they_were_decoded_at(tmp_path: Path) -> None:
    """150 windows of a 4K video must not hold 150 4K frames: each candidate is kept as ``shrink`` makes it,
    after its sharpness is measured at full size."""
    frames = temple_frames(20, blur_every=4)
    write_mp4(frames, tmp_path / "pan.mp4", fps=10)
    seen = []

    def shrink(rgb):
        seen.append(rgb.shape)
        return cv2.resize(rgb, (80, 60), interpolation=cv2.INTER_AREA)

    kept, _, _ = sharpest_frames(tmp_path / "pan.mp4", 5, shrink)
    assert [f.index for f in kept] == [0, 4, 8, 12, 16]  # chosen by full-size sharpness, as without shrinking
    assert all(f.pixels.shape == (60, 80, 3) and f.source_size == (320, 240) for f in kept)
    assert set(seen) == {(240, 320, 3)} and len(seen) >= 5


def test_a_still_image_named_like_a_video_is_refused(tmp_path: Path) -> None:
    """FFmpeg opens a PNG as a one-frame 'video' (its png_pipe reader); that is a photo with the wrong name."""
    import shutil

    shutil.copy(TEMPLE / "templeSR0001.png", tmp_path / "clip.mp4")
    with pytest.raises(BadPhotoError, match=r"clip.mp4: is a still image \(PNG\), not a video; give it its image "
                                            "extension and pass the folder that holds it"):
        sharpest_frames(tmp_path / "clip.mp4", 10)
