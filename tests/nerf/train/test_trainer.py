"""The trainer's batches while marching: rays per batch follow the samples per ray (Instant-NGP), and one
step never evaluates much more than it asked for, however the occupancy grid changed. Its precision settings."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np
import pytest
import torch

from tests.nerf.fieldfns import paper_mlp
from nerfpipe.nerf.fields.mlp import NerfField
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.samplers.configs import MarchingConfig
from nerfpipe.nerf.samplers.occupancy import OccupancyGrid
from nerfpipe.nerf.spaces.ray_space import BoxSpace
from nerfpipe.nerf.spaces.rays import pixel_centers
from nerfpipe.nerf.samplers.configs import HierarchicalConfig
from nerfpipe.nerf.samplers.hierarchical import HierarchicalSampler
from nerfpipe.nerf.samplers.marching import MarchingSampler
from nerfpipe.nerf.train.stall import StallGuard, mean_colour_psnr
from nerfpipe.nerf.train.trainer import PixelSet, Trainer, set_precision
from tests.nerf.settings import train_settings
from tests.helpers import look_at

BOX = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))


def pixels_of_one_view(size: int = 32) -> PixelSet:
    """A grey image seen from 3 units away, every ray through the box."""
    uv = pixel_centers(size, size)
    c2w = torch.tensor(look_at(np.array([0.0, -3.0, 0.0]), np.zeros(3)), dtype=torch.float32)
    return PixelSet(rgb=torch.full((len(uv), 3), 0.5), image=torch.zeros(len(uv), dtype=torch.long), uv=uv,
                    intrinsics=torch.tensor([[size / 1.2, size / 1.2, size / 2, size / 2]]), c2w=c2w[None],
                    near=torch.tensor([1.0]), far=torch.tensor([5.0]))


@dataclasses.dataclass(frozen=True)
class RareUpdates(MarchingConfig):
    update_every: ClassVar[int] = 1000  # the grid stays as it starts: every cell occupied


def marching_model() -> RadianceModel:
    torch.manual_seed(0)
    field = NerfField(paper_mlp(depth=2, width=32, view_width=16, pos_freqs=4, dir_freqs=2,
                                  density_activation="softplus"))
    grid = OccupancyGrid(*BOX, resolution=8)  # fresh: every cell occupied, every ray marched end to end
    return RadianceModel(field, None, MarchingSampler(grid, RareUpdates(steps=64, early_stop=1e-4)),
                         BoxSpace(BOX), (1.0, 1.0, 1.0), {})


def test_a_step_evaluates_at_most_twice_the_samples_it_asks_for_and_the_batch_shrinks_at_once(tmp_path) -> None:
    model = marching_model()
    config = train_settings(steps=10, batch_rays=1024, batch_samples=1000, lr=1e-3, lr_final=1e-4)
    trainer = Trainer(model, pixels_of_one_view(), config, tmp_path, torch.device("cpu"))
    trainer.train_step(1)  # not a grid update step: the grid stays fully occupied
    # 1024 rays of about 15 samples each were drawn; only the leading rays within 2 x 1000 samples ran
    assert 0 < trainer.samples <= 2000
    assert trainer.rays < 1024 and trainer.samples / trainer.rays > 1000 / 256
    # 1000 samples want fewer than 256 rays: the next batch drops straight to the smallest, 256 rays
    assert trainer.rays_per_batch == 256.0
    trainer.train_step(2)
    assert trainer.rays <= 256 and trainer.samples <= 2000


def test_the_batch_grows_smoothly_when_rays_get_shorter(tmp_path) -> None:
    model = marching_model()
    model.sampler.grid.occupied.zero_()  # nothing occupied: no samples at all
    config = train_settings(steps=10, batch_rays=1024, batch_samples=100_000, lr=1e-3, lr_final=1e-4)
    trainer = Trainer(model, pixels_of_one_view(), config, tmp_path, torch.device("cpu"))
    trainer.train_step(1)
    assert trainer.samples == 0 and trainer.rays == 1024
    # wanted: 100000 rays (one sample a ray at least), capped at 16 x 1024; a fifth of the way there
    assert trainer.rays_per_batch == 0.8 * 1024 + 0.2 * 16 * 1024


@pytest.fixture
def tf32_flags_restored():
    """torch's TF32 flags are process-wide properties, not attributes monkeypatch can restore (pytest 9.2
    fails its teardown with `'cuBLASModule' object has no attribute 'allow_tf32'`): save and put them back."""
    saved = (torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32)
    torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = False
    yield
    torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = saved


def test_tf32_is_set_for_cuda_training_only(tf32_flags_restored) -> None:
    set_precision(train_settings(tf32=True), torch.device("cpu"))
    set_precision(train_settings(tf32=False), torch.device("cuda"))
    assert not torch.backends.cuda.matmul.allow_tf32 and not torch.backends.cudnn.allow_tf32
    set_precision(train_settings(tf32=True), torch.device("cuda"))  # a flag only: needs no device
    assert torch.backends.cuda.matmul.allow_tf32 and torch.backends.cudnn.allow_tf32


def test_the_trainer_applies_its_configs_precision(tmp_path, monkeypatch) -> None:
    applied = []
    monkeypatch.setattr("nerfpipe.nerf.train.trainer.set_precision", lambda config, device: applied.append((config, device)))
    config = train_settings(steps=1, tf32=True)
    Trainer(marching_model(), pixels_of_one_view(8), config, tmp_path, torch.device("cpu"))
    assert applied == [(config, torch.device("cpu"))]


def test_mean_colour_level_by_hand() -> None:
    # half the pixels black, half white: the mean colour 0.5 is off by 0.5 everywhere, MSE 0.25, 6.02 dB
    rgb = torch.cat([torch.zeros((10, 3)), torch.ones((10, 3))])
    assert mean_colour_psnr(rgb) == pytest.approx(6.0206, abs=1e-4)


def test_the_stall_guard_restarts_once_then_reports() -> None:
    guard = StallGuard(floor_db=10.0, check_step=4, smoothing=0.5)
    verdicts = [guard.observe(step, psnr, last=False) for step, psnr in enumerate([10.0, 10.0, 10.0, 10.0, 10.5], 1)]
    assert verdicts == ["ok", "ok", "ok", "restart", "ok"]  # 10.0 at step 4 is within 1 dB of the floor
    assert guard.restarted_at == 4 and guard.ema == 10.5  # the average starts again after a restart
    assert [guard.observe(step, 10.2, last=False) for step in (6, 7, 8)] == ["ok", "ok", "stalled"]  # 4 + 4
    # the average: 10.5 -> 10.35 -> 10.275 -> 10.2375, within 1 dB of the floor at step 8
    assert guard.ema == pytest.approx(10.2375)
    assert guard.report() == {"mean_colour_psnr": 10.0, "batch_psnr_ema": 10.237, "restarted_at": 4,
                              "stalled": True}
    assert guard.observe(9, 10.0, last=True) == "ok"  # said once


def test_a_training_well_above_the_floor_passes_and_a_last_step_stall_is_reported_without_restart() -> None:
    learning = StallGuard(floor_db=10.0, check_step=2, smoothing=1.0)
    assert [learning.observe(s, 20.0, last=s == 3) for s in (1, 2, 3)] == ["ok", "ok", "ok"]
    short = StallGuard(floor_db=10.0, check_step=5, smoothing=1.0)
    assert [short.observe(s, 10.5, last=s == 3) for s in (1, 2, 3)] == ["ok", "ok", "stalled"]
    assert short.restarted_at is None


def test_a_restart_restores_the_initial_weights_and_grid_at_half_the_learning_rate(tmp_path) -> None:
    model = marching_model()
    trainer = Trainer(model, pixels_of_one_view(), train_settings(steps=3, batch_rays=256, lr=1e-2, lr_final=1e-3), tmp_path,
                      torch.device("cpu"))
    initial = {k: v.clone() for k, v in model.coarse.state_dict().items()}
    trainer.run()
    model.sampler.grid.occupied[:10] = False
    assert any(not torch.equal(initial[k], v) for k, v in model.coarse.state_dict().items())
    trainer.restart()
    assert all(torch.equal(initial[k], v) for k, v in model.coarse.state_dict().items())
    assert bool(model.sampler.grid.occupied.all()) and trainer.lr_scale == 0.5 and not trainer.optimizer.state


def masked(pixels: PixelSet, alpha: float) -> PixelSet:
    """``pixels`` with every pixel's backdrop mask ``alpha`` (1 object, 0 backdrop)."""
    return PixelSet(**{**pixels.__dict__, "alpha": torch.full((len(pixels.rgb),), alpha)})


def test_backdrop_pixels_teach_empty_space_against_a_random_colour_per_ray(tmp_path) -> None:
    config = train_settings(steps=10, batch_rays=1024, batch_samples=0, lr=1e-3, lr_final=1e-4)
    empty = marching_model()
    empty.sampler.grid.occupied.zero_()  # nothing to hit: every ray shows the colour it is composited onto

    def loss_of(pixels: PixelSet, step: int = 1) -> float:
        return Trainer(empty, pixels, config, tmp_path, torch.device("cpu")).train_step(step)[0]

    # backdrop pixels (alpha 0): the render is the ray's random colour, the target too: loss 0
    assert loss_of(masked(pixels_of_one_view(), 0.0)) == 0.0
    # object pixels (alpha 1, grey 0.5): E[(U - 0.5)^2] = 1/12 for U ~ U[0, 1]; 1024 rays x 3 channels put the
    # mean within 0.005 of it
    loss = loss_of(masked(pixels_of_one_view(), 1.0))
    assert loss == pytest.approx(1 / 12, abs=0.005)
    # the colours are a function of (seed, step), as the batches are: resuming redraws them
    assert loss_of(masked(pixels_of_one_view(), 1.0)) == loss and loss_of(masked(pixels_of_one_view(), 1.0), 2) != loss
    # without masks the render is composited onto the model's background (white): (1 - 0.5)^2 = 0.25 exactly
    assert loss_of(pixels_of_one_view()) == pytest.approx(0.25)


def test_the_random_backdrop_reaches_both_passes_of_section_5_2_sampling(tmp_path) -> None:
    torch.manual_seed(0)
    field = NerfField(paper_mlp(depth=2, width=16, view_width=8, pos_freqs=2, dir_freqs=0,
                                  density_activation="softplus"))
    with torch.no_grad():  # softplus(-100) ~ 4e-44: an empty field
        field.density.weight.zero_()
        field.density.bias.fill_(-100.0)
    model = RadianceModel(field, None, HierarchicalSampler(HierarchicalConfig(n_coarse=8, n_fine=8)), BoxSpace(BOX), (1.0, 1.0, 1.0), {})
    config = train_settings(steps=10, batch_rays=256, lr=1e-3, lr_final=1e-4)
    trainer = Trainer(model, masked(pixels_of_one_view(8), 0.0), config, tmp_path, torch.device("cpu"))
    loss, _ = trainer.train_step(1)
    assert loss == pytest.approx(0.0, abs=1e-12)  # coarse + fine, each rendering the ray's own colour


def test_a_time_budget_trains_until_it_is_spent_with_the_learning_rate_decaying_over_it(tmp_path, monkeypatch) -> None:
    import itertools
    import json

    from nerfpipe.nerf.train import trainer as trainer_module

    monkeypatch.setattr(trainer_module, "LOG_EVERY", 5)
    model = marching_model()
    config = train_settings(steps=0, seconds=1.5, batch_rays=256, batch_samples=2000, lr=1e-2, lr_final=1e-3)
    ticks = itertools.count()
    clock = lambda: next(ticks) / 16  # noqa: E731 - each read 1/16 s later: a step (between two reads) takes that
    trainer = Trainer(model, pixels_of_one_view(), config, tmp_path, torch.device("cpu"), clock=clock)
    advanced = []
    trainer.run(lambda n=1, info=None: advanced.append(n))
    # the budget is judged after each step: the 24th step spends 1.5 s, and is the last
    assert trainer.step == 24 and trainer.elapsed == pytest.approx(1.5) and trainer.finished()
    assert trainer.total == 2 and sum(advanced) == 2  # the progress bar counts whole seconds, and ends full
    log = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [5, 10, 15, 20, 24]  # every log_every steps, and the last one
    walls = [0.3125, 0.625, 0.9375, 1.25, 1.5]
    assert [r["wall"] for r in log] == pytest.approx(walls, abs=1e-3)
    assert all(r["steps_per_s"] == pytest.approx(16.0) for r in log)
    lrs = [r["lr"] for r in log]
    # decayed by the clock, from lr to lr_final: exponentially, 1e-2 * 0.1 ** (elapsed / 1.5)
    assert trainer.lr_scale == 1.0 and trainer.guard.restarted_at is None  # 24 steps: before the stall guard acts
    assert lrs == pytest.approx([1e-2 * 0.1 ** (w / 1.5) for w in walls])
    assert max(p.name for p in (tmp_path / "checkpoints").iterdir()) == f"step_{trainer.step:07d}.pt"
    # resumed from its last checkpoint, the spent budget stays spent
    again = Trainer(marching_model(), pixels_of_one_view(), config, tmp_path, torch.device("cpu"))
    assert again.resume() == trainer.step and again.finished()


def test_a_training_that_gives_time_to_the_outputs_ends_sooner_its_learning_rate_decaying_on_to_the_end(
        tmp_path, monkeypatch) -> None:
    import itertools
    import json

    from nerfpipe.nerf.train import trainer as trainer_module

    monkeypatch.setattr(trainer_module, "LOG_EVERY", 4)
    config = train_settings(steps=0, seconds=3.0, batch_rays=256, batch_samples=2000, lr=1e-2, lr_final=1e-3)
    ticks = itertools.count()
    trainer = Trainer(marching_model(), pixels_of_one_view(), config, tmp_path, torch.device("cpu"),
                      clock=lambda: next(ticks) / 16)  # a step takes 1/16 s

    def give(t: Trainer) -> bool:
        if t.step == 8:  # 0.5 s of 3 s: a sixth of the decay done; the outputs take 1.5 s of the rest
            t.give(1.5)
            assert t.config.seconds == pytest.approx(1.5) and t.given == pytest.approx(1.5)
        if t.step == 16:  # 1 s in, they are found to need 1 s in all: training takes the other half second back
            t.give(1.0)
        return False

    trainer.run(after_step=give)
    assert trainer.step == 32 and trainer.elapsed == pytest.approx(2.0) and trainer.given == pytest.approx(1.0)
    assert trainer.config.seconds == pytest.approx(2.0) and trainer.finished()
    log = {r["step"]: r["lr"] for r in map(json.loads, (tmp_path / "metrics.jsonl").read_text().splitlines())}
    # before: 1e-2 * 0.1 ** (elapsed / 3); then from a sixth of the way at 0.5 s to all of it at 1.5 s, which at 1 s
    # is 7/12 of the way; then from there to all of it at 2 s
    assert log[4] == pytest.approx(1e-2 * 0.1 ** (0.25 / 3.0))
    assert log[16] == pytest.approx(1e-2 * 0.1 ** (1 / 6 + 5 / 6 * (1.0 - 0.5) / 1.0))
    assert log[24] == pytest.approx(1e-2 * 0.1 ** (7 / 12 + 5 / 12 * (1.5 - 1.0) / 1.0))
    assert log[32] == pytest.approx(1e-3)
    trainer.give(0.0)  # never after it has stopped: it gave what it gave
    trainer.give(100.0)  # nor before now
    assert trainer.config.seconds == pytest.approx(2.0) and trainer.given == pytest.approx(1.0)


def test_each_group_decays_to_its_own_final_rate_and_the_cameras_far_below_the_field() -> None:
    from types import SimpleNamespace

    from nerfpipe.nerf.train.trainer import POSE_WARMUP, parameter_groups

    field, gains, poses = torch.nn.Linear(2, 2), torch.nn.Linear(1, 1), torch.nn.Linear(1, 1)
    model = SimpleNamespace(fields=lambda: [field], appearance=gains, refinement=poses)
    config = train_settings(lr=2e-2, lr_final=6e-3, appearance_lr=1e-2, pose_lr=3e-3)
    groups = parameter_groups(model, config)
    assert [g["base_lr"] for g in groups] == [2e-2, 1e-2, 3e-3]
    # the fields and the gains end at lr_final / lr of their rates, the cameras at 1/100 of theirs, whatever lr_final
    assert [g["final"] for g in groups] == pytest.approx([0.3, 0.3, 1 / 100])
    assert groups[2]["warmup"] == POSE_WARMUP and groups[0]["warmup"] == 0


def test_a_grid_fields_tables_learn_at_lr_and_its_mlps_at_their_share() -> None:
    from types import SimpleNamespace

    from tests.nerf.fieldfns import paper_mlp
    from nerfpipe.nerf.fields.mlp import NerfField
    from nerfpipe.nerf.fields.configs import GridConfig
    from nerfpipe.nerf.fields.grid import GridField
    from nerfpipe.nerf.train.trainer import parameter_groups

    grid = GridField((0, 0, 0), (1, 1, 1), GridConfig(levels=2, min_resolution=4, max_resolution=8, hidden=8))
    mlp = NerfField(paper_mlp(depth=2, width=8, view_width=8, pos_freqs=2, dir_freqs=1))
    config = train_settings(lr=3e-2, lr_final=9e-3, mlp_lr_share=0.25)
    groups = parameter_groups(SimpleNamespace(fields=lambda: [grid, mlp], appearance=None, refinement=None), config)
    assert [g["base_lr"] for g in groups] == pytest.approx([3e-2, 3e-2 * 0.25, 3e-2])  # the MLP field: all at lr
    assert groups[0]["params"] == [grid.table]
    # every parameter in exactly one group, and each group decaying by lr_final / lr
    grouped = [p for g in groups for p in g["params"]]
    assert len(grouped) == len({id(p) for p in grouped}) == len(list(grid.parameters())) + len(list(mlp.parameters()))
    assert [g["final"] for g in groups] == pytest.approx([0.3] * 3)


def test_a_diverged_training_is_a_stage_error_naming_the_learning_rate(tmp_path, monkeypatch) -> None:
    """The outside pass's lr=1e12 ended in a FloatingPointError traceback; within bounds a loss can still
    become nan, and that is one line saying what to lower."""
    from nerfpipe.pipeline.errors import StageError

    trainer = Trainer(marching_model(), pixels_of_one_view(8), train_settings(steps=3, lr=5.0), tmp_path,
                      torch.device("cpu"))
    monkeypatch.setattr(trainer, "train_step", lambda step: (float("nan"), 0.0))
    with pytest.raises(StageError, match=r"^train: the training loss became nan at step 0, so the field diverged; "
                                         r"lower train.optim.lr \(now 5\)"):
        trainer.run()
