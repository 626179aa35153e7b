"""Poses: look_at builds a right-handed OpenCV frame; mean_camera averages a rig."""

from __future__ import annotations

import numpy as np
import pytest

from nerfpipe.geometry.cameras import look_at, mean_camera

DOWN = np.array([0.0, 0.0, -1.0])  # world z up


def test_look_at_is_an_opencv_frame_facing_the_target():
    pose = look_at(np.array([0.0, -2.0, 0.0]), np.zeros(3), DOWN)
    # looking along +y with z up: x (right) = +x, y (down) = -z, z (forward) = +y
    assert pose[:3, :3] == pytest.approx(np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]]).astype(float))
    assert pose[:3, 3].tolist() == [0.0, -2.0, 0.0]
    assert np.linalg.det(pose[:3, :3]) == pytest.approx(1.0)


def test_look_at_refuses_an_undefined_roll():
    with pytest.raises(ValueError, match="parallel to the viewing axis"):
        look_at(np.array([0.0, 0.0, 2.0]), np.zeros(3), DOWN)
    with pytest.raises(ValueError, match="coincide"):
        look_at(np.zeros(3), np.zeros(3), DOWN)


def test_mean_camera_of_a_symmetric_pair_looks_between_them():
    left = look_at(np.array([-1.0, -2.0, 0.0]), np.array([-1.0, 0.0, 0.0]), DOWN)
    right = look_at(np.array([1.0, -2.0, 0.0]), np.array([1.0, 0.0, 0.0]), DOWN)
    mean = mean_camera(np.stack([left, right]))
    assert mean[:3, 3] == pytest.approx([0.0, -2.0, 0.0])
    assert mean[:3, 2] == pytest.approx([0.0, 1.0, 0.0]) and mean[:3, 1] == pytest.approx([0.0, 0.0, -1.0])
