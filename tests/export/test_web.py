"""The web viewer's live render: what it renders when, for a finished field and for one in training."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from nerfpipe.export import web
from nerfpipe.export.web import FAST_WIDTH, SHARP_WIDTH, WebScene, WebViewer
from nerfpipe.export.web_guard import Gate


class CountingModel:
    """Renders a flat grey frame of the asked size and records each width."""

    def __init__(self) -> None:
        self.widths: list[int] = []

    def render_image(self, intrinsics, c2w, width, height, near, far):
        self.widths.append(width)
        return {"rgb": torch.full((height, width, 3), 0.5)}


@dataclass
class FakeClient:
    """The parts of a viser client the live render reads (its camera) and writes (the background image)."""

    client_id: int = 1
    camera: SimpleNamespace = field(default_factory=lambda: SimpleNamespace(
        wxyz=np.array([1.0, 0.0, 0.0, 0.0]), position=np.array([0.0, -3.0, 0.0]), fov=0.8, aspect=4 / 3,
        update_timestamp=time.time()))
    shown: list[tuple[int, int]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.scene = SimpleNamespace(set_background_image=lambda image, format: self.shown.append(image.shape[:2]))


def watch(scene: WebScene, client: FakeClient, seconds: float, move_at: float | None = None,
          tick: float = 0.02) -> None:
    """The live render looking at ``client`` every ``tick`` seconds for ``seconds`` of a clock the test keeps
    (no thread, no sleep), its camera moved once at ``move_at``."""
    server = SimpleNamespace(get_clients=lambda: {client.client_id: client})
    viewer = WebViewer(server, scene, Gate(0))
    client.camera.update_timestamp = 0.0  # the view has just been set
    shown = None
    for step in range(round(seconds / tick)):
        now = step * tick
        if move_at is not None and abs(now - move_at) < tick / 2:
            client.camera.position = np.array([0.5, -3.0, 0.0])
            client.camera.update_timestamp = now
        shown = web.render_due(viewer, client, shown, now) or shown


def test_a_finished_field_is_rendered_fast_when_moved_then_sharp_once_and_then_left_alone() -> None:
    model = CountingModel()
    client = FakeClient()
    watch(WebScene([], model=model), client, seconds=4.0, move_at=2.0)
    # at once (the view has just moved): fast; at rest: sharp; moved: fast; at rest again: sharp; nothing more
    assert model.widths == [FAST_WIDTH, SHARP_WIDTH, FAST_WIDTH, SHARP_WIDTH]
    assert client.shown[1] == (round(SHARP_WIDTH / (4 / 3)), SHARP_WIDTH)


def test_a_field_in_training_is_rendered_again_at_rest() -> None:
    model = CountingModel()
    watch(WebScene([], model=model, sharp_width=160, refresh_seconds=0.3), FakeClient(), seconds=2.0, tick=0.25)
    # looking every 0.25 s: fast at once; 160 px once rested more than REST_SECONDS (0.3 s), at 0.5 s; then
    # again each time more than 0.3 s have passed, at 1.0 and 1.5 s, although the view never moved
    assert model.widths == [FAST_WIDTH, 160, 160, 160]


def test_the_live_render_thread_stops_when_the_viewer_does() -> None:
    """The thread ``serve`` starts per client: it renders the view at once, and ends when the viewer stops."""
    model, client = CountingModel(), FakeClient()
    viewer = WebViewer(SimpleNamespace(get_clients=lambda: {client.client_id: client}), WebScene([], model=model),
                       Gate(0))
    viewer._stop.set()  # stopped before it looked: it renders nothing and returns
    web.live_render(viewer, client)
    assert model.widths == []


def listening_addresses(port: int) -> set[str]:
    """The local addresses with a socket listening on ``port``, as ``ss -ltn`` lists them (/proc/net/tcp*)."""
    import socket
    import struct

    found = set()
    for table, family in (("/proc/net/tcp", socket.AF_INET), ("/proc/net/tcp6", socket.AF_INET6)):
        try:
            rows = open(table).read().splitlines()[1:]
        except FileNotFoundError:
            continue
        for row in rows:
            local, state = row.split()[1], row.split()[3]
            address, hex_port = local.split(":")
            if state == "0A" and int(hex_port, 16) == port:  # LISTEN
                raw = bytes.fromhex(address)
                words = b"".join(struct.pack("<I", w) for w in struct.unpack(f">{len(raw) // 4}I", raw))
                found.add(socket.inet_ntop(family, words))
    return found


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_viewer_listens_on_this_machine_only_and_says_so_in_its_url(caplog) -> None:
    port = free_port()
    viewer = web.serve(WebScene(frames=[]), port=port)
    try:
        assert listening_addresses(port) == {"127.0.0.1"}
        assert viewer.url == f"http://localhost:{port}/?token={viewer.gate.token}"
        assert "anyone who can reach this machine" not in caplog.text
    finally:
        viewer.stop()


def test_a_port_in_use_or_out_of_range_is_one_line_with_one_to_try() -> None:
    import socket

    from nerfpipe.pipeline.errors import ParamError

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ParamError, match=rf"^--port {port}: in use on 127.0.0.1; try --port \d+$"):
            web.check_address("127.0.0.1", port)
    for bad in (99999, -5, 0):
        with pytest.raises(ParamError, match=rf"^--port {bad}: a port is a number from 1 to 65535"):
            web.check_address("127.0.0.1", bad)


def test_the_panel_records_keyframes_into_a_camera_path_and_renders_full_size_views(tmp_path) -> None:
    """The panel's actions as its buttons call them, with a browser tab's camera."""
    from nerfpipe.export.camera_path import CameraPath
    from nerfpipe.imaging.png import read_png

    model = CountingModel()
    viewer = web.serve(WebScene(frames=[], model=model, run_dir=tmp_path, full_width=200), port=free_port())
    try:
        panel = viewer.panel
        assert {h.label for h in panel.handles.values() if hasattr(h, "label")} >= {
            "Add keyframe", "Clear keyframes", "Save camera_path.json", "Render full size", "Resolution"}
        tab = FakeClient().camera
        assert panel.add_keyframe(tab) == 1
        tab.position = np.array([1.0, -3.0, 0.5])
        tab.fov = 0.6
        assert panel.add_keyframe(tab) == 2 and len(panel.frusta) == 2
        saved = panel.save(frames=30, fps=12.0, loop=False)
        assert saved == tmp_path / "camera_path.json"
        path = CameraPath.load(saved)
        assert (path.frames, path.fps, len(path.keyframes)) == (30, 12.0, 2)
        assert np.allclose(path.keyframes[1].c2w[:3, 3], [1.0, -3.0, 0.5])
        assert path.keyframes[0].fov == pytest.approx(np.degrees(0.8)) and path.keyframes[1].fov == pytest.approx(
            np.degrees(0.6))
        view = panel.render_full(tab)
        assert view.parent == tmp_path / "views" and read_png(view).shape == (150, 200, 3)  # 4:3 at full width
        assert model.widths[-1] == 200
        panel.clear()
        assert panel.keyframes == [] and panel.frusta == []
        with pytest.raises(ValueError, match="at least one keyframe"):
            panel.save(frames=30, fps=12.0, loop=False)
    finally:
        viewer.stop()


def test_a_viewer_without_a_run_directory_has_no_panel() -> None:
    viewer = web.serve(WebScene(frames=[], model=CountingModel()), port=free_port())
    try:
        assert viewer.panel is None
    finally:
        viewer.stop()
