"""The train stage's presets (``--preset NAME``): settings of its parameters (``nerfpipe.stages.train.TrainParams``)
that go together, each with what it is for; and ``gpu_preset``, what the stages that render take on a CUDA device
where the job names no preset (``Stage.machine_preset``). Listing them imports no torch."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

NVIDIA_DRIVER = Path("/proc/driver/nvidia")  # present where the NVIDIA kernel driver is loaded


def cuda_device(choice: str) -> str | None:
    """The name of the CUDA device a stage whose ``device`` setting is ``choice`` (auto, cpu, cuda) computes on,
    or None: ``cpu``, no NVIDIA driver loaded (torch is not even imported then), or a torch that sees none."""
    if choice == "cpu" or not NVIDIA_DRIVER.exists():
        return None
    import torch

    return torch.cuda.get_device_name() if torch.cuda.is_available() else None


def gpu_preset(overrides: Mapping[str, Any], sizes: str) -> tuple[str, str] | None:
    """``Stage.machine_preset`` of a stage with a ``gpu`` preset: ("gpu", why) where it computes on a CUDA
    device (its ``device`` override, else auto), ``sizes`` saying what the preset sizes."""
    name = cuda_device(str(overrides.get("device", "auto")))
    return None if name is None else ("gpu", f"sized for the CUDA device {name}: {sizes}")


# Section 5.3 and Fig. 7: the model, sampling and optimizer of the paper, without empty-space skipping
PAPER = {
    "field.kind": "mlp", "sampler.kind": "hierarchical", "steps": 200_000, "optim.batch_rays": 4096,
    "optim.batch_samples": 0, "sampler.n_coarse": 64, "sampler.n_fine": 128, "field.fine_network": True,
    "field.depth": 8, "field.width": 256, "field.view_width": 128, "field.skip_after": 5, "field.include_input": False,
    "field.density_activation": "relu", "optim.lr": 5e-4, "optim.lr_final": 5e-5, "optim.adam_eps": 1e-7,
    "optim.adam_beta2": 0.999, "checkpoint_every": 10_000, "field.dir_freqs": 4,
}
# the optimizer of the CPU-scale NeRF (4x128 MLP, softplus density, 512 rays a step, lr 3e-3 over 1500
# steps); ``nerfpipe bench``'s Table 2 ablations and the ``balanced`` preset start from it
MLP_CPU = {
    "field.kind": "mlp", "sampler.kind": "hierarchical", "steps": 1500, "optim.batch_rays": 512,
    "optim.batch_samples": 0, "optim.lr": 3e-3, "optim.lr_final": 5e-5, "optim.adam_eps": 1e-7,
    "optim.adam_beta2": 0.999, "field.dir_freqs": 4,
}
PRESETS = {
    # lego at 100 px on 2 CPU cores (``nerfpipe bench``): 500 steps in under a minute, 22.9 dB; its rate decays
    # 10-fold, as measured (at lr_final 6e-3 clean lego gains 2 dB, re-exposed or moved photos far less), and is
    # the MLP's too. Its one 64^3 grid leans on the paper's L = 4 for directions: on clean lego at 100 px, L = 0
    # scored 22.16 dB against 23.0-23.3 (tests/stages/test_train_per_image.py)
    "draft": {"steps": 500, "field.levels": 1, "field.max_resolution": 64, "sampler.occupancy_resolution": 32,
              "optim.batch_samples": 32768, "optim.lr": 1e-2, "optim.lr_final": 1e-3, "optim.mlp_lr_share": 1.0,
              "field.dir_freqs": 4},
    # the default: 32^3, 64^3 and 128^3 grids, MLPs as wide as the space calls for (field.hidden), trained for
    # train.seconds (120 s) as fast as the machine goes. The presets below were measured with 64-wide MLPs, Instant-NGP's
    # width, and keep them in every space
    "fast": {},
    # the 4x128 MLP (Fig. 7's shape, smaller) marching the occupancy grid: 6000 steps, about half an hour there
    "balanced": {**MLP_CPU, "sampler.kind": "marching", "steps": 6000, "optim.batch_rays": 1024,
                 "optim.batch_samples": 32768, "optim.lr_final": 1e-4},
    # one to two days on a V100 (Section 5.3), out of reach on a CPU
    "paper": PAPER,
    # the grid field with Instant-NGP's hashed fine levels: 12 levels of 16 to 1024 cells a side, the finest
    # 8 hashed into 2^17 rows of 2 features each: 2.5 M parameters, where the dense default has 9.8 M
    "hash": {"field.kind": "hash", "field.levels": 12, "field.min_resolution": 16, "field.max_resolution": 1024,
             "field.features": 2, "field.log2_table": 17, "field.hidden": 64},
    # a CUDA device's (``TrainStage.machine_preset``): Instant-NGP's batch of 2^18 samples and hash field, 16 levels of
    # 16 to 2048 cells a side in tables of 2^19 rows, its step compiled (train.compile=auto)
    "gpu": {"field.kind": "hash", "field.levels": 16, "field.min_resolution": 16, "field.max_resolution": 2048,
            "field.features": 2, "field.log2_table": 19, "field.hidden": 64, "optim.batch_samples": 262144,
            "chunk": 65536, "eval_scale": "1"},
    # three factorized planes a level (K-Planes): levels of 32, 102, 323 and 1024 cells a side, 4 features
    # each, 14 M values, where a 1024^3 dense grid would need 4.3 G
    "planes": {"field.kind": "planes", "field.levels": 4, "field.min_resolution": 32, "field.max_resolution": 1024,
               "field.features": 4, "field.hidden": 64},
}
