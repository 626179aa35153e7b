"""A new field or sampler is one class and one registry line: a toy field (a learned colour and density that
depend on x linearly) and a toy sampler (evenly spaced samples, no importance sampling) are registered,
built from parameters by the same assembly as the real ones, trained, saved and loaded back."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import pytest
import torch
from torch import nn

from nerfpipe.nerf import registry
from nerfpipe.nerf.policy import build_model
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.render.volume import RaySamples
from nerfpipe.nerf.samplers.base import StatelessSampler
from nerfpipe.nerf.train.trainer import TrainConfig, Trainer
from nerfpipe.pipeline import ParamError
from nerfpipe.pipeline.params import build_params
from nerfpipe.stages.train import PRESETS, TrainParams
from tests.nerf.scenes import bounds_of, scene_of, world_of_one_camera
from tests.nerf.train.test_trainer import pixels_of_one_view

CPU = torch.device("cpu")


@dataclass(frozen=True)
class ToyConfig:
    scale: float = 1.0


class ToyField(nn.Module):
    """rgb = sigmoid(A x + a), sigma = softplus(b . x + c): four parameters of colour, four of density."""

    kind = "toy"
    needs_box = False

    def __init__(self, config: ToyConfig = ToyConfig()) -> None:
        super().__init__()
        self.config = config
        self.colour_net = nn.Linear(3, 3)
        self.density = nn.Linear(3, 1)

    @staticmethod
    def spec_of(params: Any, box: Any) -> dict[str, Any]:
        return {"field": asdict(ToyConfig(scale=float(params.hidden)))}

    @classmethod
    def from_spec(cls, spec: dict[str, Any]) -> "ToyField":
        return cls(ToyConfig(**spec["field"]))

    def spec(self) -> dict[str, Any]:
        return {"field": asdict(self.config)}

    @staticmethod
    def describe(spec: dict[str, Any]) -> str:
        return f"toy field of scale {spec['field']['scale']:g}"

    def forward(self, x: torch.Tensor, d: torch.Tensor | None = None, density_noise: float = 0.0):
        return self.colour(x, d), self.query_density(x)

    def query_density(self, x: torch.Tensor) -> torch.Tensor:
        return nn.functional.softplus(self.density(x)).squeeze(-1) * self.config.scale

    def density_features(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.query_density(x), x

    def colour(self, x: torch.Tensor, d: torch.Tensor | None) -> torch.Tensor:
        return torch.sigmoid(self.colour_net(x))


class EvenSampler(StatelessSampler):
    """``n`` evenly spaced samples between near and far, each in the middle of its stretch."""

    kind = "even"
    fields = 1
    adaptive = False

    def __init__(self, n: int) -> None:
        self.n = n

    @staticmethod
    def spec_of(params: Any, box: Any, lindisp: bool) -> dict[str, Any]:
        return {"n": params.n_coarse}

    @classmethod
    def from_spec(cls, spec: dict[str, Any]) -> "EvenSampler":
        return cls(spec["n"])

    def spec(self) -> dict[str, Any]:
        return {"n": self.n}

    def candidates_per_ray(self) -> int:
        return self.n

    @staticmethod
    def describe(spec: dict[str, Any]) -> str:
        return f"{spec['n']} evenly spaced samples a ray"

    def sample(self, rays, space, probe, *, train, generator, max_samples=0):
        edges = rays.near[:, None] + (rays.far - rays.near)[:, None] * torch.linspace(0.0, 1.0, self.n + 1)
        return RaySamples.dense((edges[:, :-1] + edges[:, 1:]) / 2, edges[:, :-1], edges[:, 1:]), 0, ()


@pytest.fixture
def toys(monkeypatch):
    monkeypatch.setitem(registry.FIELDS, "toy", f"{__name__}:ToyField")  # the one line a new field adds
    monkeypatch.setitem(registry.SAMPLERS, "even", f"{__name__}:EvenSampler")  # and a new sampler


def test_a_registered_field_and_sampler_are_built_trained_saved_and_loaded(toys, tmp_path) -> None:
    params = build_params("train", TrainParams, PRESETS, None,
                          {"field.kind": "toy", "field.hidden": "2", "sampler.kind": "even", "sampler.n_coarse": "16"})
    model, said = build_model(params, scene_of("inward360"), world_of_one_camera(),
                              bounds_of((2.0, 6.0)), CPU)
    assert isinstance(model.coarse, ToyField) and model.coarse.config.scale == 2.0
    assert isinstance(model.sampler, EvenSampler) and model.sampler.n == 16
    assert "toy field of scale 2" in said and "16 evenly spaced samples a ray" in said
    assert model.field_kind == "toy"

    # the trainer drives it as any other: a grey view is learned to well above its starting PSNR
    trainer = Trainer(model, pixels_of_one_view(16), TrainConfig(steps=200, batch_rays=128, lr=1e-1, lr_final=1e-2,
                                                                 checkpoint_every=1000), tmp_path, CPU)
    first_loss, _ = trainer.train_step(0)
    for step in range(1, 200):
        loss, _ = trainer.train_step(step)
    assert loss < 0.05 * first_loss

    model.save(tmp_path)
    loaded = RadianceModel.load(tmp_path)
    assert isinstance(loaded.coarse, ToyField) and isinstance(loaded.sampler, EvenSampler) and loaded.sampler.n == 16
    rays = model.ray_space.rays(*(torch.tensor(v) for v in ([[8.0, 8.0]], [[13.3, 13.3, 8.0, 8.0]])),
                                trainer.pixels.c2w, torch.tensor([2.0]), torch.tensor([6.0]))
    assert torch.equal(loaded.render_rays(rays)["rgb"], model.render_rays(rays)["rgb"])


def test_an_unregistered_kind_is_a_parameter_error_naming_the_choices() -> None:
    with pytest.raises(ParamError, match=r"train: field.kind must be one of grid, hash, planes, mlp, got 'toy'"):
        build_params("train", TrainParams, PRESETS, None, {"field.kind": "toy"})
    with pytest.raises(ParamError, match=r"sampler.kind must be one of auto, marching, hierarchical, got 'even'"):
        build_params("train", TrainParams, PRESETS, None, {"sampler.kind": "even"})
