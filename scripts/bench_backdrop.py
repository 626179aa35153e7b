"""Backdrop benchmark: after `nerfpipe run`, are the exports only the object, and how good are the renders?

Run by hand from the repository root on a finished run directory:

    python -m nerfpipe run samples/templeSparseRing --out /tmp/tA
    python scripts/bench_backdrop.py /tmp/tA

Prints the held-out PSNR and SSIM of the train stage and, for the exported point cloud and the mesh
vertices (both written in the SfM frame, taken to the normalized world with ``Bounds.to_world``), the
share of (point, training view) pairs projecting inside the image that land on the view's foreground
grown by 3 px (``nerfpipe.export.foreground``): everything but the constant backdrop, or alpha >= 0.5.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from nerfpipe import default_stages
from nerfpipe.artifacts import Bounds, ViewSplit
from nerfpipe.export.foreground import foreground_share, training_views
from nerfpipe.export.mesh import read_mesh
from nerfpipe.export.points import read_ply
from nerfpipe.nerf.train.images import ImageLoader
from nerfpipe.pipeline import Pipeline


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--dilation", type=int, default=3, help="grow the foreground by this many pixels")
    args = parser.parse_args()
    pipe = Pipeline.from_run_dir(default_stages(), args.run_dir)
    train = pipe.result("train")
    metrics = json.loads((train.path / "metrics.json").read_text())
    print(f"held-out PSNR {metrics['psnr']:.2f} dB, SSIM {metrics['ssim']:.3f} over {metrics['heldout']} views "
          f"({metrics.get('protocol', '')})")
    loader = ImageLoader.from_inputs(pipe.stage_inputs("train"))
    views = training_views(loader, ViewSplit.load(train.path / "views.json").train)
    to_world = np.asarray(Bounds.load(pipe.stage_inputs("train")["bounds"]).to_world)
    exports = {
        "points": read_ply(pipe.result("export_points").path / "points.ply").xyz,
        "mesh vertices": read_mesh(pipe.result("export_mesh").path / "mesh.ply").vertices,
    }
    for what, xyz in exports.items():
        share = foreground_share(xyz, views, args.dilation, to_world)
        print(f"{what}: {len(xyz)}; {100 * share.fraction:.2f} % of {share.pairs} (point, training view) pairs "
              f"inside the image land on the foreground grown by {args.dilation} px (target >= 95 %)")


if __name__ == "__main__":
    main()
