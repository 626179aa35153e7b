"""What ``nerfpipe bench`` compares: the train presets, and the ablations of Table 2 of the NeRF paper."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from nerfpipe.nerf.presets import MLP_CPU, PRESETS


@dataclass(frozen=True)
class BenchConfig:
    """One line of the benchmark: a train preset and overrides of train parameters."""

    name: str
    group: str  # "presets" or "ablations"
    preset: str | None
    train: dict[str, Any] = field(default_factory=dict)
    note: str = ""

    def overrides(self) -> dict[str, Any]:
        """The train parameters this configuration sets: the preset's, then its own."""
        return {**(PRESETS[self.preset] if self.preset else {}), **self.train}


PRESET_CONFIGS = [
    BenchConfig("draft", "presets", "draft", note="grid field, one 64^3 level"),
    BenchConfig("fast", "presets", "fast", note="grid field, 32^3, 64^3 and 128^3 levels, trained by time (the default)"),
    BenchConfig("hash", "presets", "hash", note="hash-grid field, 12 levels of 16^3 to 1024^3, the finest 8 hashed"),
    BenchConfig("planes", "presets", "planes", note="tri-plane field, 4 levels of 32^2 to 1024^2 planes (K-Planes)"),
    BenchConfig("balanced", "presets", "balanced", note="4x128 MLP with the occupancy grid"),
    BenchConfig("paper", "presets", "paper", note="8x256 coarse + fine MLPs, 64 + 128 samples (Section 5.3)"),
    BenchConfig("paper-1024", "presets", "paper", {"optim.batch_rays": 1024},
                note="the paper preset at 1024 rays a step (4096 hold 20 GB of activations on a CPU)"),
    BenchConfig("paper+occupancy", "presets", "paper", {"sampler.kind": "marching", "optim.batch_rays": 1024,
                                                          "optim.batch_samples": 32768},
                note="the paper's MLP marching the occupancy grid"),
]

# Table 2 of the paper: each row changes one thing of the complete model. The complete model here is the
# CPU-scale MLP (4x128) with the paper's coarse and fine networks and its sampling scaled to 100 px: N_c = 16,
# N_f = 32, 16 + (16 + 32) = 64 evaluations a ray. "No hierarchical" takes as many stratified samples with
# one network, as the paper's (256, -) matches its 64 + (64 + 128).
COMPLETE = {**MLP_CPU, "sampler.n_coarse": 16, "sampler.n_fine": 32, "field.fine_network": True}
ABLATION_CONFIGS = [
    BenchConfig("complete", "ablations", None, COMPLETE,
                note="Table 2 row 9: L = 10, view dependence, hierarchical (16 + 32, coarse and fine networks)"),
    BenchConfig("no PE", "ablations", None, {**COMPLETE, "field.positional_encoding": False}, note="row 2: raw x and d"),
    BenchConfig("no view dependence", "ablations", None, {**COMPLETE, "field.view_dependence": False}, note="row 3"),
    BenchConfig("no hierarchical", "ablations", None,
                {**COMPLETE, "sampler.hierarchical": False, "sampler.n_coarse": 64, "field.fine_network": False},
                note="row 4: 64 stratified samples, one network"),
    BenchConfig("far fewer images", "ablations", None, {**COMPLETE, "train_images": 25}, note="row 5: 25 images"),
    BenchConfig("fewer images", "ablations", None, {**COMPLETE, "train_images": 50}, note="row 6: 50 images"),
    BenchConfig("fewer frequencies", "ablations", None, {**COMPLETE, "field.pos_freqs": 5}, note="row 7: L = 5"),
    BenchConfig("more frequencies", "ablations", None, {**COMPLETE, "field.pos_freqs": 15}, note="row 8: L = 15"),
]

# a CUDA device's default, by name only (``--config gpu``): on two CPU cores its 2^18-sample steps take seconds each
GPU_CONFIG = BenchConfig("gpu", "presets", "gpu", note="hash field of 16 levels to 2048, 2^18 samples a step, compiled on CUDA")
CONFIGS = {c.name: c for c in PRESET_CONFIGS + ABLATION_CONFIGS + [GPU_CONFIG]}
GROUPS = {"presets": [c.name for c in PRESET_CONFIGS], "ablations": [c.name for c in ABLATION_CONFIGS]}


def select(names: list[str]) -> list[BenchConfig]:
    """Configurations by name or group ("presets", "ablations", "all"); raises KeyError naming the unknown."""
    chosen: list[BenchConfig] = []
    for name in names:
        expanded = GROUPS["presets"] + GROUPS["ablations"] if name == "all" else GROUPS.get(name, [name])
        for n in expanded:
            if n not in CONFIGS:
                raise KeyError(n)
            if CONFIGS[n] not in chosen:
                chosen.append(CONFIGS[n])
    return chosen
