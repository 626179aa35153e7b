"""Photos in other colour models and sample formats decode to what they show, or say why not: CMYK TIFFs
are converted (OpenCV passes their K as alpha), a 4th channel that is no alpha is dropped, HDR samples
above 1 are clipped with a line, .jfif and .jpe are JPEGs."""

from __future__ import annotations

import logging
import shutil

import cv2
import numpy as np
import pytest
from PIL import Image

from nerfpipe.imaging import photo_kind, read_photo
from nerfpipe.pipeline.errors import BadPhotoError
from tests.helpers import TEMPLE

RED, GREEN, BLUE = (255, 0, 0), (0, 255, 0), (0, 0, 255)


def stripes() -> np.ndarray:
    rgb = np.zeros((40, 60, 3), np.uint8)
    rgb[:, :20], rgb[:, 20:40], rgb[:, 40:] = RED, GREEN, BLUE
    return rgb


def test_a_cmyk_tiff_is_converted_to_rgb_without_alpha(tmp_path) -> None:
    Image.fromarray(stripes()).convert("CMYK").save(tmp_path / "cmyk.tif")
    photo = read_photo(tmp_path / "cmyk.tif")
    assert not photo.has_alpha and photo.pixels.shape == (40, 60, 3)
    assert [tuple(photo.pixels[20, x]) for x in (5, 25, 45)] == [RED, GREEN, BLUE]


def test_a_fourth_channel_that_is_no_alpha_is_dropped_and_real_alpha_kept(tmp_path) -> None:
    rgbx = np.dstack([stripes(), np.full((40, 60), 7, np.uint8)])
    Image.fromarray(rgbx, "RGBX").save(tmp_path / "rgbx.tif")
    assert not read_photo(tmp_path / "rgbx.tif").has_alpha
    Image.fromarray(rgbx, "RGBA").save(tmp_path / "rgba.tif")
    rgba = read_photo(tmp_path / "rgba.tif")
    assert rgba.has_alpha and rgba.pixels[0, 0, 3] == 7


def test_a_colour_model_neither_decoder_converts_is_refused(tmp_path) -> None:
    Image.fromarray(stripes()).convert("LAB").save(tmp_path / "lab.tif")
    with pytest.raises(BadPhotoError, match="is a TIFF in the LAB colour model; export it as RGB"):
        read_photo(tmp_path / "lab.tif")


def test_float_samples_above_one_are_clipped_with_a_line_naming_the_photo(tmp_path, caplog) -> None:
    hdr = np.full((8, 8, 3), 0.5, np.float32)
    hdr[:2] = 4.0  # a quarter of the samples
    cv2.imwrite(str(tmp_path / "hdr.tif"), hdr)
    with caplog.at_level(logging.WARNING, logger="nerfpipe"):
        photo = read_photo(tmp_path / "hdr.tif")
    assert photo.pixels.max() == 65535 and photo.pixels[4, 4, 0] == round(0.5 * 65535)
    assert f"{tmp_path / 'hdr.tif'}: float samples up to 4, above 1.0 (HDR): 25.0 % of them clipped" in caplog.text
    caplog.clear()
    cv2.imwrite(str(tmp_path / "sdr.tif"), np.full((8, 8, 3), 0.5, np.float32))
    with caplog.at_level(logging.WARNING, logger="nerfpipe"):
        read_photo(tmp_path / "sdr.tif")
    assert "clipped" not in caplog.text


@pytest.mark.parametrize("suffix", [".jfif", ".jpe", ".JFIF"])
def test_jfif_and_jpe_are_jpegs(tmp_path, suffix) -> None:
    path = tmp_path / f"photo{suffix}"
    cv2.imwrite(str(tmp_path / "photo.jpg"), cv2.imread(str(TEMPLE / "templeSR0001.png")))
    shutil.move(tmp_path / "photo.jpg", path)
    assert photo_kind(path) == "jpeg"
    assert read_photo(path).pixels.shape == (480, 640, 3)


def test_pillow_warnings_become_lines_naming_the_photo(tmp_path, caplog, monkeypatch) -> None:
    import warnings

    from nerfpipe.imaging import decode

    def warn_then_read(*args):
        warnings.warn("Corrupt EXIF data.  Expecting to read 12 bytes but only got 6.", UserWarning)
        return None

    monkeypatch.setattr(decode, "_read_header", warn_then_read)
    with caplog.at_level(logging.WARNING, logger="nerfpipe"), warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning that escaped would fail here
        decode.read_header(TEMPLE / "templeSR0001.png")
    assert f"{TEMPLE / 'templeSR0001.png'}: Corrupt EXIF data." in caplog.text
