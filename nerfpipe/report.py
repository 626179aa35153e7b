"""The run report: one HTML page, with its PNGs beside it, that shows what a run did and how well.

Sections, each present when its stage has a result for the run's current settings: the capture
(thumbnails), structure from motion (summary and a plot of cameras and sparse points), the scene
decisions with their evidence, training (loss and PSNR against wall time, held-out renders beside
their ground truth), depth previews, screenshots of the mesh and point cloud, the novel-view videos,
and the time each stage took.
"""

from __future__ import annotations

import html
import json
import shutil
from pathlib import Path
from typing import Any, Sequence

import numpy as np

THUMB_SIDE = 160
MAX_THUMBS = 48
MAX_DEPTH_PREVIEWS = 12


def _img(src: str, caption: str = "", width: int | None = None) -> str:
    size = f' width="{width}"' if width else ""
    cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    return f'<figure><img src="{html.escape(src)}" alt="{html.escape(caption or src)}"{size}>{cap}</figure>'


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _write_png(path: Path, rgb: np.ndarray) -> None:
    import cv2

    if not cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1])):
        raise OSError(f"could not write {path}")


def _thumbnail(source: Path, target: Path) -> bool:
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


def _plot_cameras(path: Path, centers: np.ndarray, axes: np.ndarray, points: np.ndarray | None,
                  colors: np.ndarray | None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(6, 5), dpi=100)
    ax = fig.add_subplot(projection="3d")
    if points is not None and len(points):
        keep = np.random.default_rng(0).permutation(len(points))[:20000]
        ax.scatter(*points[keep].T, s=0.5, c=None if colors is None else colors[keep], alpha=0.6)
    ax.scatter(*centers.T, s=12, c="tab:red", label="cameras")
    span = float(np.ptp(centers, axis=0).max()) if len(centers) > 1 else 1.0
    ax.quiver(*centers.T, *(axes * 0.1 * span).T, color="tab:red", linewidth=0.8)
    everything = centers if points is None or not len(points) else np.concatenate([centers, points[keep]])
    lo, hi = np.percentile(everything, 1, axis=0), np.percentile(everything, 99, axis=0)
    mid, half = (lo + hi) / 2, float((hi - lo).max()) / 2 or 1.0
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


def _plot_training(path: Path, records: list[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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


def write_report(run_dir: Path, stages: Sequence[Any] | None = None) -> Path:
    """Write ``run_dir/report/index.html`` and its images; return the page's path."""
    from nerfpipe.geometry.cameras import CameraSet
    from nerfpipe.pipeline import Pipeline
    from nerfpipe.stages import default_stages
    from nerfpipe.artifacts import view_file_stem

    pipe = Pipeline.from_run_dir(list(stages) if stages is not None else default_stages(), run_dir)
    folder = run_dir / "report"
    if folder.exists():
        shutil.rmtree(folder)
    (folder / "img").mkdir(parents=True)
    statuses = {s.name: s for s in pipe.status()}
    results = {name: s.result for name, s in statuses.items() if s.state == "fresh" and s.result is not None}
    sections: list[str] = []
    sfm_cameras = None
    if "sfm" in results:
        sfm_cameras = CameraSet.load(results["sfm"].path / pipe.dag.stages["sfm"].provides["sfm_model"])

    def section(title: str, body: str) -> None:
        sections.append(f"<section><h2>{html.escape(title)}</h2>{body}</section>")

    # -- capture ---------------------------------------------------------------------------------
    if "ingest" in results:
        ingest = results["ingest"]
        records = json.loads((ingest.path / "images.json").read_text(encoding="utf-8"))["images"]
        figures = []
        for i, record in enumerate(records[:MAX_THUMBS]):
            target = folder / "img" / f"thumb_{i:03d}.png"
            if _thumbnail(ingest.path / "images" / record["name"], target):
                figures.append(_img(f"img/{target.name}", record["name"]))
        more = f"<p>and {len(records) - MAX_THUMBS} more</p>" if len(records) > MAX_THUMBS else ""
        section("Capture", f"<p>{len(records)} photos from <code>{html.escape(str(pipe.source))}</code></p>"
                f"<div class='grid'>{''.join(figures)}</div>{more}")

    # -- structure from motion -------------------------------------------------------------------
    if sfm_cameras is not None:
        sfm = results["sfm"]
        lines = pipe.dag.stages["sfm"].describe(sfm.path, sfm.manifest)
        cameras = sfm_cameras
        centers = np.array([f.center for f in cameras.frames]) if cameras.frames else np.zeros((0, 3))
        axes = np.array([np.asarray(f.c2w)[:3, 2] for f in cameras.frames]) if cameras.frames else np.zeros((0, 3))
        points = colors = None
        if cameras.points is not None and len(cameras.points.xyz):
            points = np.asarray(cameras.points.xyz)
            rgb = np.asarray(cameras.points.rgb, dtype=np.float64)
            colors = rgb / 255.0 if rgb.max() > 1 else rgb
        body = "".join(f"<p>{html.escape(line)}</p>" for line in lines)
        if len(centers):
            _plot_cameras(folder / "img" / "sfm.png", centers, axes, points, colors)
            body += _img("img/sfm.png", "camera centres, viewing axes and sparse points (SfM frame)")
        section("Structure from motion", body)

    # -- scene decisions -------------------------------------------------------------------------
    if "scene" in results:
        scene = json.loads((results["scene"].path / "scene.json").read_text(encoding="utf-8"))
        rows = [(key, json.dumps(entry["value"]), entry.get("evidence", ""), "yes" if entry.get("overridden") else "")
                for key, entry in scene.items() if isinstance(entry, dict) and "value" in entry]
        section("Scene decisions", _table(("decision", "value", "evidence", "overridden"), rows))

    # -- training --------------------------------------------------------------------------------
    if "train" in results:
        train = results["train"]
        body = "".join(f"<p>{html.escape(line)}</p>" for line in pipe.dag.stages["train"].describe(train.path, train.manifest))
        log = train.path / "metrics.jsonl"
        records = [json.loads(line) for line in log.read_text(encoding="utf-8").splitlines() if line.strip()] if log.exists() else []
        if records:
            _plot_training(folder / "img" / "training.png", records)
            body += _img("img/training.png", "training loss and PSNR against wall time")
        metrics = json.loads((train.path / "metrics.json").read_text(encoding="utf-8"))
        figures = []
        for view in metrics.get("views", []):
            stem = view_file_stem(view["name"])
            pair = []
            for suffix in ("render", "gt"):
                source = train.path / "eval" / f"{stem}.{suffix}.png"
                if source.exists():
                    shutil.copy2(source, folder / "img" / f"eval_{stem}.{suffix}.png")
                    pair.append(_img(f"img/eval_{stem}.{suffix}.png", f"{view['name']}: {suffix}"))
            if pair:
                figures.append(f"<div class='pair'>{''.join(pair)}<p>PSNR {view['psnr']:.2f} dB, "
                               f"SSIM {view['ssim']:.3f}</p></div>")
        if figures:
            body += "<h3>Held-out views: render beside ground truth</h3>" + "".join(figures)
        section("Training", body)

    # -- depth -----------------------------------------------------------------------------------
    if "export_depth" in results:
        depth = results["export_depth"]
        index = json.loads((depth.path / "depth.json").read_text(encoding="utf-8"))
        figures = []
        step = max(1, len(index["views"]) // MAX_DEPTH_PREVIEWS)
        for view in index["views"][::step][:MAX_DEPTH_PREVIEWS]:
            source = depth.path / "depth" / f"{view['stem']}.preview.png"
            if source.exists():
                shutil.copy2(source, folder / "img" / f"depth_{view['stem']}.png")
                figures.append(_img(f"img/depth_{view['stem']}.png", f"{view['name']} ({view['role']})"))
        lines = pipe.dag.stages["export_depth"].describe(depth.path, depth.manifest)
        section("Depth", "".join(f"<p>{html.escape(line)}</p>" for line in lines)
                + "<p>disparity, near red to far blue; black where the field is transparent</p>"
                + f"<div class='grid'>{''.join(figures)}</div>")

    # -- geometry --------------------------------------------------------------------------------
    shots = []
    view_cameras = None
    for stage, artifact, label in (("export_mesh", "mesh", "mesh"), ("export_points", "points", "point cloud")):
        if stage not in results:
            continue
        from nerfpipe.export.screenshot import auto_view, cameras_of, load_mesh, load_points, screenshot

        path = results[stage].path / pipe.dag.stages[stage].provides[artifact]
        if view_cameras is None:
            view_cameras = cameras_of(sfm_cameras) if sfm_cameras is not None else []
        cameras = view_cameras
        geometry = {"mesh": load_mesh(path)} if artifact == "mesh" else {"points": load_points(path)}
        # framed on the geometry, seen from the cameras' side: framing the camera ring too leaves the object tiny
        box = next(iter(geometry.values())).get_axis_aligned_bounding_box()
        view = auto_view(np.asarray(box.min_bound), np.asarray(box.max_bound), cameras, 640, 480)
        _write_png(folder / "img" / f"{artifact}.png", screenshot(cameras=cameras, view=view, **geometry))
        lines = pipe.dag.stages[stage].describe(results[stage].path, results[stage].manifest)
        shots.append(_img(f"img/{artifact}.png", f"{label}: " + "; ".join(lines)))
    if shots:
        section("Mesh and point cloud", f"<div class='grid'>{''.join(shots)}</div>"
                "<p>Files in the SfM frame; open them with <code>nerfpipe view RUN_DIR mesh|points</code>.</p>")

    # -- novel views -----------------------------------------------------------------------------
    if "render" in results:
        render = results["render"]
        body = "".join(f"<p>{html.escape(line)}</p>" for line in pipe.dag.stages["render"].describe(render.path, render.manifest))
        frames = sorted((render.path / "frames").glob("rgb_*.png"))
        depths = sorted((render.path / "frames").glob("depth_*.png"))
        for name, source in (("render_first.png", frames[:1]), ("render_depth_first.png", depths[:1])):
            if source:
                shutil.copy2(source[0], folder / "img" / name)
                body += _img(f"img/{name}", "first frame")
        for video in ("render.mp4", "depth.mp4"):
            if (render.path / video).exists():
                shutil.copy2(render.path / video, folder / video)
                body += f'<p><a href="{video}">{video}</a></p>'
        section("Novel views", body)

    # -- benchmark (nerfpipe bench) ---------------------------------------------------------------
    bench = run_dir / "bench" / "bench.json"
    if bench.is_file():
        from nerfpipe.bench.report import psnr_at

        doc = json.loads(bench.read_text(encoding="utf-8"))
        marks = doc["checkpoints"]
        header = ("configuration", *(f"{m:.0f} s" for m in marks), "samples/ray", "samples/s", "render s/image", "peak memory")
        rows = []
        for r in doc["results"]:
            cells = [psnr_at(r, m) for m in marks]
            rows.append((r["name"], *("–" if c is None else f"{c['psnr']:.2f} dB / {c['ssim']:.3f}" for c in cells),
                         f"{r['samples_per_ray']:.1f}", f"{r['samples_per_s']:,}",
                         "–" if r["render_seconds_per_image"] is None else f"{r['render_seconds_per_image']:.2f}",
                         f"{r['peak_memory_bytes'] / 2**30:.2f} GiB"))
        body = "<p>held-out PSNR / SSIM after each training time (nerfpipe bench)</p>" + _table(header, rows)
        plot = bench.parent / "psnr_time.png"
        if plot.is_file():
            shutil.copyfile(plot, folder / "img" / "bench_psnr_time.png")
            body += _img("img/bench_psnr_time.png", "held-out PSNR against training time")
        section("What accuracy costs in time", body)

    # -- timings ---------------------------------------------------------------------------------
    rows = []
    for name in pipe.dag.order:
        s = statuses[name]
        seconds = s.result.manifest.get("timings", {}).get("seconds") if s.result is not None else None
        rows.append((name, s.state, "" if seconds is None else f"{seconds:.1f} s", "; ".join(s.reasons)))
    total = sum(r.manifest.get("timings", {}).get("seconds", 0.0) for r in results.values())
    section("Time per stage", _table(("stage", "state", "time", "note"), rows) + f"<p>total of fresh stages: {total:.0f} s</p>")

    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>nerfpipe report: {html.escape(run_dir.name)}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }}
h2 {{ border-bottom: 1px solid #ccc; padding-bottom: .2em; }}
figure {{ display: inline-block; margin: .3em; text-align: center; font-size: .8em; }}
figure img {{ max-width: 100%; }}
.grid {{ display: flex; flex-wrap: wrap; }}
.pair {{ display: inline-block; margin: .5em; }}
table {{ border-collapse: collapse; font-size: .9em; }}
td, th {{ border: 1px solid #ddd; padding: .3em .6em; text-align: left; vertical-align: top; }}
</style></head><body>
<h1>nerfpipe report: {html.escape(str(run_dir))}</h1>
{''.join(sections)}
</body></html>
"""
    (folder / "index.html").write_text(page, encoding="utf-8")
    return folder / "index.html"
