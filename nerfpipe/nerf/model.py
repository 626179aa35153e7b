"""A trained radiance field with everything needed to render it: fields, a sampler, background and the
ray space the scene analysis chose (world rays clipped to the scene box, NDC rays, or contracted space).
Saved as ``model.pt`` (tensors only, loadable with ``torch.load(..., weights_only=True)``) and
``model.json`` (its ``ModelSpec``: each part's kind and spec); ``build`` makes a model from a spec."""

from __future__ import annotations

import itertools
import json
import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from torch import Tensor

from nerfpipe.nerf.appearance import ExposureGains
from nerfpipe.nerf.fields import Field, field_spec
from nerfpipe.nerf.ray_space import RaySpace
from nerfpipe.nerf.rays import camera_rays, pixel_centers
from nerfpipe.nerf.refinement import PoseRefinement
from nerfpipe.nerf.registry import FIELDS, SAMPLERS, resolve
from nerfpipe.nerf.renderer import RayBatch
from nerfpipe.nerf.samplers import Sampler
from nerfpipe.nerf.spec import ModelSpec
from nerfpipe.pipeline.errors import InputError

# samples one rendering call may lay out (rays x the sampler's candidates a ray; about 48 bytes each): a chunk of
# rays is cut to fit, so that a fine march (sampler.steps) or a large chunk (render.chunk) cannot exhaust memory
RENDER_CANDIDATES = 1 << 22


@dataclass
class RadianceModel:
    """Coarse (and fine) fields, the sampler that says where along each ray to evaluate them, the background
    they are composited onto, and the ray space the scene analysis chose.

    ``sampler``: ``nerfpipe.nerf.samplers`` (Section 5.2's hierarchical sampling, or marching an occupancy
    grid with the coarse field only). Learned per training image when the scene calls for them
    (``nerfpipe.nerf.assembly``): ``appearance``, each photo's exposure and white balance (renders show the
    training photos' mean appearance), and ``refinement``, each camera's pose correction.
    """

    coarse: Field
    fine: Field | None
    sampler: Sampler
    ray_space: RaySpace
    background: tuple[float, float, float] | None
    info: dict[str, Any] = field(default_factory=dict)
    appearance: ExposureGains | None = None
    refinement: PoseRefinement | None = None

    @property
    def field_kind(self) -> str:
        """The field's name in the registry (``grid``: dense grids and a small MLP; ``mlp``: Fig. 7)."""
        return self.coarse.kind

    def fields(self) -> list[Field]:
        return [self.coarse] + ([self.fine] if self.fine is not None else [])

    def world_field(self, field: Field) -> Field | Callable[..., tuple[Tensor, Tensor]]:
        """``field`` as a function of the points rays reach: in contracted space the rays are world rays,
        and their points are contracted before the field sees them."""
        contraction = self.ray_space.contracted
        if contraction is None:
            return field
        return lambda points, viewdirs, *rest: field(contraction.to_field(points), viewdirs, *rest)

    def world_density(self, field: Field) -> Callable[[Tensor], Tensor]:
        """``field.query_density`` of the points rays reach (see ``world_field``)."""
        contraction = self.ray_space.contracted
        if contraction is None:
            return field.query_density
        return lambda points: field.query_density(contraction.to_field(points))

    def render_batch(self, rays: RayBatch, chunk: int = 8192) -> dict[str, Tensor]:
        """Deterministic rendering of rays without gradients: rgb (R, 3), depth, disparity, acc (R,), in the
        ray space's own depth (t, or NDC t'); and ``samples``, the field evaluations per ray on average."""
        for f in self.fields():
            f.eval()
        coarse, fine = self.world_field(self.coarse), None if self.fine is None else self.world_field(self.fine)
        parts: dict[str, list[Tensor]] = {"rgb": [], "depth": [], "disparity": [], "acc": []}
        evaluated = 0
        background = self.background_tensor()
        chunk = max(1, min(chunk, RENDER_CANDIDATES // self.sampler.candidates_per_ray()))  # memory, not speed
        with torch.no_grad():
            for start in range(0, len(rays), chunk):
                out, n = self.sampler.render(coarse, fine, rays.slice(start, start + chunk), background)
                evaluated += n
                for key in parts:
                    parts[key].append(out[key])
        result = {key: torch.cat(values) if values else torch.zeros(0) for key, values in parts.items()}
        result["samples"] = torch.tensor(evaluated / max(len(rays), 1))
        return result

    @property
    def device(self) -> torch.device:
        return next(itertools.chain(self.coarse.parameters(), self.coarse.buffers())).device

    def background_tensor(self) -> Tensor | None:
        return None if self.background is None else torch.tensor(self.background, device=self.device)

    def render_image(
        self, intrinsics: tuple[float, float, float, float], c2w: np.ndarray, width: int, height: int,
        near: float, far: float, chunk: int = 8192,
    ) -> dict[str, Tensor]:
        """Render a whole pinhole view. Returns rgb (H, W, 3), depth, disparity, acc (H, W), on the CPU.

        ``depth`` is the expected depth along the camera axis in world units, and ``disparity`` its
        inverse. In NDC the expected t' is mapped to world depth (``RaySpace.camera_depth``), capped at
        ``far``, since t' near 1 lies near infinity.
        """
        device = self.device
        uv = pixel_centers(width, height, device)
        n = uv.shape[0]
        k = torch.tensor(intrinsics, dtype=torch.float32, device=device).expand(n, 4)
        pose = torch.as_tensor(np.asarray(c2w), dtype=torch.float32, device=device)
        rays = self.ray_space.rays(uv, k, pose, torch.full((n,), near, device=device), torch.full((n,), far, device=device))
        out = self.render_batch(rays, chunk)
        out.pop("samples")
        if self.ray_space.ndc:
            origins, directions = camera_rays(uv, k, pose)
            depth = self.ray_space.camera_depth(origins, directions, out["depth"].to(origins))
            depth = torch.where(torch.isfinite(depth) & (depth > 0), depth, torch.full_like(depth, far)).clamp(max=far)
            out["depth"], out["disparity"] = depth, 1.0 / depth.clamp_min(1e-12)
        shapes = {"rgb": (height, width, 3)}
        return {key: value.reshape(shapes.get(key, (height, width))).cpu() for key, value in out.items()}

    # -- files ---------------------------------------------------------------------------------
    def parts(self) -> dict[str, Any]:
        """Every part with tensors, by the name its state is saved under."""
        named = {"coarse": self.coarse, "fine": self.fine, "occupancy": self.sampler, "appearance": self.appearance,
                 "refinement": self.refinement}
        return {name: part for name, part in named.items() if part is not None}

    def state(self) -> dict[str, Any]:
        """Every tensor of the model: the fields' weights, the sampler's state (an occupancy grid), the
        per-image parts; parts without tensors are left out."""
        return {name: state for name, part in self.parts().items() if (state := part.state_dict())}

    def load_state(self, weights: dict[str, Any]) -> None:
        for name, part in self.parts().items():
            if part.state_dict():
                part.load_state_dict(weights[name])

    @property
    def spec(self) -> ModelSpec:
        """What this model is made of; ``build(model.spec)`` makes its twin, untrained."""
        appearance = None if self.appearance is None else {
            "images": len(self.appearance.log2_gains), "linear": self.appearance.linear, "stops": self.appearance.start_stops}
        return ModelSpec(field=field_spec(self.coarse), sampler={"kind": self.sampler.kind, **self.sampler.spec()},
                         ray_space=self.ray_space, fine_network=self.fine is not None, background=self.background,
                         appearance=appearance,
                         refinement=None if self.refinement is None else {"images": len(self.refinement.tangent)},
                         info=self.info)

    def save(self, folder: Path) -> None:
        torch.save(self.state(), folder / "model.pt")
        (folder / "model.json").write_text(json.dumps(self.spec.to_json(), indent=1))

    @staticmethod
    def load(folder: Path, device: torch.device | str = "cpu") -> "RadianceModel":
        """The model ``save`` wrote: built from the spec in model.json, then its weights loaded."""
        spec = ModelSpec.from_json(json.loads((folder / "model.json").read_text()))
        model = build(spec, device)
        model.load_state(load_tensors(folder / "model.pt", device, "model"))
        return model


def load_tensors(path: Path, device: torch.device | str, what: str) -> dict:
    """The tensors of a file nerfpipe saved, unpickled with ``weights_only`` (no code runs). A file holding
    anything else is refused with one line, ``InputError``, and never loaded as arbitrary pickles."""
    try:
        return torch.load(path, map_location=device, weights_only=True)
    except pickle.UnpicklingError:
        raise InputError(path, f"is not a nerfpipe {what}: it holds Python objects, not only tensors, so it was not "
                         "loaded", "rerun with `--force train` to train it again; load models only from sources you trust"
                         ) from None


def build(spec: ModelSpec, device: torch.device | str = "cpu") -> RadianceModel:
    """The model ``spec`` describes, its parts made through the registry (``nerfpipe.nerf.registry``) in a
    fixed order (coarse field, fine field, sampler, per-image parts), so a seeded build is repeatable."""
    cls = resolve(FIELDS, spec.field["kind"])
    coarse = cls.from_spec(spec.field).to(device)
    fine = cls.from_spec(spec.field).to(device) if spec.fine_network else None
    sampler = resolve(SAMPLERS, spec.sampler["kind"]).from_spec(spec.sampler, spec.ray_space.contracted).to(device)
    a, r = spec.appearance, spec.refinement
    appearance = None if a is None else ExposureGains(a["images"], a["linear"], a.get("stops")).to(device)
    refinement = None if r is None else PoseRefinement(r["images"]).to(device)
    return RadianceModel(coarse, fine, sampler, spec.ray_space, spec.background, dict(spec.info), appearance, refinement)
