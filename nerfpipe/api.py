"""A finished run from Python: its cameras in the SfM frame, its field rendered from any of them (or any camera
of yours), its exports and its figures.

    import nerfpipe

    run = nerfpipe.open("runs/temple")
    view = run.render(run.heldout[0], size=320)   # a held-out view, 320 px on its long side
    print(view.rgb.shape, view.depth.max(), run.metrics["psnr"])

Everything a ``Run`` takes and gives is in the SfM frame, as the exports are (``exports/transforms.json``,
``exports/sparse/0``): camera-to-world matrices with OpenCV axes (x right, y down, z forward), depths in that
frame's units. The normalized world the field was trained in stays inside.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from nerfpipe.geometry.cameras import Camera, CameraSet, Frame
from nerfpipe.pipeline import Pipeline


@dataclass(frozen=True)
class Rendered:
    """A rendered view: ``rgb`` (H, W, 3) float32 in [0, 1] as the photos' colours; ``depth`` (H, W) float32,
    the expected depth along the camera axis in the SfM frame's units; ``opacity`` (H, W) float32, the
    accumulated opacity (near 0 where the ray met nothing, and its depth means little)."""

    rgb: np.ndarray
    depth: np.ndarray
    opacity: np.ndarray


class Run:
    """A run directory of ``nerfpipe run``, read through its current results (``open``)."""

    def __init__(self, run_dir: str | Path, device: str = "cpu") -> None:
        from nerfpipe.stages import default_stages

        self.path = Path(run_dir)
        self.device = device
        self._pipe = Pipeline.from_run_dir(default_stages(), self.path)

    # -- cameras -----------------------------------------------------------------------------------------
    @cached_property
    def cameras(self) -> CameraSet:
        """The cameras the field was trained with (refined where pose refinement ran), in the SfM frame."""
        from nerfpipe.export.bundle import in_sfm_frame

        return in_sfm_frame(CameraSet.load(self._pipe.artifact("cameras", "trained cameras")), self._bounds.to_sfm)

    @property
    def names(self) -> list[str]:
        """The views' names, in the cameras' order (``render`` takes a name or its index here)."""
        return [f.name for f in self.cameras.frames]

    @cached_property
    def heldout(self) -> list[str]:
        """The views training never saw, scored in ``metrics``."""
        from nerfpipe.artifacts import ViewSplit

        return list(ViewSplit.load(self._pipe.artifact("views", "the train/held-out split")).heldout)

    def photo(self, view: int | str) -> np.ndarray:
        """The photo of a view as training saw it (undistorted), (H, W, 3) float32 in [0, 1], in the colours
        ``render`` gives (a RAW capture's linear photos sRGB-encoded, as its renders are)."""
        from nerfpipe.imaging.png import srgb_encode
        from nerfpipe.nerf.train.images import ImageLoader

        name = self._frame(view).name
        loader = ImageLoader.from_inputs(self._pipe.stage_inputs("train"))
        pixels = loader.stored(next(f for f in loader.world.frames if f.name == name))[..., :3]
        return srgb_encode(pixels).astype(np.float32) if self._linear else pixels

    @cached_property
    def _linear(self) -> bool:
        """Whether the field was trained on linear RAW photos (the scene stage's photometric decision)."""
        from nerfpipe.artifacts import SceneDecisions

        return SceneDecisions.load(self._pipe.artifact("scene", "scene decisions")).photometric.value == "linear_raw"

    # -- rendering ---------------------------------------------------------------------------------------
    def render(self, view: int | str | tuple[np.ndarray, Camera], size: int | tuple[int, int] | None = None,
               chunk: int = 8192) -> Rendered:
        """Render the field from a view: an index or name of ``cameras``, or ``(c2w, camera)``, a (4, 4)
        camera-to-world in the SfM frame (OpenCV axes) and a pinhole ``Camera``. ``size``: the long side in
        pixels, or (width, height); by default the camera's own size."""
        import torch

        from nerfpipe.export.camera_path import view_range
        from nerfpipe.geometry.normalize import Similarity
        from nerfpipe.imaging.png import srgb_encode

        if isinstance(view, tuple):
            c2w_sfm, camera = np.asarray(view[0], dtype=np.float64), view[1]
            name = None
        else:
            frame = self._frame(view)
            c2w_sfm, camera, name = frame.c2w, self.cameras.camera_of(frame), frame.name
        width, height = _size(camera, size)
        scaled = camera.scaled(width / camera.width, height / camera.height)
        to_sfm = Similarity.from_matrix(np.asarray(self._bounds.to_sfm))
        c2w = to_sfm.inverse().apply_c2w(c2w_sfm)
        near, far = self._bounds.near_far().get(name) or view_range(c2w, self._bounds.far)
        with torch.no_grad():
            out = self._model.render_image(scaled.intrinsics, c2w, width, height, near, far,
                                           chunk)
        rgb = out["rgb"].clamp(0.0, 1.0).numpy()
        if self._linear:
            rgb = srgb_encode(rgb)
        return Rendered(rgb.astype(np.float32), (out["depth"].numpy() * to_sfm.scale).astype(np.float32),
                        out["acc"].numpy().astype(np.float32))

    # -- what the run made ---------------------------------------------------------------------------------
    @property
    def exports(self) -> dict[str, Path]:
        """The run's ``exports/`` folder: each file or folder in it by name (``mesh.glb``, ``transforms.json``...)."""
        folder = self.path / "exports"
        return {p.name: p for p in sorted(folder.iterdir())} if folder.is_dir() else {}

    @cached_property
    def metrics(self) -> dict[str, Any]:
        """The train stage's figures (``metrics.json``): held-out PSNR and SSIM, steps, rays a second..."""
        return json.loads(self._pipe.artifact("metrics", "training figures").read_text(encoding="utf-8"))

    # -- inside ----------------------------------------------------------------------------------------------
    @cached_property
    def _bounds(self) -> Any:
        from nerfpipe.artifacts import Bounds

        return Bounds.load(self._pipe.artifact("bounds", "bounds"))

    @cached_property
    def _model(self) -> Any:
        from nerfpipe.nerf.device import resolve_device
        from nerfpipe.nerf.model import RadianceModel

        return RadianceModel.load(self._pipe.artifact("model", "trained model").parent, resolve_device(self.device, "nerfpipe.open(device=...)"))

    def _frame(self, view: int | str) -> Frame:
        frames = self.cameras.frames
        if isinstance(view, (int, np.integer)) and not isinstance(view, bool):
            if not -len(frames) <= view < len(frames):
                raise IndexError(f"view {view} of {len(frames)}")
            return frames[view]
        for frame in frames:
            if frame.name == view:
                return frame
        raise KeyError(f"no view named {view!r}; Run.names lists them")

    def __repr__(self) -> str:
        return f"nerfpipe.Run({str(self.path)!r})"


def _size(camera: Camera, size: int | tuple[int, int] | None) -> tuple[int, int]:
    if size is None:
        return camera.width, camera.height
    if isinstance(size, tuple):
        width, height = (int(v) for v in size)
    else:
        scale = int(size) / max(camera.width, camera.height)
        width, height = max(1, round(camera.width * scale)), max(1, round(camera.height * scale))
    if width < 1 or height < 1:
        raise ValueError(f"size {size!r}: width and height must be at least 1")
    return width, height


def open(run_dir: str | Path, device: str = "cpu") -> Run:  # noqa: A001 -- as nerfpipe.open, like io.open
    """A finished run: ``nerfpipe.open("runs/temple").render(0)``. ``device``: where the field renders
    (``cpu``, ``cuda``, ``auto``)."""
    return Run(run_dir, device)
