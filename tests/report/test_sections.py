"""Section builders on hand-made run data: the decisions table, held-out pairs, the stage times, and no
section for a stage that has not run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nerfpipe.artifacts import Decision, SceneDecisions
from nerfpipe.pipeline import Committed, StageStatus
from nerfpipe.report import sections
from nerfpipe.report.data import RunData
from nerfpipe.stages import SceneStage, TrainStage


def run_data(tmp_path: Path, results: dict[str, Committed], statuses: dict[str, StageStatus] | None = None,
             stages: dict | None = None) -> RunData:
    folder = tmp_path / "report"
    (folder / "img").mkdir(parents=True)
    statuses = statuses or {}
    return RunData(tmp_path / "run", tmp_path / "photos", folder, stages or {}, tuple(statuses), statuses, results)


def test_no_section_for_a_stage_that_has_not_run(tmp_path):
    run = run_data(tmp_path, {})
    for build in sections.SECTIONS:
        if build is not sections.stage_times:
            assert build(run) is None, build.__name__
    assert not any((tmp_path / "report" / "img").iterdir())  # and no pictures written


def test_decisions_table_marks_the_users_override(tmp_path):
    result = tmp_path / "scene"
    result.mkdir()
    made = Decision.made("color", "border pixels agree", {})
    overridden = Decision.made([0.0, 0.0, 0.0], "median border colour", {}, override=[1.0, 1.0, 1.0])
    SceneDecisions(layout=made, background=made, background_color=overridden, lens=made, photometric=made,
                   exposure_varies=Decision.made(False, "no EXIF", {}), near=0.5, far=2.0,
                   scene_box=([-1.0] * 3, [1.0] * 3)).save(result / "scene.json")
    html = sections.scene_decisions(run_data(tmp_path, {"scene": Committed(result, {})}, stages={"scene": SceneStage()}))

    assert html.startswith("<section><h2>Scene decisions</h2><table>")
    assert "<th>decision</th><th>value</th><th>evidence</th><th>overridden</th>" in html
    assert html.count("<tr>") == 1 + 6  # the header and one row per decision, no row for near / far / box
    # the value the user set, the data's evidence with what it suggested, and "yes"
    assert ("<tr><td>background_color</td><td>[1.0, 1.0, 1.0]</td>"
            "<td>median border colour; set by the user (the data suggested (0, 0, 0))</td><td>yes</td></tr>") in html
    assert '<tr><td>background</td><td>&quot;color&quot;</td><td>border pixels agree</td><td></td></tr>' in html
    assert "<tr><td>exposure_varies</td><td>false</td><td>no EXIF</td><td></td></tr>" in html


def test_heldout_pairs_show_the_images_that_exist_with_their_scores(tmp_path):
    result = tmp_path / "train"
    (result / "eval").mkdir(parents=True)
    (result / "metrics.json").write_text(
        '{"views": [{"name": "val/r_0.png", "psnr": 25.126, "ssim": 0.9}, {"name": "r_1.png", "psnr": 1, "ssim": 0}]}')
    (result / "eval" / "val__r_0.render.png").write_bytes(b"png")  # its ground truth is missing; r_1 has nothing
    run = run_data(tmp_path, {"train": Committed(result, {})}, stages={"train": TrainStage()})

    blocks = sections.heldout_pairs(run)

    assert blocks == ["<div class='row'><figure><img src=\"img/eval_val__r_0.render.png\" alt=\"val/r_0.png: render\">"
                      "<figcaption>val/r_0.png: render</figcaption></figure><p>PSNR 25.13 dB, SSIM 0.900</p></div>"]
    assert (tmp_path / "report" / "img" / "eval_val__r_0.render.png").read_bytes() == b"png"


def test_stage_times_total_only_the_fresh_stages(tmp_path):
    def done(seconds: float) -> Committed:
        return Committed(tmp_path, {"timings": {"seconds": seconds}})

    statuses = {
        "ingest": StageStatus("ingest", "fresh", (), "k1", done(1.4)),
        "sfm": StageStatus("sfm", "fresh", ("cached by an earlier run",), "k2", done(2.0)),
        "train": StageStatus("train", "stale", ("params changed: train.lr 0.01 -> 0.005",), "k3", done(10.0)),
        "render": StageStatus("render", "missing", ("not run yet",), "k4", None),
    }
    run = run_data(tmp_path, {"ingest": done(1.4), "sfm": done(2.0)}, statuses)

    html = sections.stage_times(run)

    assert ("<tr><td>ingest</td><td>fresh</td><td>1.4 s</td><td></td><td>41%</td><td></td></tr>"
            "<tr><td>sfm</td><td>fresh</td><td>2.0 s</td><td></td><td>59%</td><td>cached by an earlier run</td></tr>"
            "<tr><td>train</td><td>stale</td><td>10.0 s</td><td></td><td></td>"
            "<td>params changed: train.lr 0.01 -&gt; 0.005</td></tr>"
            "<tr><td>render</td><td>missing</td><td></td><td></td><td></td><td>not run yet</td></tr>") in html
    assert html.endswith("<p>total of fresh stages: 3 s</p></section>")  # 1.4 + 2.0; the stale 10 s not counted

    # under a job budget: each stage's allotment, and the share of the job that trained the field
    trained = Committed(tmp_path, {"timings": {"seconds": 70.0, "allotted": 75.0, "budget": 100.0},
                                   "summary": {"train_seconds": 60.0}})
    rendered = Committed(tmp_path, {"timings": {"seconds": 10.0, "allotted": 10.0, "budget": 100.0}})
    statuses = {"sfm": StageStatus("sfm", "fresh", (), "k2", done(20.0)),
                "train": StageStatus("train", "fresh", (), "k3", trained),
                "render": StageStatus("render", "fresh", (), "k4", rendered)}
    html = sections.stage_times(run_data(tmp_path / "b", {"sfm": done(20.0), "train": trained, "render": rendered}, statuses))
    assert "<tr><td>train</td><td>fresh</td><td>70.0 s</td><td>75 s</td><td>70%</td><td></td></tr>" in html
    assert html.endswith("<p>total of fresh stages: 100 s; job budget: 100 s (--budget); training the field: 60 s, "
                         "60% of the total</p></section>")
    # a stage over its allotment by more than a tenth is noted
    slow = Committed(tmp_path, {"timings": {"seconds": 39.0, "allotted": 27.0, "budget": 100.0}})
    html = sections.stage_times(run_data(tmp_path / "c", {"render": slow}, {"render": StageStatus("render", "fresh", (), "k", slow)}))
    assert "<td>over its allotment by 12 s (44%)</td>" in html
    # what the stages before saved for it (the time training gave the outputs' floors) counts as its allotment too
    paid = Committed(tmp_path, {"timings": {"seconds": 39.0, "allotted": 27.0, "budget": 100.0, "spare": 20.0}})
    html = sections.stage_times(run_data(tmp_path / "d", {"render": paid}, {"render": StageStatus("render", "fresh", (), "k", paid)}))
    assert "<td>27 s + 20 s saved before</td>" in html and "over its allotment" not in html


@pytest.mark.parametrize("caption, alt", [("", "img/a.png"), ("a <b>", "a &lt;b&gt;")])
def test_a_figure_escapes_its_caption_and_falls_back_to_its_source_as_alt_text(caption, alt):
    from nerfpipe.report.markup import figure

    assert f'alt="{alt}"' in figure("img/a.png", caption)


def test_a_benchmark_row_has_a_dash_where_the_budget_stopped_training_first():
    slow = {"name": "slow", "finished": False, "samples_per_ray": 12.345, "samples_per_s": 123456,
            "render_seconds_per_image": None, "peak_memory_bytes": 3 * 2**29,
            "points": [{"mark": 30.0, "seconds": 30.4, "psnr": 20.0, "ssim": 0.2}]}
    # no checkpoint at 60 s and not finished: "–"; 3 * 2^29 bytes = 1.5 GiB
    assert sections.benchmark_row(slow, [30.0, 60.0]) == (
        "slow", "20.00 dB / 0.200", "–", "12.3", "123,456", "–", "1.50 GiB")


def test_a_heldout_row_is_render_photo_and_their_difference(tmp_path):
    from nerfpipe.imaging.png import read_png, write_png

    result = tmp_path / "train"
    (result / "eval").mkdir(parents=True)
    (result / "metrics.json").write_text('{"views": [{"name": "a.png", "psnr": 20.0, "ssim": 0.5}]}')
    render, photo = np.full((4, 6, 3), 100, np.uint8), np.full((4, 6, 3), 100, np.uint8)
    photo[1, 2] = (110, 40, 100)  # off by 10 and -60 in one pixel
    write_png(result / "eval" / "a.render.png", render)
    write_png(result / "eval" / "a.gt.png", photo)
    (block,) = sections.heldout_pairs(run_data(tmp_path, {"train": Committed(result, {})}, stages={"train": TrainStage()}))
    assert [c for c in ("a.png: render", "a.png: photo", f"a.png: difference x{sections.ERROR_GAIN}") if c in block] == [
        "a.png: render", "a.png: photo", "a.png: difference x4"]
    error = read_png(tmp_path / "report" / "img" / "eval_a.error.png")
    expected = np.zeros((4, 6, 3), np.uint8)
    expected[1, 2] = (40, 240, 0)  # |diff| x 4
    assert np.array_equal(error, expected)


def test_depth_previews_hold_the_heldout_views_and_spread_the_rest():
    from types import SimpleNamespace

    views = [SimpleNamespace(name=f"{i:02d}", role="heldout" if i % 8 == 0 else "train") for i in range(40)]
    chosen = sections.preview_views(views, 12)
    assert [v.name for v in chosen if v.role == "heldout"] == ["00", "08", "16", "24", "32"]
    train = [int(v.name) for v in chosen if v.role == "train"]
    assert len(chosen) == 12 and train[0] == 1 and train[-1] == 39  # from the first training view to the last
    assert max(np.diff(train)) <= 2 * min(np.diff(train)) + 2  # evenly spread
    assert [v.name for v in sections.preview_views(views[:3], 12)] == ["00", "01", "02"]


def test_the_sfm_plot_frames_every_camera_and_the_bulk_of_the_points():
    from nerfpipe.report.images import plot_frame

    centers = np.array([[5.0, 0.0, 0.0], [-5.0, 0.0, 0.0], [0.0, 5.0, 1.0], [0.0, -5.0, -1.0]])
    points = np.random.default_rng(0).normal(size=(1000, 3)) * 0.5
    points[0] = (300.0, 0.0, 0.0)  # one point far off
    mid, half = plot_frame(centers, points)
    assert np.all(np.abs(centers - mid) <= half)  # no camera is cut off
    assert half == pytest.approx(5.25, rel=0.02)  # and the far point does not shrink the scene


def test_the_exports_section_links_every_file(tmp_path):
    exports = tmp_path / "run" / "exports"
    (exports / "depth").mkdir(parents=True)
    (exports / "mesh.glb").write_bytes(b"x" * 2_000_000)
    (exports / "depth" / "a.npy").write_bytes(b"x")
    html = sections.exports(run_data(tmp_path, {}))
    assert "<a href='../run/exports/depth/'>depth/</a> (1 files)" in html
    assert "<a href='../run/exports/mesh.glb'>mesh.glb</a> (2.0 MB)" in html


def test_a_masked_score_shows_the_photo_as_taken_and_says_both_scores(tmp_path):
    from nerfpipe.imaging.png import write_png

    result = tmp_path / "train"
    (result / "eval").mkdir(parents=True)
    (result / "metrics.json").write_text('{"views": [{"name": "a.png", "psnr": 28.6, "psnr_photo": 24.6, "ssim": 0.9}]}')
    write_png(result / "eval" / "a.render.png", np.zeros((4, 6, 3), np.uint8))
    write_png(result / "eval" / "a.gt.png", np.zeros((4, 6, 3), np.uint8))  # the backdrop masked out
    write_png(result / "eval" / "a.photo.png", np.full((4, 6, 3), 50, np.uint8))  # as taken
    (block,) = sections.heldout_pairs(run_data(tmp_path, {"train": Committed(result, {})}, stages={"train": TrainStage()}))
    assert "img/eval_a.photo.png" in block and "eval_a.gt.png" not in block
    assert ("PSNR 28.60 dB against the photo with its backdrop masked out (the score), 24.60 dB against the photo "
            "as taken, SSIM 0.900") in block


def test_the_depth_scale_runs_red_near_to_blue_far_as_the_previews(tmp_path):
    from nerfpipe.imaging.png import read_png
    from nerfpipe.report.images import plot_depth_scale

    plot_depth_scale(tmp_path / "scale.png")
    bar = read_png(tmp_path / "scale.png")[..., :3].astype(int)
    row = bar[bar.shape[0] // 3]  # through the bar, above the tick labels
    coloured = np.flatnonzero(row.max(axis=1) - row.min(axis=1) > 40)  # the bar, not the white margins
    span = coloured[-1] - coloured[0]
    near, far = row[coloured[0] + span // 10], row[coloured[0] + 9 * span // 10]
    assert near[0] > near[2] + 60 and far[2] > far[0] + 60


def test_the_sfm_plot_names_its_points_and_cameras_in_its_legend(tmp_path, monkeypatch):
    from nerfpipe.report import images

    legends = []
    real = images._pyplot

    def recording():
        plt = real()
        original = plt.Axes.legend

        def legend(ax, *args, **kwargs):
            made = original(ax, *args, **kwargs)
            legends.append([text.get_text() for text in made.get_texts()])
            return made

        monkeypatch.setattr(plt.Axes, "legend", legend)
        return plt

    monkeypatch.setattr(images, "_pyplot", recording)
    rng = np.random.default_rng(0)
    centers, axes = rng.normal(size=(5, 3)), np.tile([0.0, 0.0, 1.0], (5, 1))
    images.plot_cameras(tmp_path / "sfm.png", centers, axes, rng.normal(size=(40, 3)), rng.uniform(size=(40, 3)))
    assert legends == [["40 sparse points, in their colours", "cameras"]]
