"""Score a run's trained model on some of its training views and on its held-out views, the same way.

Run by hand from the repository root:

    python scripts/eval_views.py runs/beer --scale 0.29 --views 5
    python scripts/eval_views.py runs/beer --scale 0.25 --views 9 --thirds

A field that scores its training views far above its held-out ones generalizes badly between photos
(floaters, pose errors); one that scores both alike underfits. It renders every ``len(train) / views``-th
training view and the first ``views`` held-out views at ``scale`` of their size with the train stage's own
evaluation (``nerfpipe.nerf.train.evaluation.evaluate``), and writes them beside their photos in ``--out``. With
``--thirds``, it also prints the PSNR of each kind's top thirds and of the rest, the squared error pooled over
the views (a phone capture's walls and sky are in the top third, its subject and floor below).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from nerfpipe.artifacts import Bounds, SceneDecisions, ViewSplit
from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.imaging.png import read_png
from nerfpipe.nerf.train.evaluation import evaluate
from nerfpipe.nerf.train.images import ImageLoader
from nerfpipe.nerf.model import RadianceModel


def result_of(run: Path, stage: str) -> Path:
    """The newest result folder of ``stage`` in ``run``."""
    folders = sorted((run / "stages" / stage).glob("*/manifest.json"), key=lambda p: p.stat().st_mtime)
    if not folders:
        raise SystemExit(f"{run}: no {stage} result; run nerfpipe run first")
    return folders[-1].parent


def unit(pixels: np.ndarray) -> np.ndarray:
    """8- or 16-bit pixels as float64 in [0, 1]."""
    return pixels.astype(np.float64) / np.iinfo(pixels.dtype).max


def thirds(folder: Path) -> tuple[float, float]:
    """PSNR of the top thirds and of the lower two thirds of the ``*.render.png`` in ``folder`` against their
    ``*.gt.png``, the squared error pooled over the views."""
    top, rest = [], []
    for gt_path in sorted(folder.glob("*.gt.png")):
        gt, render = (unit(read_png(p)) for p in (gt_path, gt_path.with_name(gt_path.name.replace(".gt.", ".render."))))
        error = ((gt[..., :3] - render[..., :3]) ** 2).mean(axis=-1)
        cut = error.shape[0] // 3
        top.append(error[:cut].mean())
        rest.append(error[cut:].mean())
    return -10.0 * np.log10(np.mean(top)), -10.0 * np.log10(np.mean(rest))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("--scale", type=float, default=0.25, help="share of each view's width and height")
    parser.add_argument("--views", type=int, default=5, help="views of each kind")
    parser.add_argument("--out", type=Path, default=Path("/tmp/eval_views"))
    parser.add_argument("--thirds", action="store_true", help="also the PSNR of the top thirds and of the rest")
    parser.add_argument("--train", type=Path, help="the train result folder to score (default: the run's newest)")
    args = parser.parse_args()
    train = args.train or result_of(args.run, "train")
    undistort = result_of(args.run, "undistort")
    world = CameraSet.load(result_of(args.run, "bounds") / "world")
    loader = ImageLoader(result_of(args.run, "ingest") / "images", undistort / "images", undistort / "pinhole", world,
                         Bounds.load(result_of(args.run, "bounds") / "bounds.json"),
                         SceneDecisions.load(result_of(args.run, "scene") / "scene.json"))
    model = RadianceModel.load(train, torch.device("cpu"))
    split = ViewSplit.load(train / "views.json")
    by_name = {f.name: f for f in world.frames}
    stride = max(len(split.train) // args.views, 1)
    for kind, names in (("train", split.train[::stride][:args.views]), ("heldout", split.heldout[:args.views])):
        scored = evaluate(model, loader, [by_name[n] for n in names], args.out / kind, 8192, scale=args.scale)
        views = ", ".join(f"{v['name']} {v['psnr']:.2f}" for v in scored["views"])
        print(f"{kind}: {scored['psnr']:.2f} dB / SSIM {scored['ssim']:.3f} ({views})")
        if args.thirds:
            print("{}: top thirds {:.2f} dB, lower two thirds {:.2f} dB".format(kind, *thirds(args.out / kind)))


if __name__ == "__main__":
    main()
