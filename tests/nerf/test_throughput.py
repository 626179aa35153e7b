"""The probe that predicts what rendering whole views costs: timed on at least one chunk of rays."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nerfpipe.nerf import throughput
from nerfpipe.nerf.policy import build_model
from nerfpipe.stages.train import TrainParams
from tests.helpers import look_at
from tests.nerf.scenes import bounds_of, scene_of, world_of_one_camera


@pytest.mark.parametrize("size, chunk, rays, timed", [
    ((200, 100), 8192, 4096, 8192),  # a chunk larger than the probe: a whole chunk is timed
    ((200, 100), 1024, 4096, 4096),  # smaller: the probe as asked
    ((50, 40), 8192, 4096, 2000),  # a view smaller than either: all its pixels
])
def test_the_probe_times_at_least_one_chunk_of_the_views_rays(size, chunk, rays, timed, monkeypatch) -> None:
    model, _ = build_model(TrainParams(), scene_of("inward360"), world_of_one_camera(), bounds_of(), torch.device("cpu"))
    seen = []
    render = model.render_rays
    monkeypatch.setattr(model, "render_rays", lambda batch, c: (seen.append((len(batch), c)), render(batch, c))[1])
    w, h = size
    c2w = look_at(np.array([0.0, -3.0, 0.5]), np.zeros(3))
    per_ray = throughput.seconds_per_ray(model, (w / 1.2, w / 1.2, w / 2, h / 2), c2w, w, h, 1.0, 5.0, chunk, rays)
    assert per_ray > 0
    assert seen == [(min(throughput.WARM_UP_RAYS, timed), chunk), (timed, chunk)]  # warm-up, then the timed rays


@pytest.mark.parametrize("size, timed", [
    ((64, 48), (64, 48)),  # a small view: itself
    ((4096, 2048), (724, 362)),  # 8.4 M pixels: the same view at 2^18 of them, its time scaled up 32-fold
])
def test_a_view_is_timed_whole_up_to_a_size_and_at_that_size_beyond(size, timed, monkeypatch) -> None:
    model, _ = build_model(TrainParams(), scene_of("inward360"), world_of_one_camera(), bounds_of(), torch.device("cpu"))
    seen = []
    monkeypatch.setattr(model, "render_image", lambda k, c2w, w, h, *rest: seen.append((k, w, h)) or {"size": (w, h)})
    clock = iter([10.0, 12.5, 20.0, 22.5])  # each view takes 2.5 s on this clock
    monkeypatch.setattr(throughput.time, "perf_counter", lambda: next(clock))
    w, h = size
    c2w = look_at(np.array([0.0, -3.0, 0.5]), np.zeros(3))
    seconds = throughput.seconds_per_view(model, (w / 1.2, w / 1.2, w / 2, h / 2), c2w, w, h, 1.0, 5.0, 4096)
    (k, tw, th), = seen
    assert (tw, th) == timed and tw * th <= throughput.VIEW_RAYS
    assert k == pytest.approx((tw / 1.2, tw / 1.2, tw / 2, th / 2), rel=1e-3)  # the same field of view
    assert seconds == pytest.approx(2.5 * w * h / (tw * th))
    # the view it rendered comes back where it is the view asked for, whole, for the caller to keep
    again, image = throughput.timed_view(model, (w / 1.2, w / 1.2, w / 2, h / 2), c2w, w, h, 1.0, 5.0, 4096)
    assert again == seconds and seen[1] == seen[0]
    assert image == ({"size": (w, h)} if timed == size else None)
