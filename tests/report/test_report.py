"""The run report on a partial run: sections only for stages with results, and every image it names exists; a
rewrite keeps the pictures whose results are the same commits and draws the others again."""

from __future__ import annotations

import re
from pathlib import Path

from nerfpipe.pipeline import Pipeline
from nerfpipe.report import write_report
from tests.helpers import two_stages


def test_report_of_a_partial_run(capture: Path, tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    Pipeline(two_stages(), capture, run_dir).run()
    page = write_report(run_dir, two_stages())
    assert page == run_dir / "report" / "index.html"
    text = page.read_text()
    sources = re.findall(r'<img src="([^"]+)"', text)
    assert len(sources) == 4 and all((page.parent / src).is_file() for src in sources)  # four photo thumbnails
    assert re.findall(r"<h2>([^<]+)</h2>", text) == ["Capture", "Time per stage"]
    assert "<p>4 photos from <code>" in text
    assert "<td>count</td><td>fresh</td>" in text
    # rewriting replaces the old report
    (run_dir / "report" / "stale.png").write_bytes(b"")
    write_report(run_dir, two_stages())
    assert not (run_dir / "report" / "stale.png").exists()


def test_a_rewrite_keeps_the_pictures_of_unchanged_results_and_redraws_the_rest(capture: Path, tmp_path: Path,
                                                                                 monkeypatch) -> None:
    from nerfpipe.report import sections

    run_dir = tmp_path / "run"
    Pipeline(two_stages(), capture, run_dir).run()
    drawn: list[str] = []
    real = sections.thumbnail
    monkeypatch.setattr(sections, "thumbnail", lambda source, target: drawn.append(target.name) or real(source, target))
    write_report(run_dir, two_stages())
    assert drawn == [f"thumb_{i:03d}.png" for i in range(4)]
    first = (run_dir / "report" / "img" / "thumb_000.png").read_bytes()

    drawn.clear()  # the same ingest commit: every thumbnail taken from the report it replaces, none drawn
    write_report(run_dir, two_stages())
    assert drawn == [] and (run_dir / "report" / "img" / "thumb_000.png").read_bytes() == first
    assert not (run_dir / "report.earlier").exists()

    # a report interrupted while drawing has no keys: the next one trusts none of its pictures
    (run_dir / "report" / "img" / "pictures.json").unlink()
    write_report(run_dir, two_stages())
    assert len(drawn) == 4

    drawn.clear()  # ingest computed again: a new commit, its thumbnails drawn again
    Pipeline(two_stages(), capture, run_dir).run(force=["ingest"])
    write_report(run_dir, two_stages())
    assert len(drawn) == 4
