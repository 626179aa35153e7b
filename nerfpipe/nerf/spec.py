"""A model's resolved decisions: which field, sampler, ray space and background, and what is learned per
image. ``nerfpipe.nerf.policy.resolve`` makes one from the scene's decisions and the train parameters,
``nerfpipe.nerf.model.build`` makes the model from it, and ``model.json`` stores it, so that training,
loading, ``nerfpipe bench`` and every export build a model the same way."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from nerfpipe.nerf.spaces.ray_space import RaySpace, space_from_json

@dataclass(frozen=True)
class ModelSpec:
    """What a model is made of.

    field, sampler: ``{"kind": registry name, **that part's spec}`` (``nerfpipe.nerf.registry``).
    fine_network: a second field of the same spec for the fine pass.
    background: the colour renders are composited onto (None: black, the background is part of the scene).
    appearance: ``{"images", "linear", "stops"}`` for per-image exposure gains starting at ``stops``; None: none.
    refinement: ``{"images"}`` for per-camera pose corrections; None: none.
    info: what the exports need to know about the scene (layout, photometric, the similarity to SfM).
    """

    field: dict[str, Any]
    sampler: dict[str, Any]
    ray_space: RaySpace
    fine_network: bool = False
    background: tuple[float, ...] | None = None
    appearance: dict[str, Any] | None = None
    refinement: dict[str, Any] | None = None
    info: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        doc = {f.name: getattr(self, f.name) for f in fields(self)}
        doc["ray_space"] = self.ray_space.to_json()
        doc["background"] = None if self.background is None else list(self.background)
        return doc

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> "ModelSpec":
        return cls(field=doc["field"], sampler=doc["sampler"], ray_space=space_from_json(doc["ray_space"]),
                   fine_network=bool(doc["fine_network"]),
                   background=None if doc["background"] is None else tuple(doc["background"]),
                   appearance=doc.get("appearance"), refinement=doc.get("refinement"), info=doc.get("info", {}))
