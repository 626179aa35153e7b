"""The multi-view consistency check of the point export, on a sphere whose depth maps are known in closed form."""

from __future__ import annotations

import numpy as np

from nerfpipe.export.points import agreement, nearest_views, views_to_points
from tests.export.test_sphere import FOCAL, SIZE, analytic_depth, ring_cameras


def sphere_views(count: int = 8) -> list:
    K = np.array([[FOCAL, 0.0, SIZE / 2], [0.0, FOCAL, SIZE / 2], [0.0, 0.0, 1.0]])
    views = []
    for c2w in ring_cameras(count):
        depth = analytic_depth(c2w)
        hit = np.isfinite(depth)
        rendered = {"depth": np.where(hit, depth, 0.0), "acc": hit.astype(np.float32), "rgb": np.full((SIZE, SIZE, 3), 0.5)}
        views.append((rendered, K, c2w))
    return views


def test_nearest_views_are_the_ones_looking_the_same_way() -> None:
    cameras = ring_cameras(8)  # 45 degrees apart on the ring
    near = nearest_views(cameras, 2)
    assert [sorted(n) for n in near[:2]] == [[1, 7], [0, 2]]
    assert all(len(n) == 2 for n in near)
    assert nearest_views(cameras, 7, max_angle=30.0) == [[] for _ in cameras]  # no other within 30 degrees


def test_a_true_surface_is_confirmed_and_a_wrong_depth_is_not() -> None:
    views = sphere_views()
    counts = agreement(views, 0.5, neighbours=2, tolerance=0.02)
    hit = views[0][0]["acc"] > 0
    assert (counts[0][~hit] == 0).all()
    # nearly every surface pixel of view 0 is seen by a neighbour 45 degrees round; both see its middle
    # (at 48 px, the nearest pixel's depth at grazing angles misses 2 %: the edges of the disc agree once)
    assert (counts[0][hit] >= 1).mean() > 0.95 and (counts[0][hit] == 2).mean() > 0.3
    # a depth halfway to what is behind (an average of two surfaces) lands on no neighbour's surface
    rendered = dict(views[0][0])
    rendered["depth"] = np.where(hit, rendered["depth"] * 1.15, 0.0)
    broken = [(rendered, views[0][1], views[0][2]), *views[1:]]
    wrong = agreement(broken, 0.5, neighbours=2, tolerance=0.02)[0]
    assert (wrong[hit] >= 1).mean() < 0.05  # (a few at the silhouette, where a neighbour looks along the ray)


def test_points_come_only_from_pixels_the_masks_keep() -> None:
    views = sphere_views(4)
    everything, _ = views_to_points(views, 0.5)
    masks = [np.zeros((SIZE, SIZE), dtype=bool) for _ in views]
    masks[1][10:20, 10:30] = True
    some, source = views_to_points(views, 0.5, masks=masks)
    expected = int((views[1][0]["acc"][10:20, 10:30] > 0).sum())
    assert len(some) == expected > 0 and set(source.tolist()) == {1} and len(everything) > len(some)
