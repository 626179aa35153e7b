"""The sections of the report, one builder each, in page order (``SECTIONS``).

A builder takes the gathered ``RunData``, writes the pictures it shows into ``run.img`` and returns its
``<section>``, or None when its stage has no fresh result (the stage table is always there).
"""

from __future__ import annotations

import html
import json
import shutil
from pathlib import Path
from typing import Any, Callable

import numpy as np

from nerfpipe.artifacts import ImageIndex, SceneDecisions, view_file_stem
from nerfpipe.imaging.png import write_png
from nerfpipe.report.data import RunData
from nerfpipe.report.images import plot_cameras, plot_depth_scale, plot_per_image, plot_training, thumbnail
from nerfpipe.report.markup import figure, grid, paragraphs, section, table, video

MAX_THUMBS = 48
MAX_DEPTH_PREVIEWS = 12
SHOT_WIDTH, SHOT_HEIGHT = 640, 480  # pixels, the mesh and point cloud screenshots
VIDEO_WIDTH = 480  # pixels on the page: the renders are small, the browser scales them up


def capture(run: RunData) -> str | None:
    """Thumbnails of the first ``MAX_THUMBS`` ingested photos."""
    if "ingest" not in run.results:
        return None
    records = ImageIndex.load(run.artifact("ingest", "images_json")).records
    photos = run.artifact("ingest", "images")
    figures = []
    for i, record in enumerate(records[:MAX_THUMBS]):
        name, source = f"thumb_{i:03d}.png", photos / record.name
        if run.picture(name, f"{run.commit('ingest')} {record.name}", lambda path: thumbnail(source, path)):
            figures.append(figure(f"img/{name}", record.name))
    more = f"<p>and {len(records) - MAX_THUMBS} more</p>" if len(records) > MAX_THUMBS else ""
    return section("Capture", f"<p>{len(records)} photos from <code>{html.escape(str(run.source))}</code></p>"
                   f"{grid(figures)}{more}")


def structure_from_motion(run: RunData) -> str | None:
    """The SfM stage's summary and a plot of the camera centres, their viewing axes and the sparse points."""
    cameras = run.sfm_cameras
    if cameras is None:
        return None
    body = paragraphs(run.describe("sfm"))
    if cameras.frames:
        centers = np.array([f.center for f in cameras.frames])
        axes = np.array([np.asarray(f.c2w)[:3, 2] for f in cameras.frames])
        points = colors = None
        if cameras.points is not None and len(cameras.points.xyz):
            points = np.asarray(cameras.points.xyz)
            rgb = np.asarray(cameras.points.rgb, dtype=np.float64)
            colors = rgb / 255.0 if rgb.max() > 1 else rgb
        run.picture("sfm.png", run.commit("sfm"), lambda path: plot_cameras(path, centers, axes, points, colors))
        body += figure("img/sfm.png", "camera centres, viewing axes and sparse points (SfM frame)")
    return section("Structure from motion", body)


def scene_decisions(run: RunData) -> str | None:
    """A table of the scene decisions: value, evidence, and "yes" where the user overrode the data."""
    if "scene" not in run.results:
        return None
    decisions = SceneDecisions.load(run.artifact("scene", "scene")).decisions()
    rows = [(name, json.dumps(d.value), d.evidence, "yes" if d.overridden else "") for name, d in decisions.items()]
    return section("Scene decisions", table(("decision", "value", "evidence", "overridden"), rows))


def training(run: RunData) -> str | None:
    """The train stage's summary, its loss and PSNR curves, and each held-out render beside its ground truth."""
    if "train" not in run.results:
        return None
    body = paragraphs(run.describe("train"))
    log = run.results["train"].path / "metrics.jsonl"
    records = [json.loads(line) for line in log.read_text(encoding="utf-8").splitlines() if line.strip()] if log.exists() else []
    if records:
        run.picture("training.png", run.commit("train"), lambda path: plot_training(path, records))
        body += figure("img/training.png", "training loss and PSNR against wall time")
    cameras = run.results["train"].path / "cameras" / "cameras.json"
    per_image = json.loads(cameras.read_text(encoding="utf-8")).get("extra", {}).get("per_image") if cameras.exists() else None
    if per_image:
        run.picture("per_image.png", run.commit("train"), lambda path: plot_per_image(path, per_image))
        body += figure("img/per_image.png", "per training photo: how far refinement moved its camera, and the "
                       "exposure learned for it")
    pairs = heldout_pairs(run)
    if pairs:
        body += ("<h3>Held-out views: render, photo and their difference</h3><p>difference: |render - photo| "
                 f"per pixel, times {ERROR_GAIN} (black: equal)</p>" + "".join(pairs))
    return section("Training", body)


ERROR_GAIN = 4  # the held-out difference images, brightened: a 1/4 error is white
OVERRUN = 1.1  # a stage that took more than this times its allotment is noted in the time table


def heldout_pairs(run: RunData) -> list[str]:
    """One row per held-out view of the train stage's ``metrics.json``: its render, its photo as taken and
    their difference side by side (those that exist), with the view's PSNR and SSIM; where the score was
    taken against the photo with its backdrop masked out, both PSNRs, each said for what it is."""
    from nerfpipe.imaging.png import read_png

    metrics = json.loads(run.artifact("train", "metrics").read_text(encoding="utf-8"))
    renders = run.artifact("train", "eval")
    blocks = []
    for view in metrics.get("views", []):
        stem = view_file_stem(view["name"])
        photo = next((renders / f"{stem}.{s}.png" for s in ("photo", "gt") if (renders / f"{stem}.{s}.png").exists()),
                     None)
        row = []
        for source, caption in ((renders / f"{stem}.render.png", "render"), (photo, "photo")):
            if source is not None and source.exists():
                shutil.copy2(source, run.img / f"eval_{source.name}")
                row.append(figure(f"img/eval_{source.name}", f"{view['name']}: {caption}"))
        if len(row) == 2:
            rendered, taken = (read_png(path).astype(np.int32) for path in (renders / f"{stem}.render.png", photo))
            if rendered.shape == taken.shape:
                difference = np.abs(rendered - taken)[..., :3] * ERROR_GAIN
                write_png(run.img / f"eval_{stem}.error.png", np.clip(difference, 0, 255).astype(np.uint8))
                row.append(figure(f"img/eval_{stem}.error.png", f"{view['name']}: difference x{ERROR_GAIN}"))
        if row:
            scores = (f"PSNR {view['psnr']:.2f} dB against the photo with its backdrop masked out (the score), "
                      f"{view['psnr_photo']:.2f} dB against the photo as taken" if "psnr_photo" in view
                      else f"PSNR {view['psnr']:.2f} dB")
            blocks.append(f"<div class='row'>{''.join(row)}<p>{scores}, SSIM {view['ssim']:.3f}</p></div>")
    return blocks


def preview_views(views: list[Any], count: int) -> list[Any]:
    """Up to ``count`` of ``views`` (each with a ``role``): every held-out one (up to half of ``count``), and
    training views evenly spread over the capture for the rest, in the capture's order."""
    heldout = [v for v in views if v.role == "heldout"]
    heldout = [heldout[i] for i in np.linspace(0, len(heldout) - 1, min(len(heldout), count // 2)).round().astype(int)] \
        if heldout else []
    train = [v for v in views if v.role != "heldout"]
    left = min(count - len(heldout), len(train))
    spread = [train[i] for i in np.linspace(0, len(train) - 1, left).round().astype(int)] if left > 0 else []
    chosen = {id(v) for v in heldout + spread}
    return [v for v in views if id(v) in chosen]


def depth(run: RunData) -> str | None:
    """Disparity previews of up to ``MAX_DEPTH_PREVIEWS`` exported views: the held-out ones and training views
    evenly spread over the capture."""
    if "export_depth" not in run.results:
        return None
    from nerfpipe.export.depth import DepthIndex

    views = DepthIndex.load(run.artifact("export_depth", "depth_index")).views
    previews = run.artifact("export_depth", "depth")
    figures, shown = [], []
    for view in preview_views(views, MAX_DEPTH_PREVIEWS):
        source = previews / f"{view.stem}.preview.png"
        if source.exists():
            shutil.copy2(source, run.img / f"depth_{view.stem}.png")
            figures.append(figure(f"img/depth_{view.stem}.png", f"{view.name} ({view.role})"))
            shown.append(view)
    from nerfpipe.artifacts import Bounds
    from nerfpipe.geometry.normalize import Similarity

    to_sfm = np.asarray(Bounds.load(run.artifact("bounds", "bounds")).to_sfm) if "bounds" in run.results else np.eye(4)
    scale = Similarity.from_matrix(to_sfm).scale
    run.picture("depth_scale.png", "", plot_depth_scale)
    figures = [f.replace("</figcaption>", f", red {v.near * scale:.3g} to blue {v.far * scale:.3g} SfM units</figcaption>")
               for f, v in zip(figures, shown)]
    return section("Depth", paragraphs(run.describe("export_depth"))
                   + figure("img/depth_scale.png", "the previews' colours: linear in disparity (1 / depth) from each "
                            "view's near (red) to its far (blue); black where the field is transparent")
                   + grid(figures))


GEOMETRY = (("export_mesh", "mesh", "mesh"), ("export_points", "points", "point cloud"))  # stage, artifact, label


def mesh_and_points(run: RunData) -> str | None:
    """Screenshots of the exported mesh and point cloud, seen as the first SfM camera saw the scene."""
    shown = [(stage, artifact, label) for stage, artifact, label in GEOMETRY if stage in run.results]
    if not shown:
        return None
    from nerfpipe.export.views import cameras_of

    cameras = cameras_of(run.sfm_cameras) if run.sfm_cameras is not None else []
    shots = [geometry_shot(run, stage, artifact, label, cameras) for stage, artifact, label in shown]
    return section("Mesh and point cloud", grid(shots)
                   + "<p>Files in the SfM frame; open them with <code>nerfpipe view RUN_DIR mesh|points</code>.</p>")


def geometry_shot(run: RunData, stage: str, artifact: str, label: str, cameras: list[Any]) -> str:
    """Write ``img/{artifact}.png``, a screenshot of a mesh or point cloud artifact; return its figure."""
    from nerfpipe.export.screenshot import load_mesh, load_points, screenshot
    from nerfpipe.export.views import auto_view, photo_view

    def draw(target: Path) -> None:
        path = run.artifact(stage, artifact)
        geometry = {"mesh": load_mesh(path)} if artifact == "mesh" else {"points": load_points(path)}
        # framed on the geometry (framing the camera ring too leaves the object tiny), seen as the first photo saw
        # it, so the picture can be held against the photos
        aabb = next(iter(geometry.values())).get_axis_aligned_bounding_box()
        box = np.asarray(aabb.min_bound), np.asarray(aabb.max_bound)
        view = (photo_view(*box, cameras[0], SHOT_WIDTH, SHOT_HEIGHT) if cameras
                else auto_view(*box, [], SHOT_WIDTH, SHOT_HEIGHT))
        # no frusta: in this close view they are the few cameras behind the object, drawn over it
        write_png(target, screenshot(view=view, **geometry))

    seen_from = run.commit("sfm") if cameras else ""
    run.picture(f"{artifact}.png", f"{run.commit(stage)} {seen_from}", draw)
    return figure(f"img/{artifact}.png", f"{label}: " + "; ".join(run.describe(stage)))


def novel_views(run: RunData) -> str | None:
    """The render stage's summary, the first RGB and depth frames, and the two videos, playing."""
    if "render" not in run.results:
        return None
    body = paragraphs(run.describe("render"))
    frames = run.artifact("render", "frames")
    for name, pattern, caption in (("render_first.png", "rgb_*.png", "the path's first frame"),
                                   ("render_depth_first.png", "depth_*.png", "the path's first frame: its depth")):
        first = sorted(frames.glob(pattern))[:1]
        if first:
            shutil.copy2(first[0], run.img / name)
            body += figure(f"img/{name}", caption)
    videos = []
    for artifact, caption in (("video", "the field along the path"), ("depth_video", "its depth, red near to blue far")):
        path = run.artifact("render", artifact)
        if path.exists():
            shutil.copy2(path, run.folder / path.name)
            videos.append(video(path.name, caption, width=VIDEO_WIDTH))
    return section("Novel views", body + grid(videos))


def benchmark(run: RunData) -> str | None:
    """``nerfpipe bench``'s table, held-out PSNR / SSIM at each training-time checkpoint, and its plot."""
    from nerfpipe.bench.run import BENCH_DIR

    bench = run.run_dir / BENCH_DIR / "bench.json"
    if not bench.is_file():
        return None
    doc = json.loads(bench.read_text(encoding="utf-8"))
    marks = doc["checkpoints"]
    header = ("configuration", *(f"{m:.0f} s" for m in marks), "samples/ray", "samples/s", "render s/image", "peak memory")
    body = ("<p>held-out PSNR / SSIM after each training time (nerfpipe bench)</p>"
            + table(header, [benchmark_row(r, marks) for r in doc["results"]]))
    plot = bench.parent / "psnr_time.png"
    if plot.is_file():
        shutil.copyfile(plot, run.img / "bench_psnr_time.png")
        body += figure("img/bench_psnr_time.png", "held-out PSNR against training time")
    return section("What accuracy costs in time", body)


def benchmark_row(result: dict[str, Any], marks: list[float]) -> tuple[str, ...]:
    """One configuration of ``bench.json``: PSNR / SSIM at each mark ("–" where it had not got there), its
    samples per ray and per second, render time per image and peak memory."""
    from nerfpipe.bench.report import psnr_at

    cells = [psnr_at(result, m) for m in marks]
    render = result["render_seconds_per_image"]
    return (result["name"], *("–" if c is None else f"{c['psnr']:.2f} dB / {c['ssim']:.3f}" for c in cells),
            f"{result['samples_per_ray']:.1f}", f"{result['samples_per_s']:,}",
            "–" if render is None else f"{render:.2f}", f"{result['peak_memory_bytes'] / 2**30:.2f} GiB")


def stage_times(run: RunData) -> str:
    """Every stage in pipeline order: its state, the time its result took, what the job's budget allotted it,
    its share of the total, why it is not fresh; then the total of the fresh stages, the budget, and the
    share of it that trained the field."""
    timings = {name: (s.result.manifest.get("timings", {}) if s.result is not None else {})
               for name, s in run.statuses.items()}
    total = sum(r.manifest.get("timings", {}).get("seconds", 0.0) for r in run.results.values())
    rows = []
    for name in run.order:
        status, t = run.statuses[name], timings[name]
        seconds, allotted, spare = t.get("seconds"), t.get("allotted"), t.get("spare") or 0.0
        # what the stages before saved paid for an output at its floor (``Allotment.spare``): part of what it had
        had = None if allotted is None else allotted + spare
        over = (f"over its allotment by {seconds - had:.0f} s ({seconds / had - 1:.0%})"
                if seconds is not None and had and seconds > OVERRUN * had else "")
        rows.append((name, status.state, "" if seconds is None else f"{seconds:.1f} s",
                     "" if allotted is None else f"{allotted:.0f} s" + (f" + {spare:.0f} s saved before" if spare >= 1 else ""),
                     f"{seconds / total:.0%}" if name in run.results and seconds is not None and total else "",
                     "; ".join([*status.reasons, *([over] if over else [])])))
    notes = [f"total of fresh stages: {total:.0f} s"]
    budget = next((t["budget"] for t in timings.values() if "budget" in t), None)
    if budget is not None:
        notes.append(f"job budget: {budget:.0f} s (--budget)")
    if "train" in run.results and total:
        trained = run.results["train"].manifest.get("summary", {}).get("train_seconds")
        if trained is not None:
            notes.append(f"training the field: {trained:.0f} s, {trained / total:.0%} of the total")
    return section("Time per stage", table(("stage", "state", "time", "allotted", "share", "note"), rows)
                   + "<p>" + "; ".join(notes) + "</p>")


def exports(run: RunData) -> str | None:
    """A link to every file in ``RUN_DIR/exports`` (the folders' files counted, not listed)."""
    import os

    folder = run.run_dir / "exports"
    if not folder.is_dir():
        return None
    rows = []
    for path in sorted(folder.iterdir()):
        href = html.escape(Path(os.path.relpath(path, run.folder)).as_posix(), quote=True)
        if path.is_dir():
            count = sum(1 for p in path.rglob("*") if p.is_file())
            rows.append(f"<li><a href='{href}/'>{html.escape(path.name)}/</a> ({count} files)</li>")
        else:
            rows.append(f"<li><a href='{href}'>{html.escape(path.name)}</a> ({path.stat().st_size / 1e6:.1f} MB)</li>")
    return section("Exports", f"<p>in <code>{html.escape(str(folder))}</code> (<code>nerfpipe export RUN_DIR --to "
                   f"FOLDER</code> copies them)</p><ul>{''.join(rows)}</ul>")


SECTIONS: tuple[Callable[[RunData], str | None], ...] = (
    capture, structure_from_motion, scene_decisions, training, depth, mesh_and_points, novel_views, exports, benchmark,
    stage_times,
)
