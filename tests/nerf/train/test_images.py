"""Held-out splits, and the training images from the ingest and undistort folders: alpha compositing,
grey images, size checks, and the pixel set the trainer draws rays from."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nerfpipe.geometry.cameras import CameraSet, Frame
from nerfpipe.imaging.png import write_png
from nerfpipe.nerf.train.images import ImageLoader, split_views
from nerfpipe.pipeline.errors import StageError
from tests.nerf.scenes import loader_of


def world_of(splits: list[str | None]) -> CameraSet:
    frames = [Frame(f"img{i:02d}.png", 1, np.eye(4), s) for i, s in enumerate(splits)]
    return CameraSet({}, frames)


def test_held_out_views_follow_the_split_else_every_eighth() -> None:
    with_val = world_of(["train"] * 6 + ["val"] * 4)
    views = split_views(with_val)
    assert [f.name for f in views.heldout] == [f"img{i:02d}.png" for i in range(6, 10)]
    assert len(views.train) == 6 and views.rule == "the capture's val split"

    test_beats_val = world_of(["train"] * 4 + ["val"] * 2 + ["test"] * 3)
    assert [f.split for f in split_views(test_beats_val).heldout] == ["test"] * 3

    plain = world_of([None] * 17)
    views = split_views(plain, holdout_every=8)
    assert [f.name for f in views.heldout] == ["img00.png", "img08.png", "img16.png"]
    assert len(views.train) == 14 and not {f.name for f in views.train} & {f.name for f in views.heldout}

    subset = split_views(plain, train_images=4, eval_stride=2)
    assert [f.name for f in subset.train] == ["img01.png", "img05.png", "img11.png", "img15.png"]  # train[round(linspace(0, 13, 4))]
    assert [f.name for f in subset.heldout] == ["img00.png", "img16.png"]
    with pytest.raises(StageError, match="no training images left"):
        split_views(world_of([None]), holdout_every=1)


def test_images_come_from_their_folder_composited_onto_the_background(image_folders) -> None:
    loader = loader_of(image_folders)
    a, grey, b = (loader.image(f) for f in loader.world.frames)
    # 0.2 red over the blue backdrop: (0.2, 0, 0.8)
    assert a.shape == (8, 12, 3) and a.dtype == np.float32 and a[0, 0] == pytest.approx([0.2, 0.0, 0.8], abs=1e-6)
    assert grey[1, 2] == pytest.approx([128 / 255] * 3) and b.min() == 1.0  # b from undistort's folder
    plain = loader_of(image_folders, background="none").image(loader.world.frames[0])
    assert plain[0, 0] == pytest.approx([1.0, 0.0, 0.0])  # no alpha background: the colour as it is


def test_the_pixel_set_holds_every_pixel_with_its_camera_and_bounds(image_folders) -> None:
    loader = loader_of(image_folders)
    pixels = loader.pixel_set(loader.world.frames[1:])
    assert pixels.rgb.shape == (192, 3) and pixels.uv.shape == (192, 2)  # two 12x8 images
    assert pixels.image.tolist() == [0] * 96 + [1] * 96
    assert pixels.intrinsics.tolist() == [[10.0, 10.0, 6.0, 4.0]] * 2
    assert pixels.near.tolist() == [2.0, 3.0] and pixels.far.tolist() == [6.0, 7.0]
    torch.testing.assert_close(pixels.c2w, torch.eye(4).expand(2, 4, 4))


def test_a_constant_backdrop_gives_each_pixel_its_foreground_alpha(image_folders) -> None:
    # grey.png becomes the blue backdrop (one border pixel 0.08 off it, within the tolerance 0.1) around a
    # red ring, rows 2-5 and columns 3-7, whose 2x3 inside is blue too: enclosed, but GrabCut gives it to the
    # backdrop (nerfpipe.imaging.masks.object_mask): a hole through the ring, not a blue part of it
    pixels = np.zeros((8, 12, 3), np.uint8)
    pixels[..., 2] = 255
    pixels[0, 0] = (20, 0, 255)
    pixels[2:6, 3:8] = (255, 0, 0)
    pixels[3:5, 4:7] = (0, 0, 255)
    write_png(image_folders["images"] / "grey.png", pixels)
    loader = loader_of(image_folders, background="color", tolerance=0.1)
    grey = loader.world.frames[1]
    expected = np.zeros((8, 12), bool)
    expected[2:6, 3:8] = True
    expected[3:5, 4:7] = False
    np.testing.assert_array_equal(loader.foreground(grey), expected)
    np.testing.assert_array_equal(loader.image(grey), pixels / np.float32(255))  # the photo itself, not masked
    assert loader.alpha(grey) is None and not loader.alpha(loader.world.frames[0]).any()  # a.png: alpha 0.2 < 0.5
    # a.png is red (its alpha is not used against a colour backdrop): all foreground
    pixel_set = loader.pixel_set(loader.world.frames[:2])
    alpha = pixel_set.alpha
    assert alpha.dtype == torch.float32 and alpha.tolist() == [1.0] * 96 + expected.reshape(-1).astype(float).tolist()
    # no masks without a constant backdrop, or from a scene.json that did not record its tolerance
    assert loader_of(image_folders).pixel_set(loader.world.frames).alpha is None
    assert loader_of(image_folders, background="color").pixel_set(loader.world.frames).alpha is None


def test_silhouettes_come_from_alpha_or_the_backdrop_masks(image_folders) -> None:
    loader = loader_of(image_folders)  # alpha: a.png has alpha (0.2 everywhere, below 0.5), the others none
    a = loader.world.frames[0]
    only_a = loader.silhouettes([a])
    assert len(only_a.masks) == 1 and only_a.masks[0].shape == (8, 12) and not only_a.masks[0].any()
    assert only_a.intrinsics.tolist() == [[10.0, 10.0, 6.0, 4.0]] and only_a.c2ws.tolist() == [np.eye(4).tolist()]
    assert loader.silhouettes(loader.world.frames) is None  # a photo without alpha has no silhouette to give
    assert loader_of(image_folders, background="none").silhouettes(loader.world.frames) is None
    pixels = np.zeros((8, 12, 3), np.uint8)
    pixels[..., 2] = 255
    pixels[2:6, 3:8] = (255, 0, 0)
    write_png(image_folders["images"] / "grey.png", pixels)
    backdrop = loader_of(image_folders, background="color", tolerance=0.1)
    masks = backdrop.silhouettes(backdrop.world.frames[:2]).masks
    assert masks[0].all() and masks[1].sum() == 20 and masks[1][2:6, 3:8].all()  # red a.png; the red block
    assert backdrop.foreground(backdrop.world.frames[1]) is masks[1]  # GrabCut once a photo


def test_an_image_of_another_size_than_its_camera_is_an_error(image_folders) -> None:
    loader = loader_of(image_folders, width=13)
    with pytest.raises(StageError, match="is 12x8 but its camera is 13x8; rerun with --force undistort"):
        loader.image(loader.world.frames[0])


def test_the_train_stages_inputs_make_the_same_loader(image_folders, tmp_path) -> None:
    from nerfpipe.pipeline.stage import StageInputs

    explicit = loader_of(image_folders)
    (tmp_path / "world").mkdir()
    explicit.world.save(tmp_path / "world")
    explicit.bounds.save(tmp_path / "bounds.json")
    explicit.scene.save(tmp_path / "scene.json")
    inputs = StageInputs({**image_folders, "world": tmp_path / "world", "bounds": tmp_path / "bounds.json",
                          "scene": tmp_path / "scene.json"}, tmp_path)
    loaded = ImageLoader.from_inputs(inputs)
    assert loaded.bounds == explicit.bounds and loaded.scene == explicit.scene and loaded.near_far == explicit.near_far
    frame = loaded.world.frames[0]
    np.testing.assert_array_equal(loaded.image(frame), explicit.image(frame))
