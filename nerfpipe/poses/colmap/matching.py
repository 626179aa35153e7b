"""Which photos COLMAP matches with which (exhaustive, sequential, spatial), and the matching itself."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pycolmap

from nerfpipe.artifacts import PhotoRecord
from nerfpipe.pipeline.errors import StageError


def choose_matcher(records: list[PhotoRecord], params: Any) -> tuple[str, str]:
    """Which COLMAP matcher suits the capture, and why (the reason is logged and kept in the manifest)."""
    n = len(records)
    if params.matcher != "auto":
        return params.matcher, "set by sfm.matcher"
    if n <= params.exhaustive_max:
        return "exhaustive", f"{n} photos <= sfm.exhaustive_max {params.exhaustive_max}"
    with_gps = sum(1 for r in records if (r.exif or {}).get("gps"))
    if with_gps >= 0.9 * n:
        return "spatial", f"{with_gps} of {n} photos carry GPS"
    if looks_like_video(records):
        return "sequential", f"{n} photos named as numbered frames"
    return "exhaustive", f"{n} photos, no GPS, not numbered frames (exhaustive matching is slow at this size)"


def looks_like_video(records: list[PhotoRecord]) -> bool:
    """Frames of a video: ingest took them from one, or their names end in mostly consecutive numbers."""
    if records and all(r.video_frame is not None for r in records):
        return True
    numbers = []
    for r in records:
        match = re.search(r"(\d+)\D*$", r.name)
        if match is None:
            return False
        numbers.append(int(match.group(1)))
    steps = np.diff(sorted(numbers))
    return len(steps) > 0 and float(np.median(steps)) <= 2


def match_features(database: Path, matcher: str, params: Any, known_positions: bool = False) -> None:
    device = pycolmap.Device.auto
    # two-view RANSAC is seeded too, so the same photos give the same matches, and the same model
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = params.seed
    if matcher == "exhaustive":
        pycolmap.match_exhaustive(database, verification_options=verification, device=device)
    elif matcher == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = params.sequential_overlap
        pycolmap.match_sequential(database, pairing_options=pairing, verification_options=verification, device=device)
    elif known_positions:
        # Cartesian positions in the pose file's units: 3D distances, no distance cut-off, nearest neighbours
        pairing = pycolmap.SpatialPairingOptions()
        pairing.ignore_z = False
        pairing.max_distance = math.inf
        pairing.max_num_neighbors = params.spatial_neighbors
        pycolmap.match_spatial(database, pairing_options=pairing, verification_options=verification, device=device)
    else:
        with pycolmap.Database.open(database) as db:
            if db.num_pose_priors() == 0:
                raise StageError("sfm.matcher=spatial needs GPS in the photos' EXIF; none was found. "
                                 "Use --set sfm.matcher=exhaustive or sequential")
        pycolmap.match_spatial(database, verification_options=verification, device=device)
