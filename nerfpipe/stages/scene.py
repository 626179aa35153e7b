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

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from nerfpipe.analysis.background import decide_background
from nerfpipe.analysis.exposure import decide_exposure, decide_photometric, measure_exposure
from nerfpipe.analysis.layout import decide_layout
from nerfpipe.analysis.lens import decide_lens
from nerfpipe.artifacts import BOUNDS, IMAGES_JSON, PINHOLE, WORLD, Decision, SceneDecisions
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.summary import Summary
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs

NAMED_COLORS = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}


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
        default=45.0, metadata={"bounds": (0.1, 179.9), "help": "forward: every viewing direction within this angle of the mean one"}
    )
    forward_max_advance: float = field(
        default=0.5, metadata={"bounds": (0.001, 100.0), "help": "forward: camera spread along the mean direction, at most this times the median near depth"}
    )
    converge_max_angle_deg: float = field(
        default=25.0, metadata={"bounds": (0.1, 90.0), "help": "360: cameras look at a common centre when the median axis-to-centre angle is below this"}
    )
    unbounded_outside_fraction: float = field(
        default=0.2, metadata={"bounds": (0.001, 1.0), "help": "unbounded: fraction of sparse points farther from the centre than the cameras"}
    )
    unbounded_far_near_ratio: float = field(
        default=20.0, metadata={"bounds": (1.01, 1000000.0), "help": "unbounded: median far/near ratio of the images at least this"}
    )
    background_tolerance: float = field(
        default=0.1, metadata={"bounds": (0.001, 1.0), "help": "color background: border pixels within this (0..1, per channel) of the median colour"}
    )
    background_min_fraction: float = field(
        default=0.9, metadata={"bounds": (0.001, 1.0), "help": "color background: at least this fraction of border pixels within the tolerance"}
    )
    background_images: int = field(default=24, metadata={"bounds": (1, 10_000), "help": "images sampled (evenly) for the background analysis"})

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


@dataclass(frozen=True)
class SceneSummary(Summary):
    """The decisions' values; their evidence is in ``scene.json`` (``SceneDecisions``), which ``describe`` reads."""

    layout: str = ""
    background: str = ""
    background_color: list[float] | None = None
    lens: Any = None
    photometric: str = ""
    exposure_varies: bool = False

    def describe(self) -> list[str]:
        return [f"{name} is {value}" for name, value in dataclasses.asdict(self).items()]


class SceneStage(Stage):
    """Decide the scene layout, background, lens and photometry from the data, with the evidence."""

    name = "scene"
    version = 4  # 4: azimuth coverage leaves out cameras from overhead; 3: exposure measured from the points' brightness without EXIF; each photo's stops recorded
    Params = SceneParams
    Summary = SceneSummary
    requires = ("images", "images_json", "pinhole", "world", "bounds", "undistorted_images")
    provides = {"scene": "scene.json"}
    libraries = ("numpy", "opencv-contrib-python-headless")

    def describe(self, result: Path, manifest: dict[str, Any]) -> list[str]:
        """Each decision with its evidence, from ``scene.json``; its summary's values where that is gone."""
        path = result / "scene.json"
        return SceneDecisions.load(path).describe() if path.exists() else super().describe(result, manifest)

    def run(self, inputs: StageInputs, out: Path, params: SceneParams, ctx: StageContext) -> SceneSummary:
        records = inputs.load(IMAGES_JSON).records
        if not records:
            raise StageError("scene: images.json lists no images")
        pinhole = inputs.load(PINHOLE)
        world = inputs.load(WORLD)
        bounds = inputs.load(BOUNDS)
        if not world.frames:
            raise StageError("scene: no registered images in the normalized world")

        layout, layout_text, layout_numbers = decide_layout(world, bounds, params)
        roots = pinhole.hints.image_roots
        paths = [
            (inputs["undistorted_images"] if roots.get(r.name) == "undistort" else inputs["images"]) / r.name
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
            records, lambda: measure_exposure(world, dict(zip((r.name for r in records), paths)), linear))

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
        return SceneSummary(**scene.values())
