"""scene: what kind of capture this is, decided from the data, each decision with its evidence.

Writes ``scene.json``: one entry per decision, ``{"value", "evidence", "overridden", "measured"}``, where
``evidence`` is a sentence with the numbers behind the value and ``measured`` those numbers as JSON, plus
``ndc`` (layout is forward), ``near`` / ``far`` and ``scene_box`` copied from the bounds. A decision the
user set (``--set scene.layout=forward``) keeps the measured evidence and says so.

- ``layout``: ``forward`` (every camera looks roughly the same way: rays are warped into normalized device
  coordinates, as the NeRF paper does for its real forward-facing scenes: Section 6.1 for the data, the
  arXiv version's Appendix C, "NDC ray space derivation", for the warp),
  ``inward360`` (cameras look at a common centre from around it: a bounded box, like the paper's synthetic
  360° scenes) or ``unbounded360`` (content extends far beyond the cameras, or there is no common centre:
  contracted unbounded space).
- ``background``: ``alpha`` (the photos carry transparency: composite onto ``background_color`` while
  training), ``color`` (the image borders are one near-constant colour) or ``none``.
- ``background_color``: the colour composited behind alpha, or the measured border colour.
- ``lens``: ``undistorted`` when the undistort stage found significant distortion and resampled, else ``pinhole``.
- ``photometric``: ``linear_raw`` (RAW developed linearly) or ``srgb``.
- ``exposure_varies``: whether the photos' exposure spans more than a third of a stop: from EXIF (t * ISO /
  N^2) where at least two photos have it, else from the brightness of the same sparse points in each photo
  (``measure_exposure``). ``measured["stops"]`` gives each photo's exposure relative to their mean, which
  training starts its per-image exposure from (``nerfpipe.nerf.appearance``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np

from nerfpipe.artifacts import Bounds, Decision, ImageIndex, SceneDecisions
from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.geometry.normalize import axis_angles_to, azimuth_coverage, look_at_center, viewing_spread
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs

NAMED_COLORS = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}
EXPOSURE_STEP_STOPS = 1.0 / 3.0  # cameras step exposure in thirds of a stop: anything less is rounding


def parse_color(text: str) -> tuple[float, float, float] | None:
    """``"auto"`` -> None; ``"white"`` / ``"black"``; ``"r,g,b"`` with components in [0, 1]."""
    text = text.strip().lower()
    if text == "auto":
        return None
    if text in NAMED_COLORS:
        return NAMED_COLORS[text]
    parts = text.split(",")
    try:
        rgb = tuple(float(p) for p in parts)
    except ValueError:
        rgb = ()
    if len(rgb) != 3 or not all(0.0 <= c <= 1.0 for c in rgb):
        raise ValueError(f"background_color must be auto, white, black or r,g,b in 0..1 (e.g. 0.5,0.5,0.5), got {text!r}")
    return rgb  # type: ignore[return-value]


@dataclass(frozen=True)
class SceneParams:
    layout: Literal["auto", "forward", "inward360", "unbounded360"] = field(
        default="auto", metadata={"help": "scene layout; auto decides from the camera rig and the sparse points"}
    )
    background: Literal["auto", "alpha", "color", "none"] = field(
        default="auto", metadata={"help": "background handling; auto decides from alpha channels and image borders"}
    )
    background_color: str = field(
        default="auto", metadata={"help": "auto (white behind alpha, else the measured border colour), white, black or r,g,b in 0..1"}
    )
    photometric: Literal["auto", "srgb", "linear_raw"] = field(
        default="auto", metadata={"help": "pixel encoding; auto reads it from the ingest records"}
    )
    exposure_varies: Literal["auto", "true", "false"] = field(
        default="auto", metadata={"help": "whether exposure varies across photos; auto reads EXIF"}
    )
    forward_max_angle_deg: float = field(
        default=45.0, metadata={"help": "forward: every viewing direction within this angle of the mean one"}
    )
    forward_max_advance: float = field(
        default=0.5, metadata={"help": "forward: camera spread along the mean direction, at most this times the median near depth"}
    )
    converge_max_angle_deg: float = field(
        default=25.0, metadata={"help": "360: cameras look at a common centre when the median axis-to-centre angle is below this"}
    )
    unbounded_outside_fraction: float = field(
        default=0.2, metadata={"help": "unbounded: fraction of sparse points farther from the centre than the cameras"}
    )
    unbounded_far_near_ratio: float = field(
        default=20.0, metadata={"help": "unbounded: median far/near ratio of the images at least this"}
    )
    background_tolerance: float = field(
        default=0.1, metadata={"help": "color background: border pixels within this (0..1, per channel) of the median colour"}
    )
    background_min_fraction: float = field(
        default=0.9, metadata={"help": "color background: at least this fraction of border pixels within the tolerance"}
    )
    background_images: int = field(default=24, metadata={"help": "images sampled (evenly) for the background analysis"})

    def __post_init__(self) -> None:
        parse_color(self.background_color)
        if not 0.0 < self.forward_max_angle_deg < 180.0 or not 0.0 < self.converge_max_angle_deg < 180.0:
            raise ValueError("angles must lie in (0, 180) degrees")
        if self.forward_max_advance <= 0 or self.unbounded_far_near_ratio <= 1.0:
            raise ValueError("forward_max_advance must be > 0 and unbounded_far_near_ratio > 1")
        for name in ("unbounded_outside_fraction", "background_tolerance", "background_min_fraction"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        if self.background_images < 1:
            raise ValueError(f"background_images must be >= 1, got {self.background_images}")


# -- layout ----------------------------------------------------------------------------------------------
def decide_layout(world: CameraSet, bounds: Bounds, params: SceneParams) -> tuple[str, str, dict[str, Any]]:
    """(value, evidence, measured) for the layout, from the normalized rig, its points and the near/far bounds."""
    c2ws = np.array([f.c2w for f in world.frames])
    centers = c2ws[:, :3, 3]
    mean_dir, angles = viewing_spread(c2ws)
    nears = np.array([f.near for f in bounds.frames])
    fars = np.array([f.far for f in bounds.frames])
    median_near = float(np.median(nears))
    advance = float(np.ptp(centers @ mean_dir)) if len(centers) > 1 else 0.0
    far_near = float(np.median(fars / np.maximum(nears, 1e-12)))
    measured: dict[str, Any] = {
        "cameras": len(c2ws),
        "max_angle_to_mean_deg": round(float(angles.max()), 2),
        "median_angle_to_mean_deg": round(float(np.median(angles)), 2),
        "advance_along_mean": round(advance, 4),
        "median_near": round(median_near, 4),
        "median_far_near_ratio": round(far_near, 3),
        "bounds_method": bounds.method,
    }
    spread = (
        f"viewing directions lie within {angles.max():.0f}° of their mean (median {np.median(angles):.0f}°), "
        f"camera centres spread {advance:.2f} along it vs a median near depth of {median_near:.2f}"
    )
    if angles.max() < params.forward_max_angle_deg and advance <= params.forward_max_advance * median_near:
        return "forward", f"all cameras face one way: {spread}; rays use NDC", measured

    center = look_at_center(c2ws)
    to_center = axis_angles_to(c2ws, center)
    ring = float(np.median(np.linalg.norm(centers - center, axis=1)))
    coverage = azimuth_coverage(c2ws, center)
    measured.update(
        median_axis_to_center_deg=round(float(np.median(to_center)), 2),
        ring_radius=round(ring, 4),
        azimuth_coverage_deg=round(coverage, 1),
    )
    if np.median(to_center) >= params.converge_max_angle_deg:
        return (
            "unbounded360",
            f"cameras do not share a viewing direction ({spread}) nor look at a common centre "
            f"(median {np.median(to_center):.0f}° off it); unbounded space is contracted",
            measured,
        )
    surround = (
        f"cameras look at a common centre (median {np.median(to_center):.1f}° off it) from {ring:.2f} away, "
        f"covering {coverage:.0f}° of azimuth, viewing directions up to {angles.max():.0f}° apart from their mean"
    )
    if world.points is not None and len(world.points.xyz):
        outside = float(np.mean(np.linalg.norm(world.points.xyz - center, axis=1) > ring))
        measured["points_outside_ring"] = round(outside, 4)
        content = f"{100 * outside:.1f}% of the {len(world.points.xyz)} sparse points lie farther out than the cameras"
    else:
        outside = 0.0
        content = "no sparse points (near/far from the rig)"
    content += f", median far/near {far_near:.1f}"
    if outside > params.unbounded_outside_fraction or far_near >= params.unbounded_far_near_ratio:
        return "unbounded360", f"{surround}, but the scene extends beyond them: {content}; unbounded space is contracted", measured
    return "inward360", f"{surround}; {content}; a bounded box", measured


# -- background ------------------------------------------------------------------------------------------
def read_small(path: Path, max_side: int = 128) -> np.ndarray:
    """(h, w, 3 or 4) float RGB(A) in [0, 1], downscaled (area) so the longest side is at most ``max_side``."""
    import cv2

    pixels = cv2.imdecode(np.fromfile(path, np.uint8), cv2.IMREAD_UNCHANGED)
    if pixels is None:
        raise StageError(f"scene: cannot read the image {path}")
    full = np.iinfo(pixels.dtype).max if pixels.dtype.kind in "ui" else 1.0
    if pixels.ndim == 2:
        pixels = pixels[..., None].repeat(3, axis=2)
    h, w = pixels.shape[:2]
    if max(h, w) > max_side:
        s = max_side / max(h, w)
        pixels = cv2.resize(pixels, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    pixels = pixels.astype(np.float64) / full
    order = [2, 1, 0, 3][: pixels.shape[2]]  # BGR(A) -> RGB(A)
    return pixels[..., order]


def border_pixels(rgb: np.ndarray, band: float = 0.03) -> np.ndarray:
    """(K, 3) pixels of the border band (``band`` of the shorter side, at least one pixel) of an (h, w, 3) image."""
    h, w = rgb.shape[:2]
    b = max(1, round(band * min(h, w)))
    mask = np.ones((h, w), bool)
    mask[b : h - b, b : w - b] = False
    return rgb[mask][:, :3]


def decide_background(
    records: list[dict[str, Any]], paths: list[Path], params: SceneParams
) -> tuple[str, str, dict[str, Any], tuple[float, float, float] | None]:
    """(value, evidence, measured, border colour) from the alpha flags and the images' border pixels."""
    n = len(records)
    with_alpha = sum(bool(r.get("has_alpha")) for r in records)
    take = np.unique(np.linspace(0, n - 1, min(n, params.background_images)).round().astype(int))
    borders, transparent = [], []
    for i in take:
        pixels = read_small(paths[i])
        if pixels.shape[2] == 4:
            transparent.append(float(np.mean(pixels[..., 3] < 0.5)))
        borders.append(border_pixels(pixels))
    border = np.concatenate(borders)
    color = np.median(border, axis=0)
    distance = np.abs(border - color).max(axis=1)
    within = float(np.mean(distance <= params.background_tolerance))
    measured: dict[str, Any] = {
        "images": n,
        "with_alpha": with_alpha,
        "sampled": len(take),
        "border_color": [round(float(c), 4) for c in color],
        "border_within_tolerance": round(within, 4),
        "border_p90_distance": round(float(np.percentile(distance, 90)), 4),
        "tolerance": params.background_tolerance,  # training masks the backdrop with it (nerfpipe.imaging.masks)
    }
    rgb = tuple(float(c) for c in color)
    border_text = (
        f"median border colour ({', '.join(f'{c:.2f}' for c in color)}) with {100 * within:.1f}% of border pixels "
        f"within {params.background_tolerance:g} of it (90th percentile distance {np.percentile(distance, 90):.3f}) "
        f"over {len(take)} images"
    )
    if transparent:
        measured["transparent_fraction"] = round(float(np.mean(transparent)), 4)
    if with_alpha == n and (not transparent or max(transparent) > 0.001):
        coverage = f", {100 * np.mean(transparent):.1f}% of pixels transparent on average" if transparent else ""
        return "alpha", f"{with_alpha} of {n} images have an alpha channel{coverage}", measured, rgb
    alpha_note = f"{with_alpha} of {n} images have alpha; " if with_alpha else ""
    if within >= params.background_min_fraction:
        return "color", f"{alpha_note}{border_text}: a constant background", measured, rgb
    return "none", f"{alpha_note}{border_text}: the background varies", measured, rgb


# -- lens, photometry, exposure ---------------------------------------------------------------------------
LENS_PER_CAMERA_MAX = 3  # up to this many cameras the lens evidence names each one


def decide_lens(pinhole: CameraSet) -> tuple[str, str, dict[str, Any]]:
    """``undistorted`` when the undistort stage resampled any camera's images, else ``pinhole``; the evidence
    names each camera when there are at most ``LENS_PER_CAMERA_MAX``, else summarises them all."""
    record = pinhole.extra.get("undistortion") or {}
    if not record:
        return "pinhole", "no undistortion record: the cameras were pinhole as given", {"cameras": {}}
    cameras = sorted(record.items(), key=lambda kv: str(kv[0]))
    done = sum(bool(info.get("undistorted")) for _, info in cameras)
    value = "undistorted" if done else "pinhole"
    if len(cameras) > LENS_PER_CAMERA_MAX:
        return value, _lens_summary([info.get("max_displacement_px", 0.0) for _, info in cameras], done), {"cameras": record}
    parts = []
    for camera_id, info in cameras:
        shift = info.get("max_displacement_px", 0.0)
        size = "beyond 90° off-axis (fisheye)" if shift is None else f"by up to {float(shift):.2f} px"
        parts.append(f"camera {camera_id}: distortion moves pixels {size}, "
                     f"{'undistorted' if info.get('undistorted') else 'left as is'}")
    return value, "; ".join(parts), {"cameras": record}


def _lens_summary(shifts: list[float | None], undistorted: int) -> str:
    """'71 cameras: distortion 0.2-29 px, 70 undistorted, 1 left as is' (None: a fisheye beyond 90°)."""
    finite = [float(s) for s in shifts if s is not None]
    beyond = len(shifts) - len(finite)
    spread = []
    if finite:
        lo, hi = _px(min(finite)), _px(max(finite))
        spread.append(f"distortion {lo} px" if lo == hi else f"distortion {lo}-{hi} px")
    if beyond:
        spread.append(f"{beyond} beyond 90° off-axis (fisheye)")
    left = len(shifts) - undistorted
    return f"{len(shifts)} cameras: {', '.join(spread)}, {undistorted} undistorted, {left} left as is"


def _px(value: float) -> str:
    """Two significant digits, never in exponent form: 0.2, 3.1, 29, 140."""
    return f"{value:.0f}" if value >= 10 else f"{value:.2g}"


def decide_photometric(records: list[dict[str, Any]]) -> tuple[str, str, dict[str, Any]]:
    n = len(records)
    raw = sum(bool(r.get("raw")) for r in records)
    linear = sum(bool(r.get("linear")) for r in records)
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

    from nerfpipe.export.foreground import project
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
        uv, ahead = project(points.xyz[index], camera.K(), frame.c2w)
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


def decide_exposure(records: list[dict[str, Any]], measure: Callable[[], dict[str, float]] | None = None,
                    ) -> tuple[bool, str, dict[str, Any]]:
    """Whether exposure varies: EXIF where two photos or more have it, else ``measure()`` (each photo's stops
    from the brightness of the same points, ``measure_exposure``), else assumed constant. ``measured["stops"]``:
    each photo's exposure relative to the mean of those known."""
    exif = {r["name"]: v for r in records if (v := exposure_value(r.get("exif") or {})) is not None}
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


class SceneStage(Stage):
    """Decide the scene layout, background, lens and photometry from the data, with the evidence."""

    name = "scene"
    version = 3  # 3: exposure measured from the points' brightness without EXIF; each photo's stops recorded
    Params = SceneParams
    requires = ("images", "images_json", "pinhole", "world", "bounds", "undistorted_images")
    provides = {"scene": "scene.json"}
    libraries = ("numpy", "opencv-contrib-python-headless")

    def describe(self, result: Path, manifest: dict[str, Any]) -> list[str]:
        path = result / "scene.json"
        return SceneDecisions.load(path).describe() if path.exists() else []

    def run(self, inputs: StageInputs, out: Path, params: SceneParams, ctx: StageContext) -> dict[str, Any]:
        records = ImageIndex.load(inputs["images_json"]).records
        if not records:
            raise StageError("scene: images.json lists no images")
        pinhole = CameraSet.load(inputs["pinhole"])
        world = CameraSet.load(inputs["world"])
        bounds = Bounds.load(inputs["bounds"])
        if not world.frames:
            raise StageError("scene: no registered images in the normalized world")

        layout, layout_text, layout_numbers = decide_layout(world, bounds, params)
        roots = pinhole.extra.get("image_roots", {})
        paths = [
            (inputs["undistorted_images"] if roots.get(r["name"]) == "undistort" else inputs["images"]) / r["name"]
            for r in records
        ]
        background, background_text, background_numbers, border = decide_background(records, paths, params)
        chosen_background = background if params.background == "auto" else params.background
        color_override = parse_color(params.background_color)
        auto_color: tuple[float, float, float] | None
        if chosen_background == "alpha":
            auto_color = NAMED_COLORS["white"]
            color_text = "white behind transparent pixels, as NeRF composites its synthetic scenes"
        elif chosen_background == "color":
            auto_color = border
            color_text = "the measured median border colour"
        else:
            auto_color, color_text = None, "no background colour: the background is part of the scene"
        lens, lens_text, lens_numbers = decide_lens(pinhole)
        photometric, photometric_text, photometric_numbers = decide_photometric(records)
        linear = photometric == "linear_raw"
        exposure, exposure_text, exposure_numbers = decide_exposure(
            records, lambda: measure_exposure(world, dict(zip((r["name"] for r in records), paths)), linear))

        chosen_layout = layout if params.layout == "auto" else params.layout
        if chosen_layout == "inward360" and chosen_background == "none":
            layout_text += "; with no backdrop the background is part of the scene, so the space beyond the box is contracted"
        scene = SceneDecisions(
            layout=Decision.made(layout, layout_text, layout_numbers, params.layout),
            background=Decision.made(background, background_text, background_numbers, params.background),
            background_color=Decision.made(
                None if auto_color is None else [round(c, 4) for c in auto_color],
                color_text,
                {"border_color": background_numbers["border_color"]},
                "auto" if color_override is None else list(color_override),
            ),
            lens=Decision.made(lens, lens_text, lens_numbers),
            photometric=Decision.made(photometric, photometric_text, photometric_numbers, params.photometric),
            exposure_varies=Decision.made(
                exposure, exposure_text, exposure_numbers,
                "auto" if params.exposure_varies == "auto" else params.exposure_varies == "true",
            ),
            near=bounds.near,
            far=bounds.far,
            scene_box=bounds.scene_box,
        )
        scene.save(out / "scene.json")
        for line in scene.describe():
            ctx.log.info("scene: %s", line)
        return scene.values()
