"""A model's resolved decisions: which field, sampler, ray space and background, and what is learned per
image. ``nerfpipe.nerf.policy.resolve_spec`` makes one from the scene's decisions and the train parameters,
``nerfpipe.nerf.model.build`` makes the model from it, and ``model.json`` stores it, so that training,
loading, ``nerfpipe bench`` and every export build a model the same way."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from nerfpipe.nerf.fields.configs import FieldConfig
from nerfpipe.nerf.registry import FIELDS, SAMPLERS, config_class
from nerfpipe.nerf.samplers.configs import SamplerConfig
from nerfpipe.nerf.spaces.ray_space import RaySpace, space_from_json

Box = tuple[tuple[float, ...], tuple[float, ...]]


def config_to_json(config: Any) -> dict[str, Any]:
    return dataclasses.asdict(config)


def config_from_json(registry: dict[str, Any], doc: dict[str, Any]) -> Any:
    """The registered config a ``config_to_json`` document describes (its ``kind`` picks the class)."""
    return config_class(registry, doc["kind"])(**doc)


@dataclass(frozen=True)
class ModelSpec:
    """What a model is made of.

    field, sampler: the parts' configs (``nerfpipe.nerf.registry``), as the user's parameters chose them and the
        scene resolved them (``nerfpipe.nerf.policy``).
    box: the axis-aligned box of field coordinates the field and an occupancy grid span (None: unbounded).
    fine_network: a second field of the same config for the fine pass.
    background: the colour renders are composited onto (None: black, the background is part of the scene).
    appearance: ``{"images", "linear", "stops"}`` for per-image exposure gains starting at ``stops``; None: none.
    refinement: ``{"images"}`` for per-camera pose corrections; None: none.
    info: what the exports need to know about the scene (layout, photometric, the similarity to SfM).
    """

    field: FieldConfig
    sampler: SamplerConfig
    ray_space: RaySpace
    box: Box | None = None
    fine_network: bool = False
    background: tuple[float, ...] | None = None
    appearance: dict[str, Any] | None = None
    refinement: dict[str, Any] | None = None
    info: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"field": config_to_json(self.field), "sampler": config_to_json(self.sampler),
                "ray_space": self.ray_space.to_json(),
                "box": None if self.box is None else [list(self.box[0]), list(self.box[1])],
                "fine_network": self.fine_network,
                "background": None if self.background is None else list(self.background),
                "appearance": self.appearance, "refinement": self.refinement, "info": self.info}

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> "ModelSpec":
        box = doc.get("box")
        return cls(field=config_from_json(FIELDS, doc["field"]), sampler=config_from_json(SAMPLERS, doc["sampler"]),
                   ray_space=space_from_json(doc["ray_space"]),
                   box=None if box is None else (tuple(box[0]), tuple(box[1])),
                   fine_network=bool(doc["fine_network"]),
                   background=None if doc["background"] is None else tuple(doc["background"]),
                   appearance=doc.get("appearance"), refinement=doc.get("refinement"), info=doc.get("info", {}))
