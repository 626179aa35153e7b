"""The web viewer's live render: what it renders when, for a finished field and for one in training."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import torch

from nerfpipe.export import web
from nerfpipe.export.web import FAST_WIDTH, SHARP_WIDTH, WebScene, WebViewer


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


def watch(scene: WebScene, client: FakeClient, seconds: float, move_at: float | None = None) -> None:
    """Run the live render for ``seconds`` against a fake server holding ``client``, moving its camera once."""
    server = SimpleNamespace(get_clients=lambda: {client.client_id: client})
    viewer = WebViewer(server, scene)
    client.camera.update_timestamp = time.time()  # the view has just been set
    thread = threading.Thread(target=web._live_render, args=(viewer, client), daemon=True)
    thread.start()
    started = time.time()
    if move_at is not None:
        time.sleep(move_at)
        client.camera.position = np.array([0.5, -3.0, 0.0])
        client.camera.update_timestamp = time.time()
    time.sleep(max(0.0, seconds - (time.time() - started)))
    viewer._stop.set()
    thread.join(timeout=5)
    assert not thread.is_alive()


def test_a_finished_field_is_rendered_fast_when_moved_then_sharp_once_and_then_left_alone(monkeypatch) -> None:
    monkeypatch.setattr(web, "REST_SECONDS", 1.0)  # a wide margin: a loaded CI machine starts the thread late
    model = CountingModel()
    client = FakeClient()
    watch(WebScene([], model=model), client, seconds=4.0, move_at=2.0)
    # at once (the view has just moved): fast; at rest: sharp; moved: fast; at rest again: sharp; nothing more
    assert model.widths == [FAST_WIDTH, SHARP_WIDTH, FAST_WIDTH, SHARP_WIDTH]
    assert client.shown[1] == (round(SHARP_WIDTH / (4 / 3)), SHARP_WIDTH)


def test_a_field_in_training_is_rendered_again_at_rest() -> None:
    model = CountingModel()
    watch(WebScene([], model=model, sharp_width=160, refresh_seconds=0.3), FakeClient(), seconds=2.0)
    # fast at once, then 160 px at rest and again every 0.3 s although the view never moved
    assert model.widths[0] == FAST_WIDTH and set(model.widths[1:]) == {160}
    assert 4 <= len(model.widths) - 1 <= 7, model.widths
