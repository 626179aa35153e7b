"""Foreground masks against a constant backdrop, on hand-made images and on the bundled temple."""

from __future__ import annotations

import numpy as np
import pytest

from nerfpipe.imaging.masks import backdrop_colored, backdrop_mask, dilate, foreground_mask, object_mask
from nerfpipe.imaging.png import read_png
from tests.helpers import TEMPLE

BLACK = (0.0, 0.0, 0.0)


def picture(rows: list[str]) -> np.ndarray:
    """uint8 (H, W, 3) from rows of characters: '.' black, '#' white, 'd' dark (20/255), 'g' grey (128/255)."""
    levels = {".": 0, "#": 255, "d": 20, "g": 128}
    return np.array([[[levels[c]] * 3 for c in row] for row in rows], dtype=np.uint8)


def test_a_dark_object_touching_nothing_is_foreground_and_so_is_its_dark_hole() -> None:
    # a white ring on black with a black hole in the middle: the hole is backdrop-coloured but enclosed
    image = picture([
        "......",
        ".####.",
        ".#..#.",
        ".####.",
        "......",
    ])
    assert backdrop_colored(image, BLACK, 0.1).sum() == 30 - 10  # all black pixels, the hole's 2 included
    expected_fg = np.array([[c != "." for c in row] for row in [
        "......",
        ".####.",
        ".####.",
        ".####.",
        "......",
    ]])
    np.testing.assert_array_equal(foreground_mask(image, BLACK, 0.1), expected_fg)


def test_dark_regions_connected_to_the_border_are_backdrop_even_far_inside() -> None:
    # a black corridor from the left border into the middle of a white block: all backdrop; a 'd' pixel
    # (20/255 = 0.078 <= 0.1) carries the connection; the lone black pixel at the right is enclosed
    image = picture([
        "#######",
        "...d..#",
        "####.##",
        "####.##",
        "#####.#",
        "#######",
    ])
    mask = backdrop_mask(image, BLACK, 0.1)
    assert mask[1, :6].all() and mask[2:4, 4].all()
    assert not mask[4, 5]  # touches the corridor only diagonally: 4-connectivity keeps it foreground
    assert mask.sum() == 8


def test_tolerance_edges_are_inclusive_and_per_channel() -> None:
    # 25/255 = 0.098 is within 0.1 of black, 26/255 = 0.102 is not; the largest channel decides
    row = np.array([[[25, 25, 25], [26, 0, 0], [0, 0, 26], [0, 25, 0]]], dtype=np.uint8)
    assert backdrop_colored(row, BLACK, 0.1).tolist() == [[True, False, False, True]]
    # a tolerance that is exactly an 8-bit level admits it: 51/255 = 0.2
    assert backdrop_colored(np.full((1, 1, 3), 51, np.uint8), BLACK, 0.2).item()
    # white backdrop, float and 16-bit pixels alike: 0.95 is within 0.1 of 1, 0.85 is not
    white = np.array([[[0.95, 1.0, 0.95], [0.85, 1.0, 1.0]]])
    assert backdrop_colored(white, (1, 1, 1), 0.1).tolist() == [[True, False]]
    assert backdrop_colored((white * 65535).round().astype(np.uint16), (1, 1, 1), 0.1).tolist() == [[True, False]]
    # RGBA: alpha is ignored
    rgba = np.concatenate([picture(["..", ".."]), np.zeros((2, 2, 1), np.uint8)], axis=-1)
    assert backdrop_mask(rgba, BLACK, 0.1).all()
    with pytest.raises(ValueError, match="expected"):
        backdrop_mask(np.zeros((4, 4)), BLACK, 0.1)


def test_an_image_without_backdrop_is_all_foreground() -> None:
    assert foreground_mask(picture(["gg", "gg"]), BLACK, 0.1).all()


def test_dilate_grows_by_a_disc_of_the_radius() -> None:
    mask = np.zeros((9, 9), bool)
    mask[4, 4] = True
    grown = dilate(mask, 3)
    assert grown[4, 1] and grown[4, 7] and grown[1, 4] and grown[6, 6]  # 2.8 px away
    assert not grown[1, 1] and not grown[7, 7]  # 4.2 px away
    np.testing.assert_array_equal(dilate(mask, 0), mask)


def test_temple_backdrop_is_the_black_around_the_temple() -> None:
    image = read_png(TEMPLE / "templeSR0001.png")
    fg = foreground_mask(image, BLACK, 0.1)
    h, w = fg.shape
    # the temple fills the middle of the frame; the top right corner is the black cloth behind it
    assert fg[h // 2, w // 2] and not fg[:40, -40:].any()
    # about 54 % of this view is backdrop (the grey-lit cloth the temple stands on is not within 0.1)
    assert 0.45 < 1.0 - fg.mean() < 0.6
    assert not (fg & backdrop_mask(image, BLACK, 0.1)).any()


def test_grabcut_gives_the_temples_lit_cloth_to_the_backdrop_and_keeps_the_temple() -> None:
    image = read_png(TEMPLE / "templeSR0001.png")
    simple, refined = foreground_mask(image, BLACK, 0.1), object_mask(image, BLACK, 0.1)
    # the left 100 columns are the grey-lit cloth (0.08-0.2): foreground by tolerance alone, backdrop after GrabCut
    assert simple[:, :100].mean() > 0.5 and refined[:, :100].mean() < 0.01
    # the temple stays: its lit stone (brighter than 0.4 in some channel) is kept, and the refined mask
    # only ever removes pixels from the simple one
    stone = image.max(axis=-1) > 0.4 * 255
    assert refined[stone & simple].mean() > 0.99 and not (refined & ~simple).any()
    assert 0.15 < refined.mean() < 0.3  # the temple fills about a fifth of the frame
    # the same mask from the image at twice the size (GrabCut runs at most 640 px a side and is scaled back)
    import cv2

    big = object_mask(cv2.resize(image, (1280, 960), interpolation=cv2.INTER_LINEAR), BLACK, 0.1)
    assert np.mean(cv2.resize(big.astype(np.uint8), (640, 480), interpolation=cv2.INTER_NEAREST) != refined) < 0.01


def test_grabcut_needs_both_kinds_of_seed_else_the_tolerance_mask_stands() -> None:
    ring = picture([
        "......",
        ".####.",
        ".#..#.",
        ".####.",
        "......",
    ])
    # nothing far from the backdrop colour at 3 x 0.4: no object seeds
    np.testing.assert_array_equal(object_mask(ring, BLACK, 0.4), foreground_mask(ring, BLACK, 0.4))
    # no backdrop joined to the border: all foreground
    assert object_mask(picture(["##", "##"]), BLACK, 0.1).all()
