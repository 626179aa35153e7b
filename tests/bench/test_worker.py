"""The bench worker trains what the train stage trains: the same model and the same training configuration
(precision settings included) from the same parameters."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from nerfpipe import Pipeline, default_stages
from nerfpipe.bench import worker
from nerfpipe.nerf.train.trainer import Trainer
from tests.bench.test_run import small_lego

# a few steps of a tiny MLP on 24 px images, with TF32 asked for
TRAIN = {"field": "mlp", "steps": "4", "batch_rays": "64", "n_coarse": "8", "n_fine": "8", "depth": "2", "width": "16",
         "view_width": "8", "lr": "3e-3", "lr_final": "1e-3", "seed": "3", "checkpoint_every": "2", "tf32": "true"}


@pytest.mark.slow
def test_bench_trains_with_the_train_stages_configuration(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    capture, run_dir = small_lego(tmp_path, train=4, val=2), tmp_path / "run"
    overrides = {"ingest": {"max_size": "24"}, "train": TRAIN}
    trained = []  # (config, training pixels, field class) of each Trainer made
    make = Trainer.__init__

    def recording(self, model, pixels, config, out, device, **kwargs):
        trained.append((config, len(pixels.rgb), type(model.coarse).__name__, kwargs))
        make(self, model, pixels, config, out, device, **kwargs)

    monkeypatch.setattr(Trainer, "__init__", recording)
    stage = Pipeline(default_stages(), capture, run_dir, None, overrides).run(until="train")[-1]
    spec = {"name": "tiny", "group": "presets", "capture": str(capture), "run_dir": str(run_dir),
            "overrides": overrides, "budget": 60.0, "checkpoints": [30.0], "eval_views": 0}
    bench = worker.run(spec)

    (stage_config, stage_pixels, stage_field, stage_kw), (bench_config, bench_pixels, bench_field, bench_kw) = trained
    assert stage_kw == bench_kw  # the scene's density noise, the same for both
    assert stage_config.tf32 and stage_config.seed == 3 and stage_config.steps == 4
    # the bench keeps its copies of the model in memory instead of writing checkpoints; nothing else differs
    assert bench_config == dataclasses.replace(stage_config, checkpoint_every=10**9, keep_checkpoints=1)
    assert (bench_pixels, bench_field) == (stage_pixels, stage_field) == (4 * 24 * 24, "NerfField")
    assert bench["decisions"] == stage.summary["decisions"] and bench["steps"] == stage.summary["steps"] == 4
