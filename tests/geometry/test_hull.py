"""The visual hull of silhouettes: a sphere seen from a ring of cameras, carved by hand-computable rules."""

from __future__ import annotations

import numpy as np
import pytest

from nerfpipe.geometry.hull import Silhouettes, cell_centers, hull_box, visual_hull
from tests.geometry.sphere_photos import CENTER, RADIUS, sphere_views

BOX = (np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]))


def test_the_hull_of_a_sphere_holds_the_sphere_and_its_box_is_the_spheres_grown_by_a_cell() -> None:
    views = sphere_views()
    hull = views.hull(BOX, 32, tolerance=0.0)
    centers = cell_centers(*BOX, 32)
    distance = np.linalg.norm(centers - CENTER, axis=1)
    assert hull.reshape(-1)[distance < RADIUS].all()  # nothing of the object is carved
    # a silhouette hull is larger than the object, but not much at a ring of 12: cells 2 radii away are gone
    assert not hull.reshape(-1)[distance > 2 * RADIUS].any()
    assert 0.1 < hull.sum() * (2 / 32) ** 3 / (4 / 3 * np.pi * RADIUS**3) < 3.0
    lo, hi = hull_box(hull, BOX, margin_cells=1.0)
    cell = 2 / 32
    # the box of the sphere's cells (whole cells, the sphere rounded out to the grid), one cell more a side;
    # the ring looks down from above, so the hull reaches further up and down than the sphere
    assert np.all(lo <= CENTER - RADIUS - cell + 1e-9) and np.all(hi >= CENTER + RADIUS + cell - 1e-9)
    assert np.all(lo[:2] >= CENTER[:2] - RADIUS - 3 * cell) and np.all(hi[:2] <= CENTER[:2] + RADIUS + 3 * cell)
    assert np.all(lo >= BOX[0]) and np.all(hi <= BOX[1])


def test_one_wrong_mask_carves_the_object_unless_tolerated() -> None:
    views = sphere_views()
    wrong = Silhouettes([np.zeros_like(views.masks[0]), *views.masks[1:]], views.intrinsics, views.c2ws)
    # the empty mask calls every cell its camera sees backdrop: 1 miss in 12 views carves all at tolerance 0
    assert not wrong.hull(BOX, 16, tolerance=0.0)[tuple(((CENTER + 1) / 2 * 16).astype(int))]
    tolerated = wrong.hull(BOX, 16, tolerance=0.1)  # 1 <= 0.1 x 12
    assert tolerated[tuple(((CENTER + 1) / 2 * 16).astype(int))]
    assert tolerated.sum() >= views.hull(BOX, 16, tolerance=0.0).sum()


def test_cells_too_few_photos_see_are_not_part_of_the_hull() -> None:
    views = sphere_views()
    # the sphere's centre: kept by two photos, not by one (at least 2 photos must see a cell)
    box = (CENTER - 0.01, CENTER + 0.01)
    assert visual_hull(views.masks[:2], views.intrinsics[:2], views.c2ws[:2], box, 1, min_share=0.0).all()
    assert not visual_hull(views.masks[:1], views.intrinsics[:1], views.c2ws[:1], box, 1, min_share=0.0).any()
    # and by 6 of 12 photos only when min_share <= 0.5
    assert visual_hull(views.masks[:6], views.intrinsics[:6], views.c2ws[:6], box, 1, min_share=0.5).all()
    half = Silhouettes(views.masks[:6] + [np.zeros_like(m) for m in views.masks[6:]], views.intrinsics, views.c2ws)
    assert not half.hull(box, 1, tolerance=0.0).any()


def test_a_cell_is_judged_by_its_whole_extent_not_its_centre() -> None:
    # one big cell whose centre projects off the sphere's silhouette in every view, while its corner reaches
    # into the sphere: it stays
    views = sphere_views()
    corner = CENTER + RADIUS * 0.5
    box = (corner, corner + 0.5)
    centre = corner + 0.25
    assert np.linalg.norm(centre - CENTER) > RADIUS + 0.05
    assert visual_hull(views.masks, views.intrinsics, views.c2ws, box, 1, slack_px=0.0).all()


def test_hull_box_of_nothing_is_none_and_a_full_hull_keeps_the_box() -> None:
    assert hull_box(np.zeros((4, 4, 4), dtype=bool), BOX) is None
    lo, hi = hull_box(np.ones((4, 4, 4), dtype=bool), BOX, margin_cells=2.0)
    assert lo == pytest.approx(BOX[0]) and hi == pytest.approx(BOX[1])
    one = np.zeros((4, 4, 4), dtype=bool)
    one[1, 2, 3] = True  # cell x in [-0.5, 0], y in [0, 0.5], z in [0.5, 1]
    lo, hi = hull_box(one, BOX, margin_cells=0.0)
    assert lo == pytest.approx([-0.5, 0.0, 0.5]) and hi == pytest.approx([0.0, 0.5, 1.0])
