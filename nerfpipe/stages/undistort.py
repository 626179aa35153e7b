"""undistort: pinhole cameras for everything downstream, resampling only the images that need it.

NeRF rays are cast through pinhole cameras, so every camera leaves this stage as PINHOLE. A camera whose
lens moves some pixel by more than ``threshold_px`` has its images resampled (``geometry.distortion``)
into ``images/`` here and gets the pinhole camera of the resampled images; a camera within the threshold
keeps its K, drops its (negligible) distortion, and its images are not touched, not even copied: the
``pinhole`` camera set says per frame where its image lives (``hints.image_roots``), and
``frame_image_path`` turns that into a path.
"""

from __future__ import annotations

import dataclasses
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from nerfpipe.artifacts import IMAGES_JSON, SFM_MODEL, PhotoRecord
from nerfpipe.geometry.cameras import Camera, CameraSet, Frame
from nerfpipe.imaging.png import read_png, write_png
from nerfpipe.pipeline.errors import StageError
from nerfpipe.pipeline.summary import Summary
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs


@dataclass(frozen=True)
class UndistortParams:
    threshold_px: float = field(
        default=0.5,
        metadata={"bounds": (0.0, 1000.0), "help": "undistort a camera only when its lens moves some pixel by more than this many pixels"},
    )
    interpolation: Literal["linear", "cubic", "lanczos"] = field(
        default="cubic", metadata={"help": "resampling of the colour channels; alpha is always resampled linearly"}
    )

    def __post_init__(self) -> None:
        if not (math.isfinite(self.threshold_px) and self.threshold_px >= 0):
            raise ValueError(f"threshold_px must be a number of pixels >= 0, got {self.threshold_px}")


def remap_image(pixels: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, interpolation: str) -> np.ndarray:
    """Resample (H, W[, C]) pixels (uint8 / uint16, C = 1, 3 or 4) through remap tables (H', W') float32.

    Colour uses ``interpolation``; an alpha channel (C = 4) is resampled linearly, so a mask's edge
    becomes a ramp instead of ringing. Positions outside the image repeat the border pixel.
    """
    import cv2

    flags = {"linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC, "lanczos": cv2.INTER_LANCZOS4}[interpolation]
    border = cv2.BORDER_REPLICATE
    if pixels.ndim == 3 and pixels.shape[2] == 4:
        colour = cv2.remap(np.ascontiguousarray(pixels[..., :3]), map_x, map_y, flags, borderMode=border)
        alpha = cv2.remap(np.ascontiguousarray(pixels[..., 3]), map_x, map_y, cv2.INTER_LINEAR, borderMode=border)
        return np.dstack([colour, alpha])
    return cv2.remap(pixels, map_x, map_y, flags, borderMode=border)


def pinhole_of(camera: Camera) -> Camera:
    """The PINHOLE camera with ``camera``'s K, its distortion dropped."""
    return Camera.pinhole(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)


@dataclass(frozen=True)
class UndistortSummary(Summary):
    """The cameras, how many were resampled to pinhole and how far their distortion moved a pixel at most."""

    cameras: int = 0
    undistorted_cameras: int = 0
    images_undistorted: int = 0
    images_passed_through: int = 0
    max_displacement_px: float | None = 0.0  # None: beyond 90 degrees

    def describe(self) -> list[str]:
        moved = "beyond 90 degrees" if self.max_displacement_px is None else f"{self.max_displacement_px:.2f} px"
        if self.undistorted_cameras:
            return [f"{self.images_undistorted} images undistorted ({self.undistorted_cameras} of {self.cameras} "
                    f"cameras, max displacement {moved}), {self.images_passed_through} untouched"]
        return [f"{self.cameras} pinhole cameras, max displacement {moved}: images untouched"]


class UndistortStage(Stage):
    """Make every camera a pinhole: resample the images of cameras with noticeable lens distortion."""

    name = "undistort"
    version = 1
    Params = UndistortParams
    Summary = UndistortSummary
    presets = {
        "draft": {"interpolation": "linear"},
        "fast": {"interpolation": "linear"},
    }
    requires = ("images", "images_json", "sfm_model")
    provides = {"pinhole": "pinhole", "undistorted_images": "images"}
    libraries = ("numpy", "opencv-contrib-python-headless")

    def run(self, inputs: StageInputs, out: Path, params: UndistortParams, ctx: StageContext) -> UndistortSummary:
        from nerfpipe.geometry.distortion import max_distortion_displacement, undistortion_maps

        model = inputs.load(SFM_MODEL)
        records = inputs.load(IMAGES_JSON).by_name()
        self._check_frames(model, records)
        (out / "images").mkdir()
        (out / "pinhole").mkdir()

        displacement = {cid: max_distortion_displacement(camera) for cid, camera in model.cameras.items()}
        to_undistort = sorted(cid for cid, d in displacement.items() if d > params.threshold_px)
        for cid, camera in sorted(model.cameras.items()):
            if not np.all(np.abs(camera.distortion()) <= MAX_COEFFICIENT):  # NaN too
                coefficients = ", ".join(f"{c:g}" for c in camera.distortion() if c)
                ctx.log.warning("undistort: camera %d's distortion coefficients (%s) are far beyond any lens's (within "
                                "+-%g): the undistorted photos will be wrong; check the calibration in the pose file",
                                cid, coefficients, MAX_COEFFICIENT)
        frames_of: dict[int, list[Frame]] = {cid: [] for cid in model.cameras}
        for frame in model.frames:
            frames_of[frame.camera_id].append(frame)

        cameras = {cid: pinhole_of(camera) for cid, camera in model.cameras.items()}
        written: dict[int, int] = {}
        pool = ThreadPoolExecutor(os.cpu_count() or 1)  # cv2 releases the GIL while it decodes, remaps, encodes
        try:
            with ctx.progress(sum(len(frames_of[cid]) for cid in to_undistort), "undistort") as advance:
                for cid in to_undistort:
                    map_x, map_y, cameras[cid] = undistortion_maps(model.cameras[cid])
                    names = [f.name for f in frames_of[cid]]
                    for _ in pool.map(
                        self._resample,
                        [inputs["images"] / n for n in names],
                        [out / "images" / n for n in names],
                        [(map_x, map_y)] * len(names),
                        [params.interpolation] * len(names),
                    ):
                        advance(1)
                    written[cid] = len(names)
        finally:
            # on an error or Ctrl-C, images not yet started are dropped instead of resampled for nothing
            pool.shutdown(wait=True, cancel_futures=True)

        image_roots = {f.name: "undistort" if f.camera_id in written else "ingest" for f in model.frames}
        undistortion = {
            str(cid): {
                "model": model.cameras[cid].model,
                "max_displacement_px": round(d, 4) if math.isfinite(d) else None,  # None: a fisheye beyond 90 degrees
                "undistorted": cid in written,
            }
            for cid, d in sorted(displacement.items())
        }
        pinhole = CameraSet(
            cameras, model.frames, model.points, model.source, model.unregistered,
            dataclasses.replace(model.hints, image_roots=image_roots, undistortion=undistortion),
        )
        pinhole.save(out / "pinhole")

        ctx.log.info("undistort: %s", self._log_line(displacement, written, params.threshold_px))
        largest = max(displacement.values(), default=0.0)
        return UndistortSummary(
            cameras=len(model.cameras),
            undistorted_cameras=len(written),
            images_undistorted=sum(written.values()),
            images_passed_through=len(model.frames) - sum(written.values()),
            max_displacement_px=round(largest, 4) if math.isfinite(largest) else None,
        )

    @staticmethod
    def _resample(source: Path, target: Path, maps: tuple[np.ndarray, np.ndarray], interpolation: str) -> None:
        write_png(target, remap_image(read_png(source), *maps, interpolation))

    @staticmethod
    def _check_frames(model: CameraSet, records: dict[str, PhotoRecord]) -> None:
        for frame in model.frames:
            if frame.camera_id not in model.cameras:
                raise StageError(
                    f"sfm model: frame {frame.name} names camera {frame.camera_id}, which it does not hold"
                )
            record = records.get(frame.name)
            if record is None:
                raise StageError(
                    f"sfm model: frame {frame.name} is not an ingest image; rerun sfm on the current ingest output"
                )
            camera = model.cameras[frame.camera_id]
            if (record.width, record.height) != (camera.width, camera.height):
                raise StageError(
                    f"sfm model: frame {frame.name} is {record.width}x{record.height} pixels but its camera "
                    f"{frame.camera_id} is {camera.width}x{camera.height}; rerun sfm on the current ingest output"
                )

    @staticmethod
    def _log_line(displacement: dict[int, float], written: dict[int, int], threshold: float) -> str:
        """What the stage did: per undistorted camera for up to ``LOG_PER_CAMERA_MAX`` of them, else in sum
        ('71 cameras: max displacement 0.21-29 px; 70 undistorted (70 images), 1 within 0.5 px left as is')."""
        if not written:
            largest = max(displacement.values(), default=0.0)
            return f"max displacement {largest:.2f} px <= {threshold:g} px: images pass through untouched"
        kept = [d for cid, d in displacement.items() if cid not in written]
        if len(written) > LOG_PER_CAMERA_MAX:
            n = sum(written.values())
            line = (f"{len(displacement)} cameras: max displacement {_px_range(list(displacement.values()))}; "
                    f"{len(written)} undistorted ({n} image{'s' if n != 1 else ''})")
            return line + (f", {len(kept)} within {threshold:g} px left as is" if kept else "")
        parts = [
            f"undistorted {n} image{'s' if n != 1 else ''} of camera {cid} "
            f"(max displacement {displacement[cid]:.1f} px)"
            for cid, n in sorted(written.items())
        ]
        if kept:
            parts.append(f"{len(kept)} camera{'s' if len(kept) != 1 else ''} within {threshold:g} px "
                         f"(max {max(kept):.2f} px) pass{'' if len(kept) != 1 else 'es'} through untouched")
        return "; ".join(parts)


MAX_COEFFICIENT = 10.0  # radial and tangential coefficients of real lenses, fisheyes included, stay well within this
LOG_PER_CAMERA_MAX = 3  # up to this many undistorted cameras the log line names each one


def _px_range(values: list[float]) -> str:
    """'0.6-29 px' (two significant digits), '3.1 px' when all agree; fisheyes beyond 90° are counted apart."""
    finite = [v for v in values if math.isfinite(v)]
    beyond = len(values) - len(finite)
    text = []
    if finite:
        lo, hi = (f"{v:.0f}" if v >= 10 else f"{v:.2g}" for v in (min(finite), max(finite)))
        text.append(f"{lo} px" if lo == hi else f"{lo}-{hi} px")
    if beyond:
        text.append(f"{beyond} beyond 90° off-axis")
    return ", ".join(text)
