"""Points triangulated for a capture's known poses with each choice of pairs: points, error, seconds.

Run by hand from the repository root, with ../shared beside it; each variant is NAME:JSON of sfm parameters:

    python scripts/bench_triangulation.py ../shared/data/llff_cup_kwrous /tmp/tri_cup \
        'exhaustive:{"matcher":"exhaustive"}' 'spatial10:{"matcher":"spatial","spatial_neighbors":10}'
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
from pathlib import Path

from nerfpipe import Pipeline, default_stages
from nerfpipe.artifacts import ImageIndex
from nerfpipe.pipeline.stage import StageContext
from nerfpipe.poses.colmap.triangulate import triangulate_known_poses
from nerfpipe.poses.importers import import_poses
from nerfpipe.poses.layout import detect_layout
from nerfpipe.stages.sfm import SfmParams


def main() -> None:
    capture, run = Path(sys.argv[1]), Path(sys.argv[2])
    pipe = Pipeline(default_stages(), capture, run)
    pipe.run(until="ingest")
    records = ImageIndex.load(pipe.artifact("images_json")).records
    cameras = import_poses(detect_layout(capture, None), records)
    ctx = StageContext(logging.getLogger("nerfpipe"))
    for spec in sys.argv[3:]:
        name, _, rest = spec.partition(":")
        values = json.loads(rest) if rest else {}
        params = dataclasses.replace(SfmParams(), **values)
        _, info = triangulate_known_poses(pipe.artifact("images"), cameras, records, run, params, ctx)
        print(json.dumps({"variant": name, **{k: info.get(k) for k in ("matcher", "points", "mean_reprojection_error_px", "mean_track_length", "bundle_adjustment", "seconds")}}), flush=True)


if __name__ == "__main__":
    main()
