"""What the stages hand each other: typed views of their JSON artifacts, and the names of their files.

A stage reads another stage's JSON only through these classes, by their typed references at the end of this
module (``inputs.load(BOUNDS)`` is a ``Bounds``, ``inputs.load(WORLD)`` a ``CameraSet``); each writes the same
JSON, key for key, as it reads, so cache keys and files stay as they were. Camera sets have their own class,
``nerfpipe.geometry.cameras.CameraSet``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.stage import ArtifactRef
from nerfpipe.pipeline.store import write_json_atomic

PHOTO_SUBFOLDER = "images"  # LLFF and COLMAP captures keep their photos in this sub-folder
IMAGE_ROOTS: tuple[str, ...] = ("undistort", "ingest")  # where a frame's training image lies


def _read(path: Path) -> dict[str, Any]:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise StageError(f"{path}: cannot read this stage result ({exc}); rerun with --force on the stage that wrote it") from exc


# -- file names ------------------------------------------------------------------------------------------
def output_names(relpaths: list[str]) -> dict[str, str]:
    """Ingest names of the photos: their paths below the photo folder, as ``.png``.

    ``images/0001.jpg`` -> ``0001.png`` when every photo is under ``images/`` (LLFF, COLMAP);
    ``train/r_0.png`` keeps its folder (NeRF splits); two photos that would share a name (``a.jpg``,
    ``a.tif``) both keep their extension (``a_jpg.png``, ``a_tif.png``).
    """
    prefix = f"{PHOTO_SUBFOLDER}/"
    strip = bool(relpaths) and all(rel.startswith(prefix) for rel in relpaths)
    stems = {rel: PurePosixPath(rel[len(prefix):] if strip else rel) for rel in relpaths}
    counts: dict[PurePosixPath, int] = {}
    for path in stems.values():
        counts[path.with_suffix("")] = counts.get(path.with_suffix(""), 0) + 1
    names = {}
    for rel, path in stems.items():
        base = path.with_suffix("")
        clash = counts[base] > 1
        name = f"{base}_{path.suffix.lstrip('.').lower()}.png" if clash else f"{base}.png"
        names[rel] = _within_name_limit(PurePosixPath(name), rel)
    return names


MAX_NAME_BYTES = 255  # a file name's limit on every common filesystem


def _within_name_limit(name: PurePosixPath, rel: str) -> str:
    """``name`` with its last part shortened to ``MAX_NAME_BYTES`` where it is longer, made unique by a hash of
    the photo's path (two long names that share their start stay two names)."""
    if len(name.name.encode()) <= MAX_NAME_BYTES:
        return str(name)
    tag = "-" + hashlib.sha256(rel.encode()).hexdigest()[:12] + ".png"
    stem = name.name.encode()[:MAX_NAME_BYTES - len(tag)].decode("utf-8", "ignore")
    return str(name.with_name(stem + tag))


def frame_image_path(frame_name: str, image_root: str, ingest_images: Path, undistort_images: Path) -> Path:
    """The image of frame ``frame_name``, given its ``hints.image_roots`` entry in the pinhole camera set.

    ``ingest_images`` and ``undistort_images`` are the ``images`` artifact of ingest and the
    ``undistorted_images`` artifact of undistort.
    """
    if image_root == "undistort":
        return Path(undistort_images) / frame_name
    if image_root == "ingest":
        return Path(ingest_images) / frame_name
    raise ValueError(f"image root of {frame_name!r} is {image_root!r}; expected one of {', '.join(IMAGE_ROOTS)}")


def view_file_stem(name: str) -> str:
    """A file name for a frame name that may contain folders: ``val/r_0.png`` -> ``val__r_0``."""
    return Path(name).with_suffix("").as_posix().replace("/", "__")


def mask_file(name: str) -> str:
    """The file a frame's mask is written to, in the train stage's ``masks/``."""
    return f"{Path(name).stem}.png"


# -- ingest: images.json ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class PhotoRecord:
    """One ingested photo (or video frame), as ``images.json`` records it.

    ``name``: its file in ingest's ``images/``; ``source``: the photo it came from (relative to the capture) with
    its sha256 and bytes; ``width`` x ``height`` as ingested, ``source_width`` x ``source_height`` as taken,
    ``scale`` the one over the other; ``mask``: its alpha as ``masks/NAME`` (or None); ``exif``: the
    ``ExifSummary`` as JSON; ``focal_prior``: ``{"focal_px", "source"}`` (or None); ``split``: the capture's
    train/val/test (or None); ``video_frame`` and ``time_s`` for a video's frames.
    """

    name: str
    source: str = ""
    source_sha256: str = ""
    source_bytes: int = 0
    format: str | None = None
    width: int = 0
    height: int = 0
    source_width: int = 0
    source_height: int = 0
    scale: float = 1.0
    bit_depth: int = 8
    has_alpha: bool = False
    mask: str | None = None
    raw: bool = False
    linear: bool = False
    exif: dict[str, Any] = field(default_factory=dict)
    focal_prior: dict[str, Any] | None = None
    split: str | None = None
    video_frame: int | None = None
    time_s: float | None = None

    VIDEO = ("video_frame", "time_s")  # written only for a video's frames

    @property
    def focal_px(self) -> float | None:
        """The focal length prior in pixels, where EXIF gave one."""
        return None if self.focal_prior is None else self.focal_prior.get("focal_px")

    @property
    def gps(self) -> Any:
        return self.exif.get("gps")

    def to_json(self) -> dict[str, Any]:
        doc = dataclasses.asdict(self)
        for key in self.VIDEO:
            if doc[key] is None:
                del doc[key]
        return doc

    @staticmethod
    def from_json(doc: dict[str, Any]) -> "PhotoRecord":
        known = {f.name for f in dataclasses.fields(PhotoRecord)}
        return PhotoRecord(**{k: v for k, v in doc.items() if k in known})


@dataclass(frozen=True)
class ImageIndex:
    """Ingest's ``images.json``: the capture layout, one record per ingested photo, and the photos it skipped."""

    layout: str
    records: list[PhotoRecord]
    skipped: list[dict[str, Any]] = field(default_factory=list)

    @staticmethod
    def load(path: Path) -> ImageIndex:
        doc = _read(path)
        return ImageIndex(doc.get("layout", "folder"), [PhotoRecord.from_json(r) for r in doc["images"]],
                          doc.get("skipped", []))

    def save(self, path: Path) -> None:
        write_json_atomic(path, {"layout": self.layout, "images": [r.to_json() for r in self.records],
                                 "skipped": self.skipped})

    def by_name(self) -> dict[str, PhotoRecord]:
        return {r.name: r for r in self.records}


# -- bounds: bounds.json ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class FrameBounds:
    """Near and far depth (along the camera's z axis, normalized units) of one image, and how they were found."""

    name: str
    near: float
    far: float
    method: str


BOUNDS_CONVENTION = "world: z up, region of interest in [-1, 1]^3; near/far are depths along the camera z axis"


@dataclass(frozen=True)
class Bounds:
    """The bounds stage's ``bounds.json``: the similarity between the SfM frame and the normalized world,
    the scene box and each image's near/far.

    ``to_world`` and ``to_sfm`` are 4x4 similarities ``[s R | t]`` as nested lists (they travel into other
    JSON files as they are); ``scene_box`` is ``(lo, hi)``, two (3,) corners.
    """

    to_world: list[list[float]]
    to_sfm: list[list[float]]
    scale: float
    up: list[float]
    rig: str
    method: str
    scene_box: tuple[list[float], list[float]]
    near: float
    far: float
    frames: tuple[FrameBounds, ...]

    @staticmethod
    def load(path: Path) -> Bounds:
        doc = _read(path)
        frames = tuple(FrameBounds(f["name"], float(f["near"]), float(f["far"]), f["method"]) for f in doc["frames"])
        lo, hi = doc["scene_box"]
        return Bounds(doc["to_world"], doc["to_sfm"], doc["scale"], doc["up"], doc["rig"], doc["method"],
                      (lo, hi), float(doc["near"]), float(doc["far"]), frames)

    def save(self, path: Path) -> None:
        write_json_atomic(path, {
            "convention": BOUNDS_CONVENTION,
            "to_world": self.to_world,
            "to_sfm": self.to_sfm,
            "scale": self.scale,
            "up": self.up,
            "rig": self.rig,
            "method": self.method,
            "scene_box": [self.scene_box[0], self.scene_box[1]],
            "near": self.near,
            "far": self.far,
            "frames": [{"name": f.name, "near": f.near, "far": f.far, "method": f.method} for f in self.frames],
        })

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """The scene box's corners, two float64 (3,) arrays."""
        return np.asarray(self.scene_box[0], dtype=np.float64), np.asarray(self.scene_box[1], dtype=np.float64)

    def near_far(self) -> dict[str, tuple[float, float]]:
        """Image name -> (near, far)."""
        return {f.name: (f.near, f.far) for f in self.frames}


# -- scene: scene.json -----------------------------------------------------------------------------------
def show(value: Any) -> str:
    """A decision's value as a person reads it: ``(0.5, 1, 1)``, ``none``, ``true``."""
    if isinstance(value, (list, tuple)) and all(isinstance(v, (int, float)) for v in value):
        return "(" + ", ".join(f"{v:.3g}" for v in value) + ")"
    if value is None:
        return "none"
    return str(value).lower() if isinstance(value, bool) else str(value)


@dataclass(frozen=True)
class Decision:
    """One scene decision: its value, the evidence in a sentence, whether the user set it, what was measured."""

    value: Any
    evidence: str
    overridden: bool = False
    measured: dict[str, Any] = field(default_factory=dict)

    @staticmethod
    def made(value: Any, evidence: str, measured: dict[str, Any], override: Any = "auto") -> Decision:
        """The data's decision; an ``override`` other than "auto" replaces the value and keeps the evidence."""
        if override == "auto":
            return Decision(value, evidence, False, measured)
        return Decision(override, f"{evidence}; set by the user (the data suggested {show(value)})", True, measured)

    def to_json(self) -> dict[str, Any]:
        return {"value": self.value, "evidence": self.evidence, "overridden": self.overridden, "measured": self.measured}

    @staticmethod
    def from_json(doc: dict[str, Any]) -> Decision:
        return Decision(doc["value"], doc.get("evidence", ""), bool(doc.get("overridden", False)), doc.get("measured", {}))


@dataclass(frozen=True)
class SceneDecisions:
    """The scene stage's ``scene.json``: what the data called for, each with its evidence, plus the bounds
    the decisions were made from (``near``, ``far``, ``scene_box``)."""

    layout: Decision  # forward | inward360 | unbounded360
    background: Decision  # alpha | color | none
    background_color: Decision  # [r, g, b] in [0, 1], or None
    lens: Decision
    photometric: Decision  # srgb | linear_raw
    exposure_varies: Decision
    near: float
    far: float
    scene_box: tuple[list[float], list[float]]

    NAMES = ("layout", "background", "background_color", "lens", "photometric", "exposure_varies")

    @staticmethod
    def load(path: Path) -> SceneDecisions:
        doc = _read(path)
        lo, hi = doc["scene_box"]
        return SceneDecisions(**{name: Decision.from_json(doc[name]) for name in SceneDecisions.NAMES},
                              near=doc["near"], far=doc["far"], scene_box=(lo, hi))

    def save(self, path: Path) -> None:
        write_json_atomic(path, {
            **{name: getattr(self, name).to_json() for name in self.NAMES},
            "ndc": self.ndc,
            "near": self.near,
            "far": self.far,
            "scene_box": [self.scene_box[0], self.scene_box[1]],
        })

    @property
    def ndc(self) -> bool:
        """Forward-facing captures are trained in NDC (Section 6.1's real scenes)."""
        return self.layout.value == "forward"

    def backdrop(self) -> tuple[tuple[float, float, float], float] | None:
        """(colour, tolerance) of a constant backdrop: the background decision is ``color`` with a colour, and
        the tolerance is the one the scene analysis matched border pixels with (``measured["tolerance"]``,
        the largest per-channel difference); None otherwise (alpha, none, or a scene.json without it)."""
        color, tolerance = self.background_color.value, self.background.measured.get("tolerance")
        if self.background.value != "color" or color is None or tolerance is None:
            return None
        return (float(color[0]), float(color[1]), float(color[2])), float(tolerance)

    def decisions(self) -> dict[str, Decision]:
        return {name: getattr(self, name) for name in self.NAMES}

    def values(self) -> dict[str, Any]:
        return {name: decision.value for name, decision in self.decisions().items()}

    def describe(self) -> list[str]:
        """One line per decision, e.g. ``layout is inward360: cameras look at a common centre ...``; an overridden
        decision's evidence ends with ``set by the user (the data suggested ...)``."""
        return [f"{name} is {show(decision.value)}: {decision.evidence}" for name, decision in self.decisions().items()]


# -- train: views.json -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class ViewSplit:
    """The train stage's ``views.json``: which images trained the model, which were held out, and the rule."""

    train: list[str]
    heldout: list[str]
    rule: str

    @staticmethod
    def load(path: Path) -> ViewSplit:
        doc = _read(path)
        return ViewSplit(doc["train"], doc["heldout"], doc["rule"])

    def save(self, path: Path) -> None:
        write_json_atomic(path, {"train": self.train, "heldout": self.heldout, "rule": self.rule})


# -- typed references: the artifacts above by the name stages require them under, with their loaders -------
IMAGES_JSON = ArtifactRef("images_json", ImageIndex.load)
BOUNDS = ArtifactRef("bounds", Bounds.load)
SCENE = ArtifactRef("scene", SceneDecisions.load)
VIEWS = ArtifactRef("views", ViewSplit.load)
SFM_MODEL = ArtifactRef("sfm_model", CameraSet.load)  # the SfM frame, as COLMAP or the pose files gave it
PINHOLE = ArtifactRef("pinhole", CameraSet.load)  # undistorted
WORLD = ArtifactRef("world", CameraSet.load)  # normalized (bounds)
CAMERAS = ArtifactRef("cameras", CameraSet.load)  # as trained (refined poses)
