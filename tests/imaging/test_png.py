"""The pipeline's PNGs: 8 and 16 bit, RGB, RGBA and one channel round trip; the sRGB curve by hand."""

from __future__ import annotations

import numpy as np
import pytest

from nerfpipe.imaging.png import read_png, srgb_encode, write_png
from nerfpipe.pipeline.errors import StageError


@pytest.mark.parametrize("shape", [(5, 7), (5, 7, 3), (5, 7, 4)])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_round_trip_keeps_channels_order_and_bit_depth(tmp_path, shape, dtype):
    rng = np.random.default_rng(0)
    pixels = rng.integers(0, np.iinfo(dtype).max, size=shape, dtype=dtype)
    write_png(tmp_path / "süb folder" / "ä b.png", pixels)  # makes the folder; any name works
    back = read_png(tmp_path / "süb folder" / "ä b.png")
    assert back.dtype == dtype and np.array_equal(back, pixels)


def test_red_stays_red(tmp_path):
    red = np.zeros((2, 2, 3), np.uint8)
    red[..., 0] = 255
    write_png(tmp_path / "red.png", red)
    assert read_png(tmp_path / "red.png")[0, 0].tolist() == [255, 0, 0]


def test_a_file_that_is_no_png_is_a_stage_error(tmp_path):
    (tmp_path / "x.png").write_bytes(b"not a png")
    with pytest.raises(StageError, match="x.png: cannot decode"):
        read_png(tmp_path / "x.png")


def test_srgb_curve():
    # linear segment below 0.0031308: 12.92 x; 1.0 -> 1.0; 0.5 -> 1.055 * 0.5 ** (1 / 2.4) - 0.055 = 0.7354
    out = srgb_encode(np.array([-1.0, 0.001, 0.5, 1.0, 2.0]))
    assert out == pytest.approx([0.0, 0.01292, 0.735357, 1.0, 1.0], abs=1e-6)
