"""The run report on a partial run: sections only for stages with results, and every image it names exists."""

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
