"""The web viewer's panel: the live render's resolution, the current view rendered at full size to a PNG, and
keyframes recorded into a ``camera_path.json`` that ``render.path=FILE`` renders (nerfstudio's camera-path
editor, in small).

Each control acts for the browser tab that used it: "Add keyframe" takes that tab's view, "Render full
size" renders it. Keyframes are drawn as orange frusta. What the panel writes goes into the run directory:
``RUN/camera_path.json`` and ``RUN/views/view_<time>.png``, never into the capture.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nerfpipe.export.camera_path import CameraPath, Keyframe
from nerfpipe.export.web_render import client_c2w, render_view

log = logging.getLogger("nerfpipe")

KEYFRAME_COLOUR = (255, 140, 0)
CAMERA_PATH = "camera_path.json"
VIEWS = "views"


@dataclass
class Panel:
    """The panel's state and actions; the GUI's controls call the actions with the clicking tab's camera (a
    viser camera: ``wxyz``, ``position``, ``fov`` vertical in radians, ``aspect``)."""

    viewer: Any  # the ``WebViewer``: its server draws the keyframes, its scene renders the views
    run_dir: Path
    full_width: int
    keyframes: list[Keyframe] = field(default_factory=list)
    handles: dict[str, Any] = field(default_factory=dict)
    frusta: list[Any] = field(default_factory=list)
    line: Any = None  # the path through the keyframes, as it will be rendered
    lock: threading.Lock = field(default_factory=threading.Lock)

    def add_keyframe(self, camera: Any) -> int:
        """The camera's view as the next keyframe, drawn as an orange frustum; returns how many there are."""
        with self.lock:
            self.keyframes.append(Keyframe(client_c2w(camera), math.degrees(camera.fov)))
            self.frusta.append(self.viewer.server.scene.add_camera_frustum(
                f"/keyframes/{len(self.keyframes) - 1:03d}", fov=camera.fov, aspect=camera.aspect, scale=0.12,
                thickness=0.004, color=KEYFRAME_COLOUR, wxyz=np.asarray(camera.wxyz), position=np.asarray(camera.position)))
            self._draw_line()
            return len(self.keyframes)

    def _draw_line(self) -> None:
        """The camera centres along the path the keyframes make (the spline the render follows)."""
        if self.line is not None:
            self.line.remove()
            self.line = None
        if len(self.keyframes) > 1:
            poses, _ = CameraPath(tuple(self.keyframes), frames=16 * len(self.keyframes)).sample()
            self.line = self.viewer.server.scene.add_spline_catmull_rom(
                "/keyframes/path", poses[:, :3, 3], thickness=0.006, color=KEYFRAME_COLOUR)

    def clear(self) -> None:
        with self.lock:
            for frustum in self.frusta:
                frustum.remove()
            self.keyframes.clear()
            self.frusta.clear()
            self._draw_line()

    def save(self, frames: int, fps: float, loop: bool) -> Path:
        """Write the keyframes as ``RUN/camera_path.json``; returns its path. ``ValueError`` without keyframes."""
        with self.lock:
            path = CameraPath(tuple(self.keyframes), frames, fps, loop)
            target = self.run_dir / CAMERA_PATH
            path.save(target)
        log.info("web viewer: saved %s (%d keyframes, %d frames at %g fps); render it with --set render.path=%s",
                 target, len(path.keyframes), frames, fps, target)
        return target

    def render_full(self, camera: Any) -> Path:
        """The camera's view rendered ``full_width`` pixels across, as ``RUN/views/view_<time>.png``."""
        from nerfpipe.imaging.png import write_png

        image = render_view(self.viewer.scene, client_c2w(camera), camera.fov, camera.aspect, self.full_width)
        folder = self.run_dir / VIEWS
        folder.mkdir(parents=True, exist_ok=True)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        target = next(folder / f"view_{stamp}{f'-{n}' if n else ''}.png" for n in range(10_000)
                      if not (folder / f"view_{stamp}{f'-{n}' if n else ''}.png").exists())
        write_png(target, image)
        log.info("web viewer: rendered the view at %dx%d -> %s", image.shape[1], image.shape[0], target)
        return target


def add_panel(viewer: Any, run_dir: Path, full_width: int) -> Panel:
    """Add the panel's controls to ``viewer`` (a ``WebViewer`` whose scene has a model); it writes into
    ``run_dir``. ``full_width``: pixels across of "Render full size" (the training photos' width)."""
    gui, scene = viewer.server.gui, viewer.scene
    panel = Panel(viewer, run_dir, full_width)
    with gui.add_folder("Render"):
        resolution = gui.add_slider("Resolution", min=64, max=max(64, full_width), step=16,
                                    initial_value=min(scene.sharp_width, max(64, full_width)),
                                    hint="pixels across of the live render once the view rests")
        full = gui.add_button("Render full size", hint=f"this view at {full_width} px across, into {run_dir / VIEWS}")
    with gui.add_folder("Camera path"):
        add = gui.add_button("Add keyframe", hint="the current view becomes the path's next keyframe")
        clear = gui.add_button("Clear keyframes")
        frames = gui.add_number("Frames", initial_value=120, min=2, max=10_000, step=1)
        fps = gui.add_number("FPS", initial_value=24.0, min=1.0, max=120.0, step=1.0)
        loop = gui.add_checkbox("Loop", initial_value=False)
        save = gui.add_button("Save camera_path.json", disabled=True)
        status = gui.add_markdown("No keyframes yet.")
    panel.handles = {"resolution": resolution, "full": full, "add": add, "clear": clear, "frames": frames,
                     "fps": fps, "loop": loop, "save": save, "status": status}

    @resolution.on_update
    def _(_event: Any) -> None:
        scene.sharp_width = int(resolution.value)

    @add.on_click
    def _(event: Any) -> None:
        count = panel.add_keyframe(event.client.camera)
        save.disabled = False
        status.content = f"{count} keyframe{'s' * (count != 1)}."

    @clear.on_click
    def _(_event: Any) -> None:
        panel.clear()
        save.disabled = True
        status.content = "No keyframes yet."

    @save.on_click
    def _(_event: Any) -> None:
        if panel.keyframes:
            target = panel.save(int(frames.value), float(fps.value), bool(loop.value))
            status.content = (f"Saved `{target}`. Render it: `nerfpipe run PHOTOS --out {run_dir} "
                              f"--set render.path={target}`")

    @full.on_click
    def _(event: Any) -> None:
        full.disabled = True
        status.content = f"Rendering {full_width} px across..."
        try:
            target = panel.render_full(event.client.camera)
            status.content = f"Saved `{target}`."
        finally:
            full.disabled = False

    return panel
