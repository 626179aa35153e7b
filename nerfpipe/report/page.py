"""The page: gather the run once, build every section, and write them into the page shell."""

from __future__ import annotations

import html
import json
import os
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

from nerfpipe.pipeline.store import require_run_dir
from nerfpipe.report.data import KEYS, gather
from nerfpipe.report.sections import SECTIONS

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; }
figure { display: inline-block; margin: .3em; text-align: center; font-size: .8em; }
figure img { max-width: 100%; }
.grid { display: flex; flex-wrap: wrap; }
.row { display: flex; flex-wrap: wrap; align-items: flex-end; margin: .5em 0; }
.row figure { flex: 1 1 30%; }
table { border-collapse: collapse; font-size: .9em; }
td, th { border: 1px solid #ddd; padding: .3em .6em; text-align: left; vertical-align: top; }
"""


def page(run_dir: Path, sections: Sequence[str]) -> str:
    """The whole HTML document for the run in ``run_dir``, its sections in order."""
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>nerfpipe report: {html.escape(run_dir.name)}</title>
<style>{STYLE}</style></head><body>
<h1>nerfpipe report: {html.escape(str(run_dir))}</h1>
{''.join(sections)}
</body></html>
"""


def write_report(run_dir: Path, stages: Sequence[Any] | None = None) -> Path:
    """Write ``run_dir/report/index.html`` and its images, replacing any earlier report; return the page's path.
    A picture of the earlier report is kept where what it shows has not changed (``RunData.picture``): a rerun
    that changed nothing rewrites the page in a fraction of a second.

    ``stages``: the pipeline's stages, by default ``nerfpipe.stages.default_stages()``.
    """
    require_run_dir(run_dir, "the report")
    folder, earlier = run_dir / "report", run_dir / "report.earlier"
    run = gather(run_dir, stages, folder)
    if earlier.exists():  # left by a report that was interrupted
        shutil.rmtree(earlier)
    if folder.exists():
        os.replace(folder, earlier)
        run = replace(run, previous=earlier / "img")
    run.img.mkdir(parents=True)
    built = (build(run) for build in SECTIONS)
    (folder / "index.html").write_text(page(run_dir, [s for s in built if s is not None]), encoding="utf-8")
    (run.img / KEYS).write_text(json.dumps(run.drawn, indent=1), encoding="utf-8")  # last: the pictures are whole
    if earlier.exists():
        shutil.rmtree(earlier)
    return folder / "index.html"
