"""What the web viewer and its panel both render with: a browser camera's pose, and the field's view from it.
Its own module, so that ``web`` and ``web_panel`` import it and not each other."""

from __future__ import annotations

from typing import Any

import numpy as np


def client_c2w(camera: Any) -> np.ndarray:
    """(4, 4) camera-to-world of a browser's camera (viser's are OpenCV-axed, as nerfpipe's)."""
    import viser.transforms as tf

    c2w = np.eye(4)
    c2w[:3, :3] = tf.SO3(np.asarray(camera.wxyz)).as_matrix()
    c2w[:3, 3] = camera.position
    return c2w


def render_view(scene: Any, c2w: np.ndarray, fov: float, aspect: float, width: int) -> np.ndarray:
    """(H, W, 3) uint8: ``scene.model`` (a ``RadianceModel``) seen by a pinhole camera at ``c2w`` (OpenCV axes) with
    vertical ``fov``, out to ``scene.far``."""
    import torch

    from nerfpipe.export.camera_path import view_range

    height = max(2, round(width / aspect))
    focal = 0.5 * height / np.tan(fov / 2)
    near, far = view_range(c2w, scene.far)  # from wherever the browser's camera is
    with torch.no_grad():
        rendered = scene.model.render_image((focal, focal, width / 2, height / 2), c2w, width, height, near, far)
    return (np.clip(rendered["rgb"].numpy(), 0, 1) * 255).astype(np.uint8)
