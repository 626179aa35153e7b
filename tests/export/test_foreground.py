"""Projecting exported points into masked views: hand-computed pixels and shares; then the bundled temple,
whose exports after a short training lie on the temple and whose black backdrop renders empty."""

from __future__ import annotations

import itertools
import json

import cv2
import numpy as np
import pytest

from nerfpipe import Pipeline, default_stages
from nerfpipe.artifacts import Bounds, ViewSplit
from nerfpipe.export.depth import DepthIndex
from nerfpipe.export.foreground import ForegroundShare, MaskedView, foreground_share, project, training_views
from nerfpipe.export.mesh import read_mesh
from nerfpipe.export.points import read_ply
from nerfpipe.nerf.train.images import ImageLoader
from tests.helpers import TEMPLE, count_progress

# a 4x4 image, f = 10, principal point at its centre (2, 2); the camera at the origin looking along +z
K = np.array([[10.0, 0.0, 2.0], [0.0, 10.0, 2.0], [0.0, 0.0, 1.0]])


def one_pixel_foreground(row: int, col: int) -> np.ndarray:
    mask = np.zeros((4, 4), bool)
    mask[row, col] = True
    return mask


def test_projection_is_pinhole_with_pixel_centres_at_half_integers() -> None:
    points = np.array([[0.0, 0.0, 1.0], [-0.15, 0.1, 2.0], [0.0, 0.0, -1.0]])
    uv, front = project(points, K, np.eye(4))
    # (0, 0, 1) -> (2, 2); (-0.15, 0.1, 2) -> (10 * -0.075 + 2, 10 * 0.05 + 2) = (1.25, 2.5)
    np.testing.assert_allclose(uv[:2], [[2.0, 2.0], [1.25, 2.5]])
    assert front.tolist() == [True, True, False]


def test_share_counts_pairs_inside_the_image_and_those_on_the_foreground() -> None:
    points = np.array([
        [0.0, 0.0, 1.0],    # (2, 2): pixel row 2, col 2, the foreground
        [-0.15, 0.0, 1.0],  # (0.5, 2): row 2, col 0, background, 2 px from the foreground
        [-0.15, -0.15, 1.0],  # (0.5, 0.5): row 0, col 0, 2.8 px away
        [1.0, 0.0, 1.0],    # u = 12: outside the image, not a pair
        [0.0, 0.0, -1.0],   # behind the camera, not a pair
    ])
    view = MaskedView(K, np.eye(4), one_pixel_foreground(2, 2))
    assert foreground_share(points, [view], dilation=0) == ForegroundShare(pairs=3, on_foreground=1)
    assert foreground_share(points, [view], dilation=2) == ForegroundShare(pairs=3, on_foreground=2)
    assert foreground_share(points, [view], dilation=3) == ForegroundShare(pairs=3, on_foreground=3)
    # two views add up: the second camera 1 to the right sees (1, 0, 1) at (2, 2) and (0, 0, 1) at u = -8
    moved = np.eye(4)
    moved[0, 3] = 1.0
    both = foreground_share(points, [view, MaskedView(K, moved, one_pixel_foreground(2, 2))], dilation=0)
    assert both == ForegroundShare(pairs=4, on_foreground=2) and both.fraction == pytest.approx(0.5)
    assert ForegroundShare(0, 0).fraction == 1.0


def test_points_in_another_frame_are_taken_to_the_views_frame_first() -> None:
    # points written at twice the scale (an SfM frame); to_view_frame halves them
    to_view = np.diag([0.5, 0.5, 0.5, 1.0])
    view = MaskedView(K, np.eye(4), one_pixel_foreground(2, 2))
    share = foreground_share(np.array([[0.0, 0.0, 2.0], [0.3, 0.0, 2.0]]), [view], dilation=0, to_view_frame=to_view)
    # (0, 0, 1) -> (2, 2) on the foreground; (0.15, 0, 1) -> (3.5, 2): inside the image, off the foreground
    assert share == ForegroundShare(pairs=2, on_foreground=1)


def test_training_views_take_the_backdrop_mask_else_the_alpha_channel(tmp_path) -> None:
    from tests.nerf.scenes import loader_of, write_image_folders

    folders = write_image_folders(tmp_path)
    # alpha: a.png has alpha 0.2 (< 0.5: no foreground), the others no alpha channel to test against
    (view,) = training_views(loader_of(folders), ["a.png"])
    assert view.foreground.shape == (8, 12) and not view.foreground.any()
    np.testing.assert_array_equal(view.K, [[10.0, 0.0, 6.0], [0.0, 10.0, 4.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="grey.png: the scene has no constant backdrop and the photo no alpha"):
        training_views(loader_of(folders), ["grey.png"])
    # a blue backdrop: white b.png is all foreground
    (view,) = training_views(loader_of(folders, background="color", tolerance=0.1), ["b.png"])
    assert view.foreground.all()


# -- the bundled temple: a white temple on black cloth -------------------------------------------------
# a short training (the draft preset's one 64^3 grid, 800 steps of 8192 samples) on 320x240 images. At 160x120
# the silhouette pixels, whose depth mixes the temple and what lies behind it, are twice as large a share of the
# points, and 89-97 % of the points land on the temple depending on the steps; at 320x240 99.9 %, as at full size
TEMPLE_SHORT = {
    "ingest": {"max_size": 320},
    "train": {"steps": 800, "batch_samples": 8192, "batch_rays": 1024, "checkpoint_every": 1000},
    "export_mesh": {"resolution": 128},
}


@pytest.mark.slow
def test_temple_exports_hold_the_temple_and_its_backdrop_renders_empty(tmp_path) -> None:
    calls: list = []
    pipe = Pipeline(default_stages(), TEMPLE, tmp_path / "temple", "draft", TEMPLE_SHORT, progress=count_progress(calls))
    pipe.run(until="export_mesh")
    # export_mesh shows its progress: a bar whose steps all come
    total = next(c[0] for c in calls if isinstance(c, tuple) and c[1] == "export mesh")
    bar = calls.index((total, "export mesh"))
    assert total >= 4 and sum(itertools.takewhile(lambda c: isinstance(c, int), calls[bar + 1:])) == total
    train = pipe.result("train")
    metrics = json.loads((train.path / "metrics.json").read_text())
    assert any(d.startswith("backdrop masks: ") for d in metrics["decisions"])
    assert "by their backdrop masks" in metrics["protocol"] and metrics["psnr_photo"] < metrics["psnr"]
    loader = ImageLoader.from_inputs(pipe.stage_inputs("train"))
    views = training_views(loader, ViewSplit.load(train.path / "views.json").train)
    to_world = Bounds.load(pipe.stage_inputs("train")["bounds"]).to_world
    points = read_ply(pipe.result("export_points").path / "points.ply").xyz
    vertices = read_mesh(pipe.result("export_mesh").path / "mesh.ply").vertices
    shares = {what: foreground_share(xyz, views, 3, to_world) for what, xyz in (("points", points), ("mesh", vertices))}
    print({what: (round(s.fraction, 4), s.pairs) for what, s in shares.items()})
    assert all(s.pairs > 1000 for s in shares.values())
    assert shares["points"].fraction >= 0.95 and shares["mesh"].fraction >= 0.95
    # the backdrop renders empty: opacity of the training views' pure backdrop pixels (1/4 scale)
    depth = pipe.result("export_depth").path
    accs = []
    for view in DepthIndex.load(depth / "depth.json").views:
        if view.role == "train":
            fg = loader.foreground(next(f for f in loader.world.frames if f.name == view.name)).astype(np.float32)
            backdrop = cv2.resize(fg, (view.width, view.height), interpolation=cv2.INTER_AREA) == 0.0
            accs.append(np.load(depth / "depth" / f"{view.stem}.acc.npy")[backdrop])
    assert float(np.mean(np.concatenate(accs))) < 0.05
