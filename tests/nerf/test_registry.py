"""A new field or sampler is one class and one registry line: a toy field (a learned colour and density that
depend on x linearly) and a toy sampler (evenly spaced samples, no importance sampling) are registered,
built from parameters by the same policy as the real ones, trained, saved and loaded back."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import pytest
import torch
from torch import nn

from nerfpipe.nerf import registry
from nerfpipe.nerf.policy import build_model
from nerfpipe.nerf.model import RadianceModel
from nerfpipe.nerf.render.volume import RaySamples
from nerfpipe.nerf.samplers.base import StatelessSampler
from nerfpipe.nerf.fields.configs import FieldConfig
from nerfpipe.nerf.samplers.configs import SamplerConfig
from nerfpipe.nerf.train.trainer import Trainer
from nerfpipe.pipeline import ParamError
from nerfpipe.pipeline.params import build_params, param
from nerfpipe.stages.train import PRESETS, TrainParams
from tests.nerf.scenes import bounds_of, scene_of, world_of_one_camera
from tests.nerf.settings import train_settings
from tests.nerf.train.test_trainer import pixels_of_one_view

CPU = torch.device("cpu")


class ToyField(nn.Module):
    """rgb = sigmoid(A x + a), sigma = softplus(b . x + c) * gain: four parameters of colour, four of density, and
    a setting of its own (``gain``), configured beside the class as every part is."""

    @dataclass(frozen=True)
    class Config(FieldConfig):
        kind: str = "toy"
        gain: float = param(1.0, "toy: the density's scale", bounds=(0.0, 100.0))

        target: ClassVar[Any] = f"{__name__}:ToyField"
        needs_box: ClassVar[bool] = False

        def describe(self) -> str:
            return f"toy field of gain {self.gain:g}"

    def __init__(self, config: Config) -> None:
        super().__init__()
        self.config = config
        self.colour_net = nn.Linear(3, 3)
        self.density = nn.Linear(3, 1)

    @classmethod
    def from_config(cls, config: Config, box: Any) -> "ToyField":
        return cls(config)

    def box(self) -> None:
        return None

    def forward(self, x: torch.Tensor, d: torch.Tensor | None = None, density_noise: float = 0.0):
        return self.colour(x, d), self.query_density(x)

    def query_density(self, x: torch.Tensor) -> torch.Tensor:
        return nn.functional.softplus(self.density(x)).squeeze(-1) * self.config.gain

    def density_features(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.query_density(x), x

    def colour(self, x: torch.Tensor, d: torch.Tensor | None) -> torch.Tensor:
        return torch.sigmoid(self.colour_net(x))


class EvenSampler(StatelessSampler):
    """``n`` evenly spaced samples between near and far, each in the middle of its stretch."""

    @dataclass(frozen=True)
    class Config(SamplerConfig):
        kind: str = "even"
        n: int = param(8, "even: samples a ray", bounds=(1, 4096))

        target: ClassVar[Any] = f"{__name__}:EvenSampler"

        def step_samples(self, batch_rays: int, batch_samples: int) -> int:
            return batch_rays * self.n

        def describe(self) -> str:
            return f"{self.n} evenly spaced samples a ray"

    adaptive = False

    def __init__(self, config: Config) -> None:
        self.config = config

    @classmethod
    def from_config(cls, config: Config, box: Any) -> "EvenSampler":
        return cls(config)

    def candidates_per_ray(self) -> int:
        return self.config.n

    def sample(self, rays, space, probe, *, train, generator, max_samples=0):
        edges = rays.near[:, None] + (rays.far - rays.near)[:, None] * torch.linspace(0.0, 1.0, self.config.n + 1)
        return RaySamples.dense((edges[:, :-1] + edges[:, 1:]) / 2, edges[:, :-1], edges[:, 1:]), 0, ()


@pytest.fixture
def toys(monkeypatch):
    monkeypatch.setitem(registry.FIELDS, "toy", f"{__name__}:ToyField.Config")  # the one line a new field adds
    monkeypatch.setitem(registry.SAMPLERS, "even", f"{__name__}:EvenSampler.Config")  # and a new sampler


def test_a_registered_field_and_sampler_are_built_trained_saved_and_loaded(toys, tmp_path) -> None:
    params = build_params("train", TrainParams, PRESETS, None,
                          {"field.kind": "toy", "field.gain": "2", "sampler.kind": "even", "sampler.n": "16"})
    model, said = build_model(params, scene_of("inward360"), world_of_one_camera(),
                              bounds_of((2.0, 6.0)), CPU)
    assert isinstance(model.coarse, ToyField) and model.coarse.config.gain == 2.0
    assert isinstance(model.sampler, EvenSampler) and model.sampler.config.n == 16
    assert "toy field of gain 2" in said and "16 evenly spaced samples a ray" in said
    assert model.field_kind == "toy"

    # the trainer drives it as any other: a grey view is learned to well above its starting PSNR
    trainer = Trainer(model, pixels_of_one_view(16), train_settings(steps=200, batch_rays=128, lr=1e-1, lr_final=1e-2,
                                                                    checkpoint_every=1000), tmp_path, CPU)
    first_loss, _ = trainer.train_step(0)
    for step in range(1, 200):
        loss, _ = trainer.train_step(step)
    assert loss < 0.05 * first_loss

    model.save(tmp_path)
    loaded = RadianceModel.load(tmp_path)
    assert isinstance(loaded.coarse, ToyField) and isinstance(loaded.sampler, EvenSampler)
    assert loaded.coarse.config == model.coarse.config and loaded.sampler.config.n == 16
    rays = model.ray_space.rays(*(torch.tensor(v) for v in ([[8.0, 8.0]], [[13.3, 13.3, 8.0, 8.0]])),
                                trainer.pixels.c2w, torch.tensor([2.0]), torch.tensor([6.0]))
    assert torch.equal(loaded.render_rays(rays)["rgb"], model.render_rays(rays)["rgb"])


def test_a_toys_setting_is_a_parameter_of_its_kind_only(toys) -> None:
    from nerfpipe.pipeline.params import param_specs

    specs = {s.name: s for s in param_specs(TrainParams)}
    assert specs["field.gain"].kinds == ("toy",) and specs["field.gain"].bounds == (0.0, 100.0)
    assert specs["sampler.n"].kinds == ("even",)
    with pytest.raises(ParamError, match=r"field.gain is a setting of the toy field kind, and field.kind is grid"):
        build_params("train", TrainParams, PRESETS, None, {"field.gain": "2"})
    with pytest.raises(ParamError, match=r"train.field.gain: 200 is outside its bounds"):
        build_params("train", TrainParams, PRESETS, None, {"field.kind": "toy", "field.gain": "200"})


def test_an_unregistered_kind_is_a_parameter_error_naming_the_choices() -> None:
    with pytest.raises(ParamError, match=r"train.field.kind: 'toy' is not one of grid, hash, planes, mlp"):
        build_params("train", TrainParams, PRESETS, None, {"field.kind": "toy"})
    with pytest.raises(ParamError, match=r"train.sampler.kind: 'even' is not one of auto, marching, hierarchical"):
        build_params("train", TrainParams, PRESETS, None, {"sampler.kind": "even"})
