"""The report's own pictures: photo thumbnails, the SfM plot, the training curves, PNGs of RGB arrays."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

THUMB_SIDE = 160  # pixels, the longer side of a capture thumbnail
MAX_PLOTTED_POINTS = 20000


def thumbnail(source: Path, target: Path) -> bool:
    """Write a PNG of ``source`` no larger than ``THUMB_SIDE``, transparency flattened onto white; False
    when ``source`` cannot be read or ``target`` written."""
    import cv2

    image = cv2.imread(str(source), cv2.IMREAD_UNCHANGED)
    if image is None:
        return False
    if image.dtype == np.uint16:
        image = (image / 257).astype(np.uint8)
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    elif image.shape[2] == 4:
        alpha = image[..., 3:].astype(np.float32) / 255
        image = (image[..., :3] * alpha + 255 * (1 - alpha)).astype(np.uint8)
    h, w = image.shape[:2]
    scale = THUMB_SIDE / max(h, w)
    if scale < 1:
        image = cv2.resize(image, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)
    return bool(cv2.imwrite(str(target), image))


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_frame(centers: np.ndarray, points: np.ndarray | None) -> tuple[np.ndarray, float]:
    """The centre and half side of the cube a camera plot shows: every camera (N, 3), and the sparse points
    (P, 3) between their 1st and 99th percentiles, with a 5 % margin."""
    lo, hi = centers.min(axis=0), centers.max(axis=0)
    if points is not None and len(points):
        lo = np.minimum(lo, np.percentile(points, 1, axis=0))
        hi = np.maximum(hi, np.percentile(points, 99, axis=0))
    return (lo + hi) / 2, 1.05 * float((hi - lo).max()) / 2 or 1.0


def plot_cameras(path: Path, centers: np.ndarray, axes: np.ndarray, points: np.ndarray | None,
                 colors: np.ndarray | None) -> None:
    """A 3D plot of camera centres (N, 3) with their viewing axes (N, 3) and, when given, sparse
    points (P, 3) in their colours (P, 3) in [0, 1]; framed on every camera first, then on the 1st..99th
    percentile of the points (a few far-off points do not shrink the scene, and no camera is cut off)."""
    plt = _pyplot()
    fig = plt.figure(figsize=(6, 5), dpi=100)
    ax = fig.add_subplot(projection="3d")
    if points is not None and len(points):
        keep = np.random.default_rng(0).permutation(len(points))[:MAX_PLOTTED_POINTS]
        ax.scatter(*points[keep].T, s=0.5, c=None if colors is None else colors[keep], alpha=0.6,
                   label=f"{len(points):,} sparse points, in their colours"
                         + (f" ({len(keep):,} shown)" if len(keep) < len(points) else ""))
    ax.scatter(*centers.T, s=12, c="tab:red", label="cameras")
    span = float(np.ptp(centers, axis=0).max()) if len(centers) > 1 else 1.0
    ax.quiver(*centers.T, *(axes * 0.1 * span).T, color="tab:red", linewidth=0.8)
    mid, half = plot_frame(centers, points[keep] if points is not None and len(points) else None)
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_depth_scale(path: Path, steps: int = 256) -> None:
    """The depth previews' colour scale as a bar: the colours ``nerfpipe.export.depth.depth_preview`` gives,
    from a view's near (red, left) to its far (blue, right), linear in disparity (each view's own near and far
    are in its caption)."""
    from nerfpipe.export.depth import depth_preview

    near, far = 1.0, 16.0
    depth = 1.0 / np.linspace(1.0 / near, 1.0 / far, steps)
    bar = depth_preview(np.tile(depth, (24, 1)), np.ones((24, steps)), near, far)
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 0.9), dpi=100)
    ax.imshow(bar, aspect="auto", extent=(0.0, 1.0, 0.0, 1.0))
    ax.set_xticks([0.0, 0.5, 1.0])
    ax.set_xticklabels(["near", "halfway in 1 / depth", "far"])
    ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_training(path: Path, records: list[dict[str, Any]]) -> None:
    """Training loss (log scale) and PSNR against wall time, from the records of ``metrics.jsonl``."""
    plt = _pyplot()
    wall = [r["wall"] for r in records]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.5), dpi=100)
    left.plot(wall, [r["loss"] for r in records])
    left.set_yscale("log")
    left.set_xlabel("wall time (s)")
    left.set_ylabel("training loss (MSE)")
    right.plot(wall, [r["psnr"] for r in records], color="tab:green")
    right.set_xlabel("wall time (s)")
    right.set_ylabel("training PSNR (dB)")
    for a in (left, right):
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_per_image(path: Path, per_image: dict[str, dict[str, Any]]) -> None:
    """Per training photo, in order: how far its camera moved (degrees, and the centre's move in world units)
    and its learned exposure (stops per channel), from ``hints.per_image`` of the train stage's cameras;
    a panel for each of the two that the photos have."""
    plt = _pyplot()
    names = list(per_image)
    moved = [n for n in names if "rotation_deg" in per_image[n]]
    exposed = [n for n in names if "exposure_stops" in per_image[n]]
    panels = [p for p in (("moved", moved), ("exposure", exposed)) if p[1]]
    fig, axes = plt.subplots(len(panels), 1, figsize=(10, 2.6 * len(panels)), dpi=100, squeeze=False)
    for ax, (kind, keys) in zip(axes[:, 0], panels):
        x = np.arange(len(keys))
        if kind == "moved":
            ax.bar(x, [per_image[n]["rotation_deg"] for n in keys], color="tab:red")
            ax.set_ylabel("camera turned (deg)")
            twin = ax.twinx()
            twin.plot(x, [per_image[n]["translation"] for n in keys], "k.", markersize=3)
            twin.set_ylabel("centre moved (world units)")
        else:
            stops = np.array([per_image[n]["exposure_stops"] for n in keys])
            for channel, color in enumerate(("tab:red", "tab:green", "tab:blue")):
                ax.plot(x, stops[:, channel], ".", color=color, markersize=4)
            ax.axhline(0.0, color="grey", linewidth=0.5)
            ax.set_ylabel("exposure (stops, R G B)")
        ax.set_xlabel("training photo (in order)")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
