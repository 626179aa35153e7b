"""nerfpipe.open: a finished run's cameras in the SfM frame, renders from them (and from a camera of one's own)
whose depth agrees with the exported depth maps, its exports and figures; and the README's example, run as it
is written."""

from __future__ import annotations

import os
import re

import numpy as np
import pytest

import nerfpipe
from nerfpipe import Pipeline, default_stages
from nerfpipe.cli.exports import refresh_exports
from nerfpipe.geometry.cameras import CameraSet
from tests.helpers import REPO, TEMPLE

SHORT = {"ingest": {"max_size": "160"},
         "train": {"steps": "150", "checkpoint_every": "1000", "per_image.refine_poses": "off"}}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("api") / "temple"
    pipe = Pipeline(default_stages(), TEMPLE, folder, "draft", SHORT)
    pipe.run(until="export_depth")
    refresh_exports(pipe)
    return folder


@pytest.mark.slow
def test_a_run_gives_its_cameras_renders_exports_and_figures(run_dir):
    run = nerfpipe.open(run_dir)
    assert len(run.names) == 16 and set(run.heldout) <= set(run.names) and run.heldout
    # the cameras in the SfM frame: the par file's own poses (not refined here), not the normalized world's
    sfm = CameraSet.load(next((run_dir / "stages" / "sfm").glob("*/model")))
    for frame in run.cameras.frames:
        assert np.abs(frame.c2w - next(f for f in sfm.frames if f.name == frame.name).c2w).max() < 1e-6
    view = run.render(run.heldout[0], size=80)
    assert view.rgb.shape == (60, 80, 3) and view.depth.shape == view.opacity.shape == (60, 80)
    assert view.rgb.dtype == np.float32 and 0 <= view.rgb.min() <= view.rgb.max() <= 1
    # depth in SfM units, as the exported depth maps (depth/index.json lists the same view at its own size)
    from nerfpipe.export.depth import DepthIndex

    index = DepthIndex.load(run_dir / "exports" / "depth" / "index.json")
    exported = next(v for v in index.views if v.name == run.heldout[0])
    mine = run.render(run.heldout[0], size=(exported.width, exported.height))
    theirs = np.load(run_dir / "exports" / "depth" / f"{exported.stem}.depth.npy")
    solid = (mine.opacity > 0.9) & (np.load(run_dir / "exports" / "depth" / f"{exported.stem}.acc.npy") > 0.9)
    assert solid.mean() > 0.05 and np.abs(mine.depth - theirs)[solid].max() < 1e-3 * theirs[solid].max()
    # a camera of one's own: the same view, given as a matrix and a camera (its near and far then from where it
    # stands, not the photo's, so the samples along a ray differ a little)
    frame = run.cameras.frames[run.names.index(run.heldout[0])]
    again = run.render((frame.c2w, run.cameras.camera_of(frame)), size=80)
    assert np.abs(again.rgb - view.rgb).mean() < 2e-3 and np.abs(again.opacity - view.opacity).mean() < 5e-3
    assert run.photo(0).shape[2] == 3 and run.exports["transforms.json"].is_file()
    assert run.metrics["steps"] == 150 and run.metrics["psnr"] > 10
    with pytest.raises(KeyError, match="no view named 'nope.png'"):
        run.render("nope.png")


@pytest.mark.slow
def test_the_readme_example_runs_as_written(run_dir, tmp_path, monkeypatch):
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    code = next(block for block in re.findall(r"```python\n(.*?)```", readme, re.S) if "nerfpipe.open" in block)
    assert len(code.strip().splitlines()) <= 5
    monkeypatch.chdir(tmp_path)
    os.symlink(run_dir.parent, tmp_path / "runs")  # the example opens runs/temple, as the first command names it
    exec(compile(code, "README.md", "exec"), {})
    from PIL import Image

    picture = np.asarray(Image.open(tmp_path / "heldout.png"))
    assert picture.shape == (120, 320, 3)  # the photo and the render side by side, at 160x120
