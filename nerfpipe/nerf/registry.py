"""The parts a model is made of, by name: fields, samplers, and the ray spaces a model.json names.

Each entry names a part's config (``nerfpipe.nerf.fields.configs``, ``nerfpipe.nerf.samplers.configs``): the
user's parameter group for that kind, whose ``target`` is the part's class. A new field or sampler is one
module (its config and its class) and one line here. The entries are import paths (or the config classes
themselves), so that naming and checking a part (``--set train.field.kind=grid``) imports no torch; the class
is imported when a model is built or loaded (``part_class``).
"""

from __future__ import annotations

import importlib
from typing import Any

FIELDS: dict[str, Any] = {
    "grid": "nerfpipe.nerf.fields.configs:GridConfig",  # dense multiresolution grids and a small MLP
    "hash": "nerfpipe.nerf.fields.configs:HashConfig",  # the grid field with hashed fine levels (Instant-NGP)
    "planes": "nerfpipe.nerf.fields.configs:PlanesConfig",  # three factorized planes a level (K-Planes)
    "mlp": "nerfpipe.nerf.fields.configs:MlpConfig",  # the paper's MLP (Fig. 7)
}
SAMPLERS: dict[str, Any] = {
    "marching": "nerfpipe.nerf.samplers.configs:MarchingConfig",  # an occupancy grid marched (Instant-NGP)
    "hierarchical": "nerfpipe.nerf.samplers.configs:HierarchicalConfig",  # Section 5.2: N_c stratified + N_f importance
}

SPACES: dict[str, Any] = {  # by the kind a model.json names its ray space with
    "box": "nerfpipe.nerf.spaces.ray_space:BoxSpace",  # world rays, clipped to the scene box when there is one
    "ndc": "nerfpipe.nerf.spaces.ray_space:NdcSpace",  # forward-facing: NDC of the mean camera
    "contracted": "nerfpipe.nerf.spaces.ray_space:ContractedSpace",  # the world beyond the box contracted
}


def load(path: Any) -> Any:
    """The object an entry names: ``"module:Name"`` (or ``"module:Class.Config"``, a config nested in its part's
    class, as nerfstudio keeps them) imported, or the object itself."""
    if not isinstance(path, str):
        return path
    module, _, name = path.partition(":")
    found = importlib.import_module(module)
    for part in name.split("."):
        found = getattr(found, part)
    return found


def configs(registry: dict[str, Any]) -> dict[str, type]:
    """Every registered kind's config class, by kind."""
    return {kind: load(path) for kind, path in registry.items()}


def config_class(registry: dict[str, Any], kind: str) -> type:
    """The config class registered as ``kind``; ``ValueError`` naming the choices for another."""
    if kind not in registry:
        raise ValueError(f"kind must be one of {', '.join(registry)}, got {kind!r}")
    return load(registry[kind])


def part_class(config: Any) -> type:
    """The class a part's ``config`` builds (its ``target``)."""
    return load(type(config).target)
