"""The parts a model is made of, by name: fields and samplers.

A new field or sampler is a class (``nerfpipe.nerf.fields.base.Field``, ``nerfpipe.nerf.samplers.base.Sampler``) and
one line here. The entries are import paths, so that naming and checking a part (``--set
train.field.kind=grid``) imports no torch; ``resolve`` imports the class when a model is built or loaded.
"""

from __future__ import annotations

import importlib

FIELDS: dict[str, str] = {
    "grid": "nerfpipe.nerf.fields.grid:GridField",  # dense multiresolution grids and a small MLP
    "hash": "nerfpipe.nerf.fields.hash:HashGridField",  # the grid field with hashed fine levels (Instant-NGP)
    "planes": "nerfpipe.nerf.fields.planes:PlaneField",  # three factorized planes a level (K-Planes)
    "mlp": "nerfpipe.nerf.fields.mlp:NerfField",  # the paper's MLP (Fig. 7)
}
SAMPLERS: dict[str, str] = {
    "marching": "nerfpipe.nerf.samplers.base:MarchingSampler",  # an occupancy grid marched (Instant-NGP)
    "hierarchical": "nerfpipe.nerf.samplers.base:HierarchicalSampler",  # Section 5.2: N_c stratified + N_f importance
}


def check(registry: dict[str, str], kind: str, what: str, extra: tuple[str, ...] = ()) -> None:
    """Raise ``ValueError`` naming the choices when ``kind`` is neither registered nor one of ``extra``."""
    if kind not in registry and kind not in extra:
        raise ValueError(f"{what} must be one of {', '.join((*extra, *registry))}, got {kind!r}")


def resolve(registry: dict[str, str], kind: str) -> type:
    """The class registered as ``kind``."""
    module, _, name = registry[kind].partition(":")
    return getattr(importlib.import_module(module), name)
