"""ingest: the capture's photos as upright, downscaled PNGs plus ``images.json``.

Reads JPEG, PNG, TIFF and camera RAW (through rawpy/LibRaw), applies EXIF orientation, keeps alpha,
downscales with area resampling, and records EXIF priors (focal length, make, model, exposure) for SfM.
The photos themselves are only ever read.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from nerfpipe.artifacts import ImageIndex, PhotoRecord, output_names
from nerfpipe.imaging.png import write_png
from nerfpipe.pipeline.errors import BadPhotoError, InputError
from nerfpipe.pipeline.fingerprint import Fingerprint
from nerfpipe.pipeline.summary import Summary
from nerfpipe.pipeline.stage import Stage, StageContext, StageInputs
from nerfpipe.poses.layout import detect_layout

log = logging.getLogger("nerfpipe")


@dataclass(frozen=True)
class IngestParams:
    max_size: int = field(default=1600, metadata={"bounds": (0, 65_536), "help": "longest side in pixels after downscaling; 0 keeps full size"})
    bit_depth: Literal["auto", "8", "16"] = field(
        default="auto", metadata={"help": "PNG bit depth; auto = 16 for RAW and 16-bit sources, else 8"}
    )
    alpha: Literal["channel", "mask"] = field(
        default="channel", metadata={"help": "keep an alpha channel as RGBA PNGs, or as separate masks/*.png"}
    )
    raw_linear: bool = field(default=False, metadata={"help": "RAW: linear (gamma 1) output for HDR use"})
    raw_highlight_mode: Literal["clip", "ignore", "blend", "reconstruct"] = field(
        default="clip", metadata={"help": "RAW: LibRaw highlight mode"}
    )
    raw_white_balance: Literal["camera", "auto", "daylight"] = field(
        default="camera", metadata={"help": "RAW: white balance (as shot by the camera, auto, or daylight)"}
    )
    min_size: int = field(default=32, metadata={"bounds": (1, 65_536), "help": "refuse photos whose shorter side is below this many pixels"})
    max_megapixels: float = field(
        default=250.0,
        metadata={"bounds": (0.0, 10000.0), "help": "refuse photos above this size, read from the header before decoding (a guard against "
                  "decompression bombs; 0 = no limit); today's largest camera and phone photos are 200 MP"},
    )
    video_frames: int = field(
        default=150, metadata={"bounds": (2, 10_000), "help": "a video capture: frames to keep, each the sharpest of its stretch of the video"}
    )
    skip_bad: bool = field(default=False, metadata={"help": "skip unreadable or duplicate photos with a warning"})
    workers: int = field(default=0, metadata={"keyed": False, "bounds": (0, 256), "help": "decoding threads; 0 = one per CPU core"})

    def __post_init__(self) -> None:
        if self.max_size < 0:
            raise ValueError(f"max_size must be 0 (no downscaling) or a positive size, got {self.max_size}")
        if self.max_size and self.max_size < 16:
            raise ValueError(f"max_size {self.max_size} is too small for SfM; use at least 16 (or 0 for full size)")
        if self.raw_linear and self.bit_depth == "8":
            raise ValueError("raw_linear needs 16-bit output; set ingest.bit_depth=16 or auto")
        if self.video_frames < 2:
            raise ValueError(f"video_frames must be at least 2 (SfM needs two views), got {self.video_frames}")
        if self.min_size < 1:
            raise ValueError(f"min_size must be at least 1 pixel, got {self.min_size}")
        if self.max_megapixels < 0:
            raise ValueError(f"max_megapixels must be 0 (no limit) or positive, got {self.max_megapixels}")
        if 0 < self.max_megapixels * 1e6 < 1:  # would round to 0 pixels, which reads as no limit
            raise ValueError(f"max_megapixels {self.max_megapixels:g} is below one pixel; use 0 for no limit")
        if self.workers < 0:
            raise ValueError(f"workers must be >= 0, got {self.workers}")


PNG_SHARE = 0.2  # PNG bytes / pixel bytes of a typical photo, for the free-space check
MAX_ASPECT = 10  # a photo longer than this many times its width is no camera view (panoramas: 2-8)
MIN_VIDEO_FRAMES = 3  # fewer views than SfM can reconstruct from: refused at ingest, naming the video


def target_size(width: int, height: int, max_size: int) -> tuple[int, int]:
    """Size after fitting the longest side into ``max_size`` (never upscales); 0 means no limit."""
    longest = max(width, height)
    if max_size == 0 or longest <= max_size:
        return width, height
    scale = max_size / longest
    return max(1, round(width * scale)), max(1, round(height * scale))


def to_bit_depth(pixels: np.ndarray, bits: int) -> np.ndarray:
    if bits == 16 and pixels.dtype == np.uint8:
        return pixels.astype(np.uint16) * 257
    if bits == 8 and pixels.dtype == np.uint16:
        return ((pixels.astype(np.uint32) + 128) // 257).astype(np.uint8)
    return pixels


@dataclass(frozen=True)
class IngestSummary(Summary):
    """What ingest made: photos (or a video's frames), their megapixels as taken, and how many were skipped,
    RAW, with alpha or with an EXIF focal prior."""

    images: int = 0
    skipped: int = 0
    source_megapixels: float = 0.0
    raw: int = 0
    with_alpha: int = 0
    with_focal_prior: int = 0
    video: dict[str, Any] | None = None  # {"file", "frames", "fps", "seconds"} for a video capture

    def describe(self) -> list[str]:
        if self.video is not None:
            v = self.video
            return [f"{self.images} frames of {v['file']} ({v['frames']} frames, {v['seconds']:.0f} s at "
                    f"{v['fps']:g} fps), each the sharpest of its stretch"]
        line = f"{self.images} photos ({self.source_megapixels} MP)"
        extras = [f"{n} {label}" for n, label in ((self.skipped, "skipped"), (self.raw, "RAW"),
                                                  (self.with_alpha, "with alpha"),
                                                  (self.with_focal_prior, "with an EXIF focal prior")) if n]
        return [line + (", " + ", ".join(extras) if extras else "")]


class IngestStage(Stage):
    """Decode photos (JPEG, PNG, TIFF, camera RAW), apply EXIF orientation, downscale, write PNGs + images.json."""

    name = "ingest"
    version = 3  # 2: layout and splits in images.json, sub-folder names; 3: short or tiny videos refused
    Params = IngestParams
    Summary = IngestSummary
    presets = {
        "draft": {"max_size": 400},
        "fast": {"max_size": 800},
        "balanced": {"max_size": 1600},
        # Section 6.1: the paper trains its real forward-facing scenes on 1008x756 images.
        "paper": {"max_size": 1008},
        "full": {"max_size": 0},
        "hdr": {"raw_linear": True, "bit_depth": "16"},
    }
    provides = {"images": "images", "images_json": "images.json"}
    libraries = ("numpy", "opencv-contrib-python-headless", "rawpy")
    inputs_label = "photos"

    def input_files(self, source: Path, params: IngestParams) -> list[Path]:
        """The photos, their heads checked before the engine hashes them: a file that is no photo (a 3 GB
        file of zeros named .jpg) is refused for a read of 64 KB, not after hashing it (unless
        ``skip_bad``, which skips it later with a warning)."""
        from nerfpipe.imaging import photo_kind
        from nerfpipe.imaging.integrity import check_head

        photos = detect_layout(source).photos
        if not params.skip_bad:
            for photo in photos:
                if (kind := photo_kind(photo)) is not None:
                    check_head(photo, kind, size=1 << 16)
            return photos
        readable = []
        for photo in photos:  # the engine hashes what is returned: a file it cannot read is skipped here
            try:
                with open(photo, "rb") as f:
                    f.read(1)
            except OSError as err:
                log.warning("skipped %s: cannot be read (%s)", photo, err.strerror or err)
                continue
            readable.append(photo)
        return readable

    def expected_bytes(self, inputs: StageInputs, params: IngestParams) -> int:
        """The PNGs' size from the photos' headers: their pixels at the output size and depth, times the
        share PNG keeps of a photo (measured 0.09 to 0.4 on the shared captures; 0.2 taken)."""
        from nerfpipe.imaging import read_header

        total = 0
        for fp in inputs.files:
            header = read_header(inputs.path(fp))
            if header is not None:
                width, height = target_size(header.width, header.height, params.max_size)
                depth = 2 if params.bit_depth == "16" else header.bytes_per_sample if params.bit_depth == "auto" else 1
                total += width * height * header.channels * depth
        return int(total * PNG_SHARE)

    def run(self, inputs: StageInputs, out: Path, params: IngestParams, ctx: StageContext) -> IngestSummary:
        from nerfpipe.imaging import RawOptions

        raw = RawOptions(params.raw_linear, params.raw_highlight_mode, params.raw_white_balance)
        (out / "images").mkdir()
        layout = detect_layout(inputs.source)
        if layout.kind == "video":
            return self._video(inputs, out, params, ctx)
        if params.alpha == "mask":
            (out / "masks").mkdir()
        names = output_names([fp.relpath for fp in inputs.files])
        first_of: dict[str, str] = {}
        duplicate_of: dict[str, str] = {}
        for fp in inputs.files:
            if fp.size > 0:  # empty files are reported as empty, not as duplicates of each other
                duplicate_of[fp.relpath] = first_of.setdefault(fp.sha256, fp.relpath)

        def convert(fp: Fingerprint) -> dict[str, Any] | BadPhotoError:
            try:
                return self._convert(inputs, fp, names[fp.relpath], duplicate_of.get(fp.relpath), out, params, raw)
            except BadPhotoError as err:
                return err

        records, skipped = [], []
        pool = ThreadPoolExecutor(params.workers or os.cpu_count() or 1)
        try:
            with ctx.progress(len(inputs.files), "ingest") as advance:
                # map keeps input order, so "the first bad photo" is the first by name, whatever the threads do
                for fp, result in zip(inputs.files, pool.map(convert, inputs.files)):
                    advance(1)
                    if isinstance(result, BadPhotoError):
                        if not params.skip_bad:
                            raise result
                        ctx.log.warning("skipped %s: %s", result.path, result.problem)
                        skipped.append({"source": fp.relpath, "reason": result.problem})
                    else:
                        records.append(result)
        finally:
            # on an error or Ctrl-C, photos not yet started are dropped instead of decoded for nothing
            pool.shutdown(wait=True, cancel_futures=True)
        if not records:
            raise InputError(inputs.source, "none of the photos could be used", "see the warnings above for each file")

        records = [dataclasses.replace(r, split=layout.splits.get(r.source)) for r in records]
        ImageIndex(layout.kind, records, skipped).save(out / "images.json")
        megapixels = sum(r.source_width * r.source_height for r in records) / 1e6
        ctx.log.info(
            "ingest: %d photos (%.1f MP) -> %s%s",
            len(records),
            megapixels,
            ", ".join(sorted({f"{r.width}x{r.height}" for r in records})),
            f", {len(skipped)} skipped" if skipped else "",
        )
        return IngestSummary(images=len(records), skipped=len(skipped), source_megapixels=round(megapixels, 3),
                             raw=sum(r.raw for r in records), with_alpha=sum(r.has_alpha for r in records),
                             with_focal_prior=sum(r.focal_prior is not None for r in records))

    @staticmethod
    def _video(inputs: StageInputs, out: Path, params: IngestParams, ctx: StageContext) -> IngestSummary:
        """A video capture: about ``video_frames`` frames, each the sharpest of its window, as PNGs; each
        record keeps the frame's index and time in the video."""
        import cv2

        from nerfpipe.imaging import ExifSummary
        from nerfpipe.imaging.video import sharpest_frames

        (fp,) = inputs.files
        path = inputs.path(fp)

        def shrink(rgb: np.ndarray) -> np.ndarray:
            size = target_size(rgb.shape[1], rgb.shape[0], params.max_size)
            return rgb if size == rgb.shape[1::-1] else cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)

        frames, decoded, rate = sharpest_frames(path, params.video_frames, shrink)
        src_w, src_h = frames[0].source_size
        if min(src_w, src_h) < params.min_size:
            raise BadPhotoError(path, f"has frames of only {src_w}x{src_h} pixels, below ingest.min_size="
                                f"{params.min_size}", "pass a video of a higher resolution")
        if len(frames) < MIN_VIDEO_FRAMES:
            raise BadPhotoError(path, f"holds only {decoded} frame{'s' * (decoded != 1)}; a reconstruction needs at "
                                f"least {MIN_VIDEO_FRAMES} views (a NeRF wants dozens)",
                                "pass a video that walks round the subject, a few seconds or more")
        records = []
        for i, frame in enumerate(frames):
            src_w, src_h = frame.source_size
            pixels = frame.pixels
            height, width = pixels.shape[:2]
            name = f"frame_{i:04d}.png"  # numbered in order, so SfM matches them sequentially
            write_png(out / "images" / name, pixels)
            records.append(PhotoRecord(
                name=name, source=fp.relpath, source_sha256=fp.sha256, source_bytes=fp.size, format="video",
                width=width, height=height, source_width=src_w, source_height=src_h, scale=width / src_w, bit_depth=8,
                has_alpha=False, mask=None, raw=False, linear=False, exif=ExifSummary().to_json(), focal_prior=None,
                split=None, video_frame=frame.index, time_s=round(frame.time_s, 4),
            ))
        ImageIndex("video", records).save(out / "images.json")
        seconds = decoded / rate
        ctx.log.info("ingest: %d of the %d frames of %s (%.0f s at %.3g fps), each the sharpest of its %.2f s -> %dx%d",
                     len(records), decoded, fp.relpath, seconds, rate, seconds / len(records),
                     records[0].width, records[0].height)
        return IngestSummary(
            images=len(records),
            source_megapixels=round(sum(r.source_width * r.source_height for r in records) / 1e6, 3),
            video={"file": fp.relpath, "frames": decoded, "fps": round(rate, 3), "seconds": round(seconds, 3)},
        )

    @staticmethod
    def _convert(
        inputs: StageInputs,
        fp: Fingerprint,
        name: str,
        duplicate_of: str | None,
        out: Path,
        params: IngestParams,
        raw: Any,
    ) -> PhotoRecord:
        import cv2

        from nerfpipe.imaging import (
            PhotoSizeError,
            SizeLimits,
            focal_prior_px,
            photo_kind,
            read_photo,
        )

        path = inputs.path(fp)
        if duplicate_of is not None and duplicate_of != fp.relpath:
            raise BadPhotoError(
                path, f"is the same photo as {duplicate_of} (identical content)", "remove one of them, or pass --skip-bad"
            )
        limits = SizeLimits(params.min_size, round(params.max_megapixels * 1e6))
        try:
            photo = read_photo(path, raw, limits, sha256=fp.sha256)
        except PhotoSizeError as err:
            if err.too == "small":
                problem = f"{err.problem}, below ingest.min_size={params.min_size}"
                advice = "remove it from the photo folder or pass --skip-bad (lower ingest.min_size if it is a real photo)"
            else:
                problem = f"{err.problem}, above ingest.max_megapixels={params.max_megapixels:g}"
                advice = (f"if it is a real photo, raise the limit with --set ingest.max_megapixels="
                          f"{math.ceil(err.size[0] * err.size[1] / 1e6)}; otherwise remove it or pass --skip-bad")
            raise BadPhotoError(path, problem, advice) from None
        pixels = photo.pixels
        src_w, src_h = photo.source_size
        if max(src_w, src_h) > MAX_ASPECT * min(src_w, src_h):
            raise BadPhotoError(path, f"is {src_w}x{src_h} pixels, {max(src_w, src_h) / min(src_w, src_h):.0f} times "
                                f"as long as it is wide: no camera view (at most {MAX_ASPECT}:1 is taken)",
                                "remove it from the photo folder or pass --skip-bad")
        width, height = target_size(src_w, src_h, params.max_size)
        if (width, height) != (src_w, src_h):
            pixels = cv2.resize(pixels, (width, height), interpolation=cv2.INTER_AREA)
        bits = 16 if params.bit_depth == "16" or (params.bit_depth == "auto" and photo.bit_depth == 16) else 8
        pixels = to_bit_depth(pixels, bits)
        mask_rel = None
        if photo.has_alpha and params.alpha == "mask":
            mask_rel = f"masks/{name}"
            write_png(out / mask_rel, np.ascontiguousarray(pixels[..., 3]))
            pixels = np.ascontiguousarray(pixels[..., :3])
        write_png(out / "images" / name, pixels)
        prior = focal_prior_px(photo.exif, width, height)
        return PhotoRecord(
            name=name,
            source=fp.relpath,
            source_sha256=fp.sha256,
            source_bytes=fp.size,
            format=photo_kind(path),
            width=width,
            height=height,
            source_width=src_w,
            source_height=src_h,
            scale=width / src_w,
            bit_depth=bits,
            has_alpha=photo.has_alpha,
            mask=mask_rel,
            raw=photo.is_raw,
            linear=photo.linear,
            exif=photo.exif.to_json(),
            focal_prior=None if prior is None else {"focal_px": prior[0], "source": prior[1]},
        )
