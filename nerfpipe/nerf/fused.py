"""Rendering without gradients in one native loop a ray (``nerfpipe.nerf.native.render_marched``; and training's
visibility pass, ``reached_marched``), for the models it knows: a dense or hashed grid field (``GridField`` or
``HashGridField``, not a field with corners of its own) marched through an occupancy grid (``MarchingSampler``) in a
contracted or box ray space, with no fine field. That is the default model of
every capture on a CPU; any other model, or a machine without the native library, renders through
``RadianceModel.render`` (the sampler, the field and ``volume_render``), which computes the same quantities and
which the kernel is tested against.

Why: rendering a chunk of rays through torch is some forty operations over arrays of samples, and the visibility
pass's bookkeeping between them is half of a render on a CPU (docs/benchmarks.md); one loop a ray keeps a sample's
point, features and activations in registers and the cache.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from nerfpipe.nerf import native
from nerfpipe.nerf.fields.grid import GridField, natively_cornered
from nerfpipe.nerf.samplers.march import march_frame
from nerfpipe.nerf.samplers.marching import MarchingSampler
from nerfpipe.nerf.render.volume import RaySamples
from nerfpipe.nerf.spaces.rays import RayBatch


def _layers(*nets: nn.Sequential) -> tuple[tuple[Tensor, Tensor], ...] | None:
    """The (weight, bias) of each linear layer of MLPs made of Linear layers with ReLU between them, float32; None
    for any other make."""
    layers = []
    for net in nets:
        modules = list(net)
        if not modules or any(not isinstance(m, nn.Linear if i % 2 == 0 else nn.ReLU) for i, m in enumerate(modules)) \
                or len(modules) % 2 == 0:
            return None
        for linear in modules[::2]:
            if linear.bias is None or linear.weight.dtype != torch.float32:
                return None
            layers.append((linear.weight, linear.bias))
    return tuple(layers)


def marched_grid(model: Any) -> native.MarchedGrid | None:
    """``model`` (a ``RadianceModel``) as the native kernel renders it, or None where it is made of other parts."""
    field, sampler, space = model.coarse, model.sampler, model.ray_space
    if (not isinstance(field, GridField) or not natively_cornered(field) or type(field).combine is not GridField.combine
            or model.fine is not None or type(sampler) is not MarchingSampler):
        return None
    frame = march_frame(space)  # None for a space the native loops do not know (NDC)
    if frame is None:
        return None
    contracted, center, half = frame
    layers = _layers(field.density_net, field.color_net)
    if layers is None or len(layers) != 5:
        return None
    grid, config = sampler.grid, sampler.config
    return native.MarchedGrid(
        contracted=contracted, center=center, half=half, step=grid.diagonal / config.steps,
        most=sampler.candidates_per_ray(), early_stop=config.early_stop, occupied=grid.occupied,
        occupancy_box=(tuple(grid.lo.tolist()), tuple(grid.hi.tolist())), table=field.table,
        resolutions=field.resolutions, offsets=field.offsets, sizes=field.sizes, box=field.box(), layers=layers,
        dir_freqs=field.config.dir_freqs, view_dependent=field.config.view_dependence)


def render_fused(grid: native.MarchedGrid, rays: RayBatch) -> tuple[Tensor, Tensor, Tensor, Tensor] | None:
    """``rays`` rendered through ``grid`` (``marched_grid``): rgb (R, 3) onto nothing, depth, acc and samples
    evaluated (R,), as ``RadianceModel.render`` gives them without a background; None where the kernel cannot run."""
    return native.render_marched(grid, rays.origins, rays.directions, rays.viewdirs, rays.near, rays.far)


def reached_fused(grid: native.MarchedGrid, rays: RayBatch, samples: RaySamples) -> Tensor | None:
    """Which of ``samples`` of ``rays`` each ray reaches before its transmittance falls below the early stop, from the
    field's density through ``grid`` (``marched_grid``): the mask (N,) ``nerfpipe.nerf.samplers.march.visible`` would
    keep, in one native loop a ray; None where the kernel cannot run."""
    return native.reached_marched(grid, rays.origins, rays.directions, samples.ray, samples.t, samples.starts,
                                  samples.ends)
