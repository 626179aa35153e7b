"""A trained radiance field with everything needed to render it: fields, a sampler, background and the
ray space the scene analysis chose (world rays clipped to the scene box, NDC rays, or contracted space).
Saved as ``model.pt`` (tensors only, loadable with ``torch.load(..., weights_only=True)``) and
``model.json`` (its ``ModelSpec``: each part's config); ``build`` makes a model from a spec."""

from __future__ import annotations

import dataclasses
import itertools
import json
import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from nerfpipe.nerf.appearance import ExposureGains
from nerfpipe.nerf.fields.base import Field
from nerfpipe.nerf.fused import marched_grid, reached_fused, render_fused
from nerfpipe.nerf.kernels import for_rendering
from nerfpipe.nerf.spaces.ray_space import RaySpace
from nerfpipe.nerf.spaces.rays import RayBatch, pixel_centers
from nerfpipe.nerf.refinement import PoseRefinement
from nerfpipe.nerf.registry import part_class
from nerfpipe.nerf.render.volume import RaySamples, RenderOutput, volume_render
from nerfpipe.nerf.samplers.base import Sampler
from nerfpipe.nerf.spec import ModelSpec
from nerfpipe.pipeline.errors import InputError


# what one field call may hold without gradients (rendering): a large chunk of rays, or many samples a ray left
# after early termination, is evaluated in pieces whose activations (each linear layer's output and its
# activation's, float32) stay within this, however wide the field's layers (train.field.hidden up to 1024)
EVAL_BYTES = 1 << 25
EVAL_POINTS = (1 << 10, 1 << 16)  # the fewest and most points a piece holds

# samples one rendering call may lay out (rays x the sampler's candidates a ray; about 48 bytes each): a chunk of
# rays is cut to fit, so that a fine march (sampler.steps) or a large chunk (render.chunk) cannot exhaust memory
RENDER_CANDIDATES = 1 << 22


@dataclass
class RadianceModel:
    """Coarse (and fine) fields, the sampler that says where along each ray to evaluate them, the background
    they are composited onto, and the ray space the scene analysis chose.

    ``sampler``: ``nerfpipe.nerf.samplers.base`` (Section 5.2's hierarchical sampling, or marching an occupancy
    grid with the coarse field only). Learned per training image when the scene calls for them
    (``nerfpipe.nerf.policy``): ``appearance``, each photo's exposure and white balance (renders show the
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
        return self.coarse.config.kind

    def fields(self) -> list[Field]:
        return [self.coarse] + ([self.fine] if self.fine is not None else [])

    def render(self, rays: RayBatch, *, train: bool = False, generator: torch.Generator | None = None,
               max_samples: int = 0, background: Tensor | None | str = "model", images: Tensor | None = None,
               density_noise: float = 0.0) -> RenderOutput:
        """Render ``rays`` (in the ray space's ray coordinates): the one place a model renders.

        The sampler says where along each ray to look (randomized when ``train``, and with ``max_samples``
        > 0 only for the leading rays whose samples fit it: the output's length says how many); the field it
        names is evaluated there, with noise of std ``density_noise`` on raw density (training), and
        ``volume_render`` composites. Then each photo's appearance (``images`` (R,): the training image of
        each ray, when the model learns appearance) and the ``background`` (3,) / (R, 3) behind it: "model"
        for the model's own, None for none. Gradients flow where autograd is on; ``render_rays`` renders without.
        """
        samples, level, earlier = self.sample(rays, train=train, generator=generator, max_samples=max_samples,
                                              density_noise=density_noise)
        return self.shade(rays, samples, level, earlier, background=background, images=images, density_noise=density_noise)

    def sample(self, rays: RayBatch, *, train: bool = False, generator: torch.Generator | None = None,
               max_samples: int = 0, density_noise: float = 0.0) -> tuple[RaySamples, int, tuple[RenderOutput, ...]]:
        """``render``'s first half: where the sampler looks along ``rays`` (its ``sample``: the samples, the level
        of the field to evaluate there, and the renderings it made on its way)."""
        probe = _Probe(self, rays, density_noise, self.eval_points())
        return self.sampler.sample(rays, self.ray_space, probe, train=train, generator=generator, max_samples=max_samples)

    def shade(self, rays: RayBatch, samples: RaySamples, level: int = 0, earlier: tuple[RenderOutput, ...] = (), *,
              background: Tensor | None | str = "model", images: Tensor | None = None,
              density_noise: float = 0.0) -> RenderOutput:
        """``render``'s second half: the field of ``level`` at ``samples`` of ``rays``, composited (Eq. 3), then each
        photo's appearance and the background, as ``render`` says. Shapes follow the samples' and the rays' counts
        alone, so a step that pads both to fixed counts (``nerfpipe.nerf.train.compiled``) compiles once."""
        out = _Probe(self, rays, density_noise, self.eval_points()).render(samples, level)
        out = dataclasses.replace(out, earlier=earlier,
                                  evaluated=len(samples) + sum(len(e.samples) for e in earlier))
        if images is not None and self.appearance is not None:  # as the photo's camera recorded the light
            out = out.map_rgb(lambda rgb, o: self.appearance(rgb, images[:len(o)]))
        # "over" onto the background after the exposure: a backdrop whose colour is a stand-in (alpha, a masked
        # cloth) is not exposed by the camera
        return out.over(self.background_tensor() if isinstance(background, str) else background)

    def render_rays(self, rays: RayBatch, chunk: int = 8192, background: Tensor | None | str = "model") -> dict[str, Tensor]:
        """``render`` without gradients, deterministic, ``chunk`` rays at a time (cut further to what memory
        allows, ``RENDER_CANDIDATES``): rgb (R, 3), depth, disparity, acc (R,) in the ray space's own ray
        parameter (t, or NDC t'); and ``samples``, the field evaluations per ray on average. ``background`` as
        ``render`` takes it. A model the native kernel knows renders in one loop a ray (``nerfpipe.nerf.fused``)."""
        for f in self.fields():
            f.eval()
        parts: dict[str, list[Tensor]] = {"rgb": [], "depth": [], "acc": []}
        evaluated = 0
        fused = marched_grid(self)
        # memory, not speed: the kernel holds only its outputs, torch every candidate step
        chunk = max(1, min(chunk, RENDER_CANDIDATES // self.sampler.candidates_per_ray())) if fused is None else \
            max(chunk, 1 << 16)
        behind = self.background_tensor() if isinstance(background, str) else background
        with torch.no_grad():
            for start in range(0, max(len(rays), 1), chunk):  # an empty batch renders once, to empty shapes
                part = rays.slice(start, start + chunk)
                done = None if fused is None else render_fused(fused, part)
                if done is None:
                    out = self.render(part, background=background)
                    done, evaluated = (out.rgb, out.depth, out.acc), evaluated + out.evaluated
                else:
                    rgb, depth, acc, counts = done
                    done, evaluated = (RenderOutput.blend(rgb, acc, behind), depth, acc), evaluated + int(counts.sum())
                for key, value in zip(parts, done):
                    parts[key].append(value)
        result = {key: torch.cat(values) for key, values in parts.items()}
        result["disparity"] = RenderOutput.inverse(result["depth"])
        result["samples"] = torch.tensor(evaluated / max(len(rays), 1))
        return result

    def eval_points(self) -> int:
        """Points a field call evaluates at once without gradients (``EVAL_BYTES``): fewer, the wider the
        fields' layers."""
        floats = max(sum(m.out_features for m in f.modules() if isinstance(m, torch.nn.Linear)) for f in self.fields())
        return int(min(max(EVAL_BYTES // max(8 * floats, 1), EVAL_POINTS[0]), EVAL_POINTS[1]))

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

        ``depth`` is the expected depth along the camera axis in world units (``RaySpace.camera_depth``),
        capped at ``far`` (an NDC t' near 1 lies near infinity), and ``disparity`` its inverse.
        """
        device = self.device
        uv = pixel_centers(width, height, device)
        n = uv.shape[0]
        k = torch.tensor(intrinsics, dtype=torch.float32, device=device).expand(n, 4)
        pose = torch.as_tensor(np.asarray(c2w), dtype=torch.float32, device=device)
        rays = self.ray_space.rays(uv, k, pose, torch.full((n,), near, device=device), torch.full((n,), far, device=device))
        out = self.render_rays(rays, chunk)
        out.pop("samples")
        depth = self.ray_space.camera_depth(uv, k, pose, out["depth"])
        depth = torch.where(torch.isfinite(depth) & (depth > 0), depth, torch.full_like(depth, far)).clamp(max=far)
        out["depth"], out["disparity"] = depth, 1.0 / depth.clamp_min(1e-12)
        shapes = {"rgb": (height, width, 3)}
        return {key: value.reshape(shapes.get(key, (height, width))).cpu() for key, value in out.items()}

    # -- files ---------------------------------------------------------------------------------
    def parts(self) -> dict[str, Any]:
        """Every part with tensors, by the name its state is saved under."""
        named = {"coarse": self.coarse, "fine": self.fine, "sampler": self.sampler, "appearance": self.appearance,
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
        return ModelSpec(field=self.coarse.config, sampler=self.sampler.config, ray_space=self.ray_space,
                         box=self.coarse.box(), fine_network=self.fine is not None, background=self.background,
                         appearance=appearance,
                         refinement=None if self.refinement is None else {"images": len(self.refinement.tangent)},
                         info=self.info)

    def save(self, folder: Path) -> None:
        torch.save(self.state(), folder / "model.pt")
        (folder / "model.json").write_text(json.dumps(self.spec.to_json(), indent=1))

    @staticmethod
    def load(folder: Path, device: torch.device | str = "cpu") -> "RadianceModel":
        """The model ``save`` wrote: built from the spec in model.json, then its weights loaded."""
        try:
            spec = ModelSpec.from_json(json.loads((folder / "model.json").read_text()))
        except (KeyError, TypeError, ValueError) as err:  # a model.json of an older nerfpipe, or damaged
            raise InputError(folder / "model.json", f"is not a model this nerfpipe can build ({err})",
                             "rerun with `--force train` to train it again") from None
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
    cls = part_class(spec.field)
    coarse = cls.from_config(spec.field, spec.box).to(device)
    fine = cls.from_config(spec.field, spec.box).to(device) if spec.fine_network else None
    sampler = part_class(spec.sampler).from_config(spec.sampler, spec.box).to(device)
    a, r = spec.appearance, spec.refinement
    appearance = None if a is None else ExposureGains(a["images"], a["linear"], a.get("stops")).to(device)
    refinement = None if r is None else PoseRefinement(r["images"]).to(device)
    return RadianceModel(coarse, fine, sampler, spec.ray_space, spec.background, dict(spec.info), appearance, refinement)


class _Probe:
    """What ``RadianceModel.render`` lets its sampler ask while it samples ``rays`` (``samplers.Probe``)."""

    def __init__(self, model: RadianceModel, rays: RayBatch, density_noise: float, piece: int) -> None:
        self.model, self.rays, self.noise, self.piece = model, rays, density_noise, piece

    def density_features(self, ray: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
        with torch.no_grad():
            field, rays = for_rendering(self.model.coarse), self.rays
            return _pieces(self.piece, lambda r, s: field.density_along(self.model.ray_space, rays.origins,
                                                                        rays.directions, r, s), ray, t)

    def reached(self, samples: RaySamples, early_stop: float) -> Tensor | None:
        grid = marched_grid(self.model)
        if grid is None or early_stop != grid.early_stop:
            return None
        return reached_fused(grid, self.rays, samples)

    def render(self, samples: RaySamples, level: int) -> RenderOutput:
        """The field of ``level`` (the last there is) at ``samples``, composited onto nothing (Eq. 3). The
        first field's density and features the sampler already evaluated (``RaySamples.known``) are reused."""
        model, rays = self.model, self.rays
        fields = model.fields()
        index = min(level, len(fields) - 1)
        viewdirs = rays.viewdirs[samples.ray]
        # the field's functions compiled where that pays (``nerfpipe.nerf.kernels``)
        field = fields[index] if self.noise else for_rendering(fields[index])  # eager where gradients flow (``run``)
        if samples.known is not None and index == 0:
            sigma, features = samples.known
            rgb = _pieces(self.piece, field.colour, features, viewdirs)[0]
        else:
            points = model.ray_space.field_points(rays.points(samples.ray, samples.t))
            rgb, sigma = _pieces(self.piece, lambda x, d: field(x, d, self.noise) if self.noise else field(x, d),
                                 points, viewdirs)
        n = samples.n_rays
        return volume_render(sigma, rgb, samples, rays.near[:n], rays.far[:n])


def _pieces(piece: int, fn, *inputs: Tensor):
    """``fn(*inputs)`` of (M, ...) inputs, in pieces of ``piece`` rows when gradients are off; outputs
    concatenated (a tensor output comes back as a one-tuple)."""
    count = inputs[0].shape[0]
    if torch.is_grad_enabled() or count <= piece:
        out = fn(*inputs)
        return out if isinstance(out, tuple) else (out,)
    parts = [fn(*(x[i:i + piece] for x in inputs)) for i in range(0, count, piece)]
    parts = [p if isinstance(p, tuple) else (p,) for p in parts]
    return tuple(torch.cat(column) for column in zip(*parts))
