"""Are exported points where the photos show the object? Project them into the training views and count.

For captures with a foreground mask per view (alpha, or a constant backdrop: ``nerfpipe.imaging.masks``), an
export that holds only the object projects onto the foreground of every view that sees it; backdrop
learnt as density (a black starburst around an object on black) projects onto the backdrop.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from nerfpipe.export.views import ViewCamera
from nerfpipe.imaging.masks import dilate
from nerfpipe.nerf.train.images import ImageLoader


@dataclass(frozen=True)
class MaskedView:
    """One view to test points against. K: (3, 3) pinhole intrinsics (pixel (i, j) spans [j, j+1) x [i, i+1),
    COLMAP's convention); c2w: (4, 4) OpenCV camera-to-world in the frame of the points; foreground: (H, W) bool."""

    K: np.ndarray
    c2w: np.ndarray
    foreground: np.ndarray


@dataclass(frozen=True)
class ForegroundShare:
    """``pairs``: (point, view) pairs where the point lies in front of the view and projects inside its image;
    ``on_foreground``: those landing on the (dilated) foreground; ``fraction``: their share (1 without pairs)."""

    pairs: int
    on_foreground: int

    @property
    def fraction(self) -> float:
        return self.on_foreground / self.pairs if self.pairs else 1.0


def project(points: np.ndarray, K: np.ndarray, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, 2) pixel coordinates (u, v) = (fx x / z + cx, fy y / z + cy) of points (M, 3) in a camera's frame
    (``ViewCamera.project``), and (M,) bool: in front of the camera (z > 0)."""
    uv, depth = ViewCamera((K[0, 0], K[1, 1], K[0, 2], K[1, 2]), c2w, 1, 1).project(points)
    return uv, depth > 1e-9


def foreground_share(points: np.ndarray, views: Sequence[MaskedView], dilation: int = 3,
                     to_view_frame: np.ndarray | None = None) -> ForegroundShare:
    """Of all (point, view) pairs where the point projects inside the view's image, how many land on the
    view's foreground grown by ``dilation`` pixels (masks and depth edges are a pixel or two apart).

    points: (M, 3); to_view_frame: (4, 4) similarity taking them to the views' frame (e.g. ``Bounds.to_world``
    for exports written in the SfM frame), or None when they are in it already.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if to_view_frame is not None:
        m = np.asarray(to_view_frame, dtype=np.float64)
        points = points @ m[:3, :3].T + m[:3, 3]
    pairs = on = 0
    for view in views:
        fg = dilate(view.foreground, dilation)
        h, w = fg.shape
        uv, front = project(points, np.asarray(view.K, dtype=np.float64), view.c2w)
        inside = front & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        cols, rows = uv[inside, 0].astype(np.int64), uv[inside, 1].astype(np.int64)
        pairs += int(inside.sum())
        on += int(fg[rows, cols].sum())
    return ForegroundShare(pairs, on)


def training_views(loader: ImageLoader, names: Sequence[str]) -> list[MaskedView]:
    """The views ``names`` (e.g. ``ViewSplit.train``) in the normalized world, with their foreground:
    everything but the constant backdrop (``ImageLoader.foreground``) or, for photos with alpha, alpha >= 0.5.
    Raises ``ValueError`` when the scene has neither."""
    frames = {f.name: f for f in loader.world.frames}
    views = []
    for name in names:
        frame = frames[name]
        foreground = loader.foreground(frame)
        if foreground is None:
            foreground = loader.alpha(frame)
        if foreground is None:
            raise ValueError(f"{name}: the scene has no constant backdrop and the photo no alpha to test against")
        views.append(MaskedView(loader.world.camera_of(frame).K(), np.asarray(frame.c2w), foreground))
    return views
