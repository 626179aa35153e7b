"""A web viewer of a finished run (viser): the mesh, the point cloud, the camera frusta with their photos,
and a live render of the radiance field from the browser's viewpoint.

Everything is shown in the model's normalized world (z up, the scene box in [-1, 1]^3), so the browser's
camera can be rendered as is: the mesh and the point cloud, stored in the SfM frame, are brought over by
the bounds stage's ``to_world`` similarity. The live render is progressive: when the view moves, a small
frame (``FAST_WIDTH`` pixels wide) is rendered at once and shown behind the geometry; once the view has
rested for ``REST_SECONDS``, the same view is rendered again at ``SHARP_WIDTH``.

While a field trains (``nerfpipe run --view``) the same viewer shows the model being trained: the view at rest
is rendered again every ``refresh_seconds``, smaller, so that watching costs training little time.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from nerfpipe.export.mesh import Mesh
from nerfpipe.export.points import Cloud
from nerfpipe.export.web_guard import LOOPBACK_NAMES, Gate, guarded, probe
from nerfpipe.export.web_render import client_c2w, render_view
from nerfpipe.pipeline.errors import NerfpipeError, ParamError

log = logging.getLogger("nerfpipe")

FAST_WIDTH, SHARP_WIDTH = 96, 320  # pixels across, of the live render while moving and once at rest
REST_SECONDS = 0.3
THUMB_WIDTH = 160  # pixels across, of the photos drawn in the frusta
START_BACK = 0.6  # the browser's first view: this share of the first camera's distance behind it (the world's
# origin is the scene's centre), turned by START_TURN_DEG about the up axis
START_TURN_DEG = 12.0


@dataclass
class WebFrame:
    """One camera to draw: its world c2w (OpenCV axes), vertical field of view (radians), aspect, photo."""

    name: str
    c2w: np.ndarray
    fov: float
    aspect: float
    photo: np.ndarray | None = None


@dataclass
class WebScene:
    """What the viewer shows, all in the normalized world; ``model`` renders the live view when given."""

    frames: list[WebFrame]
    mesh: Mesh | None = None
    points: Cloud | None = None
    model: Any = None
    near: float = 0.0
    far: float = 1.0
    sharp_width: int = SHARP_WIDTH  # pixels across of the render at rest
    refresh_seconds: float | None = None  # render the view at rest again this often (a field in training)
    run_dir: Path | None = None  # a finished run's folder: the panel (``web_panel``) writes its files there
    full_width: int = SHARP_WIDTH  # pixels across of the training photos: the panel's full-size render


def _wxyz(rotation: np.ndarray) -> np.ndarray:
    import viser.transforms as tf

    return tf.SO3.from_matrix(rotation).wxyz


@dataclass
class WebViewer:
    """A running viser server and what it holds (the tests look at these handles)."""

    server: Any
    scene: WebScene
    gate: Gate
    mesh: Any = None
    points: Any = None
    frusta: list[Any] = field(default_factory=list)
    renders: int = 0  # live frames rendered so far
    panel: Any = None  # the ``web_panel.Panel`` of a finished run's viewer
    _stop: threading.Event = field(default_factory=threading.Event)

    @property
    def url(self) -> str:
        """The URL to open: the only one the viewer answers, since it carries the gate's token."""
        host = self.server.get_host()
        shown = "localhost" if host in LOOPBACK else f"[{host}]" if ":" in host else host
        return f"http://{shown}:{self.server.get_port()}/?token={self.gate.token}"

    def stop(self) -> None:
        self._stop.set()
        self.server.stop()


LOOPBACK = ("127.0.0.1", "localhost", "::1")


def check_address(host: str, port: int) -> None:
    """Refuse, with one line, a port outside 1..65535 or one that something on ``host`` already listens on
    (naming a free one to try); viser would otherwise fail in a thread or quietly move to another port."""
    if not 1 <= port <= 65535:
        raise ParamError(f"--port {port}: a port is a number from 1 to 65535, e.g. --port 8080")
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        try:
            probe.bind((host, port))
        except OSError as err:
            if err.errno not in (errno.EADDRINUSE, errno.EACCES):
                raise ParamError(f"--host {host}: cannot listen there ({err.strerror}); use --host 127.0.0.1") from None
            with socket.socket(family, socket.SOCK_STREAM) as free:
                free.bind((host, 0))
                raise ParamError(f"--port {port}: {'in use' if err.errno == errno.EADDRINUSE else 'not allowed'} on "
                                 f"{host}; try --port {free.getsockname()[1]}") from None


def serve(scene: WebScene, host: str = "127.0.0.1", port: int = 8080, share: bool = False) -> WebViewer:
    """Start the viewer on ``host``:``port`` (this machine only, by default: the page shows the run's photos);
    it serves until ``stop()``. The live render runs in one thread per browser tab.

    Only requests with the token of ``WebViewer.url`` are answered (``web_guard``), with a loopback ``Host``
    unless ``host`` is another address, and WebSockets only from the viewer's own origin. ``share`` shows
    viser's share button, which publishes the viewer, photos included, through viser's public tunnel."""
    import viser

    check_address(host, port)
    if host not in LOOPBACK:
        log.warning("web viewer: listening on %s: anyone who can reach this machine on port %d and has the URL "
                    "(its token) sees the run's photos, cameras and model", host, port)
    gate = Gate(port, hosts=LOOPBACK_NAMES if host in LOOPBACK else ())
    server = guarded(gate, lambda: viser.ViserServer(host=host, port=port, verbose=False))
    gate.port = server.get_port()
    if probe(host, gate.port, {"Host": f"localhost:{gate.port}"}) != 403:  # the gate is not in front: fail closed
        server.stop()
        raise NerfpipeError(f"the web viewer cannot check who connects with viser {viser.__version__}; not serving "
                            "the run (install the viser version nerfpipe was tested with)")
    server.gui.configure_theme(show_share_button=share)
    if share:
        log.warning("web viewer: the share button publishes this viewer, the run's photos included, on a public "
                    "URL through viser's tunnel service, for anyone who has that URL")
    else:  # a page without the button could still send viser's share request
        server.request_share_url = lambda *args, **kwargs: None
    server.scene.set_up_direction("+z")
    viewer = WebViewer(server, scene, gate)
    # with a live render the geometry starts hidden (the render is behind it); the scene tree shows each
    if scene.mesh is not None:
        colors = scene.mesh.colors if scene.mesh.colors is not None else np.full((len(scene.mesh.vertices), 3), 0.7)
        import trimesh

        solid = trimesh.Trimesh(scene.mesh.vertices, scene.mesh.triangles, process=False,
                                vertex_colors=np.round(np.clip(colors, 0, 1) * 255).astype(np.uint8))
        viewer.mesh = server.scene.add_mesh_trimesh("/mesh", solid, visible=scene.model is None)
    if scene.points is not None:
        viewer.points = server.scene.add_point_cloud(
            "/points", scene.points.xyz.astype(np.float32), np.clip(scene.points.rgb, 0, 1).astype(np.float32),
            point_size=0.004, visible=scene.model is None and scene.mesh is None)
    centres = np.array([f.c2w[:3, 3] for f in scene.frames]) if scene.frames else np.zeros((1, 3))
    size = 0.03 * float(np.median(np.linalg.norm(centres - np.median(centres, axis=0), axis=1)) or 1.0)
    for i, frame in enumerate(scene.frames):
        viewer.frusta.append(server.scene.add_camera_frustum(
            f"/cameras/{i:04d}", fov=frame.fov, aspect=frame.aspect, scale=size, thickness=size / 80,
            image=frame.photo, wxyz=_wxyz(frame.c2w[:3, :3]), position=frame.c2w[:3, 3]))

    def on_connect(client: Any) -> None:
        if scene.frames:  # start behind the first photo's camera, looking at the scene's centre, z up
            first = scene.frames[0]
            client.camera.fov = first.fov
            turn = np.radians(START_TURN_DEG)  # about the up axis, so the first frustum does not hide the centre
            spin = np.array([[np.cos(turn), -np.sin(turn), 0.0], [np.sin(turn), np.cos(turn), 0.0], [0.0, 0.0, 1.0]])
            client.camera.position = (1 + START_BACK) * spin @ first.c2w[:3, 3]
            client.camera.look_at = np.zeros(3)
        if scene.model is not None:
            threading.Thread(target=live_render, args=(viewer, client), daemon=True).start()

    server.on_client_connect(on_connect)
    if scene.model is not None and scene.run_dir is not None:
        from nerfpipe.export.web_panel import add_panel

        viewer.panel = add_panel(viewer, scene.run_dir, scene.full_width)
    return viewer


def live_render(viewer: WebViewer, client: Any) -> None:
    """Render the client's view whenever it changes: fast at once, sharp once it has rested (``render_due``)."""
    shown: tuple | None = None
    while not viewer._stop.is_set() and client.client_id in viewer.server.get_clients():
        rendered = render_due(viewer, client, shown, time.time())
        if rendered is None:
            time.sleep(0.02)
        else:
            shown = rendered


def render_due(viewer: WebViewer, client: Any, shown: tuple | None, now: float) -> tuple | None:
    """One look at the client's view at time ``now`` (seconds, as its camera's ``update_timestamp``): render it
    if it moved since ``shown`` (camera state, width, time) was rendered (``FAST_WIDTH``), if it has rested
    ``REST_SECONDS`` since it moved and is not yet sharp (``sharp_width``), or if it rested and the scene asks
    for a refresh every ``refresh_seconds`` (a field in training). Returns what is shown now, None if nothing
    was rendered."""
    camera = client.camera
    state = (tuple(np.round(camera.wxyz, 5)), tuple(np.round(camera.position, 5)), round(camera.fov, 5),
             round(camera.aspect, 4))
    moved = shown is None or shown[0] != state
    rested = now - camera.update_timestamp > REST_SECONDS
    sharp = viewer.scene.sharp_width
    refresh = viewer.scene.refresh_seconds
    due = refresh is not None and shown is not None and now - shown[2] > refresh
    if not (moved or (rested and (shown[1] != sharp or due))):
        return None
    width = sharp if rested else FAST_WIDTH
    client.scene.set_background_image(render_view(viewer.scene, client_c2w(camera), camera.fov, camera.aspect, width),
                                      format="jpeg")
    viewer.renders += 1
    return state, width, now


def web_scene(model_dir: Path, cameras_dir: Path, images_dir: Path, bounds_json: Path,
              mesh_ply: Path | None = None, points_ply: Path | None = None, run_dir: Path | None = None) -> WebScene:
    """A finished run's results as a ``WebScene``: the train stage's model and cameras (the world frame), the
    ingested photos, the bounds (near, far and ``to_world``), and the mesh and point cloud when exported;
    ``run_dir`` (the run's folder) adds the panel that writes camera paths and full-size views there."""
    from nerfpipe.artifacts import Bounds
    from nerfpipe.export.mesh import read_mesh, transformed
    from nerfpipe.export.points import read_ply
    from nerfpipe.export.points import transformed as transformed_cloud
    from nerfpipe.geometry.cameras import CameraSet
    from nerfpipe.nerf.model import RadianceModel

    bounds = Bounds.load(bounds_json)
    cameras = CameraSet.load(cameras_dir)
    frames = web_frames(cameras, images_dir)
    mesh = transformed(read_mesh(mesh_ply), bounds.to_world) if mesh_ply is not None else None
    points = transformed_cloud(read_ply(points_ply), bounds.to_world) if points_ply is not None else None
    full_width = cameras.camera_of(cameras.frames[0]).width if cameras.frames else SHARP_WIDTH
    return WebScene(frames, mesh, points, RadianceModel.load(model_dir), bounds.near, bounds.far, run_dir=run_dir,
                    full_width=full_width)


def web_frames(cameras: Any, images_dir: Path) -> list[WebFrame]:
    """One ``WebFrame`` per frame of a world-frame ``CameraSet``, with its photo from ``images_dir``."""
    frames = []
    for frame in cameras.frames:
        camera = cameras.camera_of(frame)
        fov = 2 * float(np.arctan(0.5 * camera.height / camera.fy))
        frames.append(WebFrame(frame.name, np.asarray(frame.c2w), fov, camera.width / camera.height,
                               thumbnail(images_dir / frame.name)))
    return frames


def thumbnail(path: Path) -> np.ndarray | None:
    """A photo at ``THUMB_WIDTH`` pixels across, RGB, for a frustum; None when it cannot be read."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        return None
    height = max(1, round(image.shape[0] * THUMB_WIDTH / image.shape[1]))
    return cv2.resize(image, (THUMB_WIDTH, height), interpolation=cv2.INTER_AREA)[..., ::-1].copy()


# While training, the web viewer renders the view at rest every this many seconds, this many pixels across: a
# 160 x 120 frame of the demo's model renders in 0.2 s on a 2-core CPU, so watching costs training about 7%.
WATCH_REFRESH_SECONDS, WATCH_WIDTH = 3.0, 160


@contextlib.contextmanager
def watching(model: Any, world: Any, images: Path, bounds: Any, port: int | None, host: str,
             log: logging.Logger) -> Iterator[None]:
    """Serve the web viewer of ``model`` while it trains (the block), when a ``port`` is asked for (``nerfpipe
    run --view``): the training cameras of ``world`` with thumbnails of ``images``, out to ``bounds.far``."""
    if port is None:
        yield
        return
    scene = WebScene(web_frames(world, images), model=model, near=bounds.near, far=bounds.far,
                     sharp_width=WATCH_WIDTH, refresh_seconds=WATCH_REFRESH_SECONDS)
    viewer = serve(scene, host=host, port=port)
    log.info("train: watch the field learn at %s (the view at rest is rendered again every %.0f s)", viewer.url,
             WATCH_REFRESH_SECONDS)
    try:
        yield
    finally:
        viewer.stop()
        log.info("train: the training viewer stopped; `nerfpipe view RUN_DIR --web` shows the finished run")
