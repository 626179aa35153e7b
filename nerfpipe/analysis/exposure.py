"""How the photos were exposed: RAW developed linearly or not, and whether the exposure varies across them
(EXIF exposure values, else the brightness of the same sparse points in each photo)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from nerfpipe.artifacts import PhotoRecord
from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.geometry.normalize import project

EXPOSURE_STEP_STOPS = 1.0 / 3.0  # cameras step exposure in thirds of a stop: anything less is rounding


def decide_photometric(records: list[PhotoRecord]) -> tuple[str, str, dict[str, Any]]:
    n = len(records)
    raw = sum(bool(r.raw) for r in records)
    linear = sum(bool(r.linear) for r in records)
    value = "linear_raw" if linear == n else "srgb"
    evidence = f"{linear} of {n} photos are RAW developed linearly ({raw} RAW in all)"
    if 0 < linear < n:
        evidence += "; mixed encodings, treated as sRGB"
    return value, evidence, {"photos": n, "raw": raw, "linear": linear}


def exposure_value(exif: dict[str, Any]) -> float | None:
    """log2(t * ISO / N^2): the photo's exposure in stops (higher = more light gathered), or None."""
    t, n, iso = exif.get("exposure_time_s"), exif.get("f_number"), exif.get("iso")
    if not t or not n or not iso or t <= 0 or n <= 0 or iso <= 0:
        return None
    return math.log2(t * iso / (n * n))


def measure_exposure(world: CameraSet, paths: dict[str, Path], linear: bool, min_points: int = 20,
                     max_side: int = 400) -> dict[str, float]:
    """Each photo's exposure in stops relative to the others, from the brightness of the sparse points it sees.

    A point's linear luminance (3x3 mean around its projection, in a copy at most ``max_side`` px) is its
    radiance times the photo's gain, so log2 luminance = point term + photo term; both are found by
    alternating medians (robust to specular points and mismatches), skipping pixels near black or white.
    Returns {frame name: stops, centred on their median} for the frames with at least ``min_points``
    measured points that other frames see too; {} without points.
    """
    import cv2

    from nerfpipe.imaging.png import read_png, srgb_decode

    points = world.points
    if points is None or not points.visible or len(points.xyz) == 0:
        return {}
    rows, cols, logs = [], [], []
    for i, frame in enumerate(world.frames):
        path = paths.get(frame.name)
        if path is None or not path.exists() or i >= len(points.visible) or len(points.visible[i]) < min_points:
            continue
        pixels = read_png(path)
        pixels = pixels.astype(np.float32) / (65535.0 if pixels.dtype == np.uint16 else 255.0)
        grey = pixels if pixels.ndim == 2 else pixels[..., :3].mean(axis=-1)
        scale = min(1.0, max_side / max(grey.shape))
        if scale < 1.0:
            grey = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        grey = cv2.blur(grey, (3, 3))
        index = points.visible[i]
        camera = world.camera_of(frame)
        uv, depth = project(frame.c2w, camera.K(), points.xyz[index])
        ahead = depth > 1e-9
        u, v = uv[:, 0] * scale, uv[:, 1] * scale
        h, w = grey.shape
        inside = ahead & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        value = grey[v[inside].astype(int), u[inside].astype(int)]
        usable = (value > 0.03) & (value < 0.95)  # clipped or lost in noise: no exposure in it
        light = value[usable] if linear else srgb_decode(value[usable])
        rows.append(np.full(len(light), i))
        cols.append(index[inside][usable])
        logs.append(np.log2(light))
    if not rows:
        return {}
    row, col, log = np.concatenate(rows), np.concatenate(cols), np.concatenate(logs)
    seen = np.bincount(col, minlength=len(points.xyz))
    shared = seen[col] >= 2
    row, col, log = row[shared], col[shared], log[shared]
    photo = np.zeros(len(world.frames))
    for _ in range(4):  # log = point + photo: alternate medians
        point = _group_median(col, log - photo[row], len(points.xyz))
        photo = _group_median(row, log - point[col], len(world.frames))
    counts = np.bincount(row, minlength=len(world.frames))
    measured = {f.name: float(photo[i]) for i, f in enumerate(world.frames) if counts[i] >= min_points}
    centre = float(np.median(list(measured.values()))) if measured else 0.0
    return {name: value - centre for name, value in measured.items()}


def _group_median(group: np.ndarray, values: np.ndarray, groups: int) -> np.ndarray:
    """The median of ``values`` per ``group`` index (0 for groups without values)."""
    order = np.lexsort((values, group))
    group, values = group[order], values[order]
    starts = np.searchsorted(group, np.arange(groups), side="left")
    ends = np.searchsorted(group, np.arange(groups), side="right")
    out = np.zeros(groups)
    for g in np.nonzero(ends > starts)[0]:
        out[g] = np.median(values[starts[g]:ends[g]])
    return out


def decide_exposure(records: list[PhotoRecord], measure: Callable[[], dict[str, float]] | None = None,
                    ) -> tuple[bool, str, dict[str, Any]]:
    """Whether exposure varies: EXIF where two photos or more have it, else ``measure()`` (each photo's stops
    from the brightness of the same points, ``measure_exposure``), else assumed constant. ``measured["stops"]``:
    each photo's exposure relative to the mean of those known."""
    exif = {r.name: v for r in records if (v := exposure_value(r.exif or {})) is not None}
    n = len(records)
    if len(exif) >= 2:
        stops, how = exif, f"EXIF exposure (time x ISO / f-number^2) of {len(exif)} of {n} photos"
    else:
        stops = measure() if measure is not None else {}
        how = f"the brightness of the same sparse points in {len(stops)} of {n} photos (no EXIF exposure)"
        if len(stops) < 2:
            return False, (f"EXIF exposure (time, f-number, ISO) known for {len(exif)} of {n} photos and no shared "
                           "points to measure it by; assumed constant"), {"with_exif": len(exif), "source": "none"}
    values = np.array(list(stops.values()))
    if len(exif) >= 2:
        spread = float(values.max() - values.min())
    else:  # measured: the 10th-90th percentile range, as a few photos' matches can be off
        spread = float(np.percentile(values, 90) - np.percentile(values, 10))
    varies = spread > EXPOSURE_STEP_STOPS + 1e-9
    mean = float(values.mean())
    evidence = f"{how} spans {spread:.2f} stops ({'more' if varies else 'not more'} than a third of a stop)"
    return varies, evidence, {"with_exif": len(exif), "spread_stops": round(spread, 4),
                              "source": "exif" if len(exif) >= 2 else "brightness",
                              "stops": {name: round(v - mean, 4) for name, v in stops.items()}}
