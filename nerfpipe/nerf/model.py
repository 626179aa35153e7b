"""A trained radiance field with everything needed to render it: fields, a sampler, background and the
ray space the scene analysis chose (world rays clipped to the scene box, NDC rays, or contracted space).
Saved as ``model.pt`` (tensors only, loadable with ``torch.load(..., weights_only=True)``) and
``model.json`` (each part's kind and spec, rebuilt through ``nerfpipe.nerf.registry``)."""

from __future__ import annotations

import itertools
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from torch import Tensor

from nerfpipe.nerf.appearance import ExposureGains
from nerfpipe.nerf.contraction import BOUND, Contraction
from nerfpipe.nerf.fields import Field, field_spec, load_field
from nerfpipe.nerf.rays import camera_rays, intersect_box, ndc_points, ndc_points_inverse, ndc_rays, pixel_centers
from nerfpipe.nerf.refinement import PoseRefinement
from nerfpipe.nerf.registry import SAMPLERS, resolve
from nerfpipe.nerf.renderer import RayBatch
from nerfpipe.nerf.samplers import Sampler


@dataclass(frozen=True)
class RaySpace:
    """How pixels become rays for this scene.

    ``ndc``: forward-facing; rays go into the frame of ``ndc_c2w`` (the mean camera, OpenCV) and through
    ``ndc_rays`` with ``ndc_focal``, ``ndc_size`` and ``ndc_near``; sampled over t' in [0, 1].
    ``box``: bounded (inward 360); each ray's [near, far] is clipped to the box (min, max corners).
    ``contraction``: the box (min, max corners) kept at full resolution, with everything beyond it
    contracted (``nerfpipe.nerf.contraction``, mip-NeRF 360 Eq. 10): world rays over each image's near/far,
    the fields and the occupancy grid in contracted space, [-2, 2]^3.
    """

    ndc: bool = False
    ndc_c2w: tuple[tuple[float, ...], ...] | None = None
    ndc_focal: float = 0.0
    ndc_size: tuple[int, int] = (0, 0)
    ndc_near: float = 1.0
    box: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    contraction: tuple[tuple[float, ...], tuple[float, ...]] | None = None

    @property
    def contracted(self) -> Contraction | None:
        """The map of world points into the fields' contracted space, when this space has one."""
        return None if self.contraction is None else Contraction(*self.contraction)

    def _reference(self, like: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        ref = torch.as_tensor(self.ndc_c2w, dtype=like.dtype, device=like.device)
        flip = torch.tensor([1.0, -1.0, -1.0], dtype=like.dtype, device=like.device)  # OpenCV -> OpenGL
        return ref[:3, :3], ref[:3, 3], flip

    def rays(self, uv: Tensor, intrinsics: Tensor, c2w: Tensor, near: Tensor, far: Tensor) -> RayBatch:
        """Rays for pixel positions ``uv`` (R, 2) of cameras (R, 4) / (R, 4, 4) with depth bounds (R,)."""
        origins, directions = camera_rays(uv, intrinsics, c2w)
        viewdirs = torch.nn.functional.normalize(directions, dim=-1)
        if self.ndc:
            rotation, center, flip = self._reference(origins)
            o = ((origins - center) @ rotation) * flip
            d = (directions @ rotation) * flip
            o, d = ndc_rays(o, d, self.ndc_focal, self.ndc_size[0], self.ndc_size[1], self.ndc_near)
            zeros = torch.zeros_like(near)
            return RayBatch(o, d, viewdirs, zeros, torch.ones_like(near))
        if self.box is not None:
            lo = torch.as_tensor(self.box[0], dtype=origins.dtype, device=origins.device)
            hi = torch.as_tensor(self.box[1], dtype=origins.dtype, device=origins.device)
            t_enter, t_exit = intersect_box(origins, directions, lo, hi)
            near_c, far_c = torch.maximum(near, t_enter), torch.minimum(far, t_exit)
            miss = near_c >= far_c
            # a ray that misses the box samples a zero-length interval at far: all weight goes to the background
            near = torch.where(miss, far, near_c)
            far = torch.where(miss, far, far_c)
        return RayBatch(origins, directions, viewdirs, near, far)

    def camera_depth(self, origins: Tensor, directions: Tensor, t: Tensor) -> Tensor:
        """Depth along the camera axis, in world units, of the point at ray parameter ``t`` of this space.

        World rays (``camera_rays``: unit z component in the camera) already measure it. An NDC ray's t'
        lies on the reference camera's z = -near / (1 - t') (OpenGL), which the world ray o + s d reaches
        at s = (z - o_z) / d_z in that frame.

        Args:
            origins, directions: (R, 3) world rays from ``camera_rays``; t: (R,).
        Returns:
            (R,); infinite where an NDC t' reaches 1.
        """
        if not self.ndc:
            return t
        rotation, center, flip = self._reference(origins)
        o_z = (((origins - center) @ rotation) * flip)[..., 2]
        d_z = ((directions @ rotation) * flip)[..., 2]
        z = -self.ndc_near / (1.0 - t)
        return (z - o_z) / d_z

    def to_field(self, points: Tensor) -> Tensor:
        """World points (..., 3) where the field is queried: themselves, or their NDC or contracted coordinates."""
        if self.contraction is not None:
            return self.contracted.to_field(points)
        if not self.ndc:
            return points
        rotation, center, flip = self._reference(points)
        local = ((points - center) @ rotation) * flip
        return ndc_points(local, self.ndc_focal, self.ndc_size[0], self.ndc_size[1], self.ndc_near)

    def from_field(self, points: Tensor) -> Tensor:
        """The inverse of ``to_field``: field coordinates (..., 3) back to world points."""
        if self.contraction is not None:
            return self.contracted.from_field(points)
        if not self.ndc:
            return points
        rotation, center, flip = self._reference(points)
        local = ndc_points_inverse(points, self.ndc_focal, self.ndc_size[0], self.ndc_size[1], self.ndc_near)
        return (local * flip) @ rotation.T + center

    def field_box(self, far: float | None = None) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
        """The box of field coordinates that holds the scene: the scene box, or NDC's [-1, 1]^3 cut at the
        depth ``far`` of the reference camera (z' = 1 - 2 near / far), as z' = 1 lies at infinity; the
        contracted cube [-2, 2]^3."""
        if self.contraction is not None:
            return (-BOUND, -BOUND, -BOUND), (BOUND, BOUND, BOUND)
        if self.ndc:
            z_max = 1.0 - 2.0 * self.ndc_near / far if far is not None else 1.0
            return (-1.0, -1.0, -1.0), (1.0, 1.0, z_max)
        return self.box


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

    def save(self, folder: Path) -> None:
        torch.save(self.state(), folder / "model.pt")
        doc = {
            "field": field_spec(self.coarse),
            "fine_network": self.fine is not None,
            "sampler": {"kind": self.sampler.kind, **self.sampler.spec()},
            "ray_space": asdict(self.ray_space),
            "background": None if self.background is None else list(self.background),
            "appearance": None if self.appearance is None else {
                "images": len(self.appearance.log2_gains), "linear": self.appearance.linear},
            "refinement": None if self.refinement is None else {"images": len(self.refinement.tangent)},
            "info": self.info,
        }
        (folder / "model.json").write_text(json.dumps(doc, indent=1))

    @staticmethod
    def load(folder: Path, device: torch.device | str = "cpu") -> "RadianceModel":
        """The model ``save`` wrote: every part rebuilt from model.json through the registry, then its weights."""
        doc = json.loads((folder / "model.json").read_text())
        weights = torch.load(folder / "model.pt", map_location=device, weights_only=True)
        coarse = load_field(doc["field"]).to(device)
        fine = load_field(doc["field"]).to(device) if doc["fine_network"] else None
        rs = doc["ray_space"]
        ray_space = RaySpace(
            ndc=rs["ndc"],
            ndc_c2w=None if rs["ndc_c2w"] is None else tuple(tuple(r) for r in rs["ndc_c2w"]),
            ndc_focal=rs["ndc_focal"], ndc_size=tuple(rs["ndc_size"]), ndc_near=rs["ndc_near"],
            box=None if rs["box"] is None else (tuple(rs["box"][0]), tuple(rs["box"][1])),
            contraction=None if rs.get("contraction") is None else (tuple(rs["contraction"][0]), tuple(rs["contraction"][1])),
        )
        sampler = resolve(SAMPLERS, doc["sampler"]["kind"]).from_spec(doc["sampler"], ray_space.contracted).to(device)
        background = None if doc["background"] is None else tuple(doc["background"])
        appearance = None if not doc.get("appearance") else \
            ExposureGains(doc["appearance"]["images"], doc["appearance"]["linear"]).to(device)
        refinement = None if not doc.get("refinement") else PoseRefinement(doc["refinement"]["images"]).to(device)
        model = RadianceModel(coarse, fine, sampler, ray_space, background, doc.get("info", {}), appearance, refinement)
        model.load_state(weights)
        return model
