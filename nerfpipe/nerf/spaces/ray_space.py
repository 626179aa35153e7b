"""Ray spaces: how pixels become rays for a scene, where along them the field is queried, and how field
coordinates map back to the world. Three, each a class behind one protocol, so that no caller asks which
one it has:

- ``BoxSpace``: world rays, clipped to the scene box when there is one (inward 360°), else over each
  image's near/far; the field lives in world coordinates.
- ``NdcSpace``: forward-facing captures (the paper's Section 6.1): rays in normalized device coordinates of
  the mean camera, t' in [0, 1] from the near plane to infinity; the field lives in NDC.
- ``ContractedSpace``: scenes that reach beyond their box (mip-NeRF 360, Eq. 10): world rays over each
  image's near/far, the field in contracted coordinates, the box at full resolution and the rest of the
  world squeezed into a shell around it.

A ray's points ``o + t d`` are in the space's *ray coordinates* (world, or NDC); ``field_points`` takes
them to the field's coordinates, ``to_field`` / ``from_field`` take world points there and back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Protocol

import torch
from torch import Tensor

from nerfpipe.nerf import native
from nerfpipe.nerf.spaces.contraction import BOUND, Contraction
from nerfpipe.nerf.spaces.rays import RayBatch, camera_rays, intersect_box, ndc_points, ndc_points_inverse, ndc_rays

Box = tuple[tuple[float, ...], tuple[float, ...]]


class RaySpace(Protocol):
    """How pixels become rays and rays' points become field coordinates (see the module's docstring)."""

    kind: ClassVar[str]

    def rays(self, uv: Tensor, intrinsics: Tensor, c2w: Tensor, near: Tensor, far: Tensor) -> RayBatch:
        """Rays for pixel positions ``uv`` (R, 2) of cameras (R, 4) / (R, 4, 4) with depth bounds (R,), in
        ray coordinates; their ``viewdirs`` are unit world directions."""

    def segment_rays(self, start: Tensor, end: Tensor, viewdirs: Tensor) -> RayBatch:
        """Rays from world points ``start`` to ``end`` (R, 3), t in [0, 1]; ``viewdirs`` (R, 3) unit."""

    def field_points(self, points: Tensor) -> Tensor:
        """Points (..., 3) of rays in ray coordinates -> the field's coordinates."""

    def to_field(self, points: Tensor) -> Tensor:
        """World points (..., 3) -> field coordinates."""

    def from_field(self, points: Tensor) -> Tensor:
        """Field coordinates (..., 3) -> world points; the inverse of ``to_field``."""

    def steps(self, origins: Tensor, directions: Tensor, near: Tensor, far: Tensor, step: float,
              most: int) -> tuple[Tensor, Tensor]:
        """Steps of about ``step`` in field coordinates along rays (R, 3) in ray coordinates, tiling
        [near, far] (R,): their starts and ends (R, S) in ray parameter, S at most ``most``; a step past a
        ray's far bound starts and ends at far."""

    def camera_depth(self, uv: Tensor, intrinsics: Tensor, c2w: Tensor, t: Tensor) -> Tensor:
        """Depth along the camera axis, in world units, of ray parameter ``t`` (R,) of the rays ``rays``
        makes for these pixels; infinite where it lies at infinity."""

    def field_box(self, far: float | None = None) -> Box | None:
        """The box of field coordinates that holds the scene (``far``: the farthest depth a photo sees),
        or None where the field is unbounded."""

    def mesh_box(self, far: float, scene_box: Box, region: str) -> Box:
        """The box of field coordinates a surface is extracted from: ``region`` "box" for the scene box
        only, "all" for all the field holds."""

    def world_voxel(self, voxel: float, resolution: int, scene_box: Box) -> float:
        """The world size that stands for a field voxel of ``voxel`` on a grid of ``resolution`` cells a side."""

    def seen_map(self) -> Callable[[Tensor], Tensor] | None:
        """Field coordinates -> world points, for finding the cells the training cameras see; None where
        every cell of the field box is in their view by construction."""

    def to_json(self) -> dict[str, Any]: ...

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> "RaySpace": ...


def _box_tensors(box: Box, like: Tensor) -> tuple[Tensor, Tensor]:
    return (torch.as_tensor(box[0], dtype=like.dtype, device=like.device),
            torch.as_tensor(box[1], dtype=like.dtype, device=like.device))


def constant_steps(directions: Tensor, near: Tensor, far: Tensor, step: float, most: int) -> tuple[Tensor, Tensor]:
    """Steps of length ``step`` in the rays' own coordinates tiling [near, far]: starts and ends (R, S), the
    last step of a ray cut at far, S the most any ray needs (at most ``most``: rays longer than that many
    steps, unclipped ones, stop there)."""
    norm = torch.linalg.vector_norm(directions, dim=-1).clamp_min(1e-12)
    dt = step / norm
    length = (far - near).clamp_min(0.0)
    needed = torch.nan_to_num(length / dt, nan=0.0, posinf=0.0)
    n_steps = int(torch.ceil(needed.max()).item()) if len(near) else 0
    n_steps = max(min(n_steps, most), 1)
    k = torch.arange(n_steps, device=directions.device, dtype=directions.dtype)
    starts = torch.minimum(near.unsqueeze(-1) + k * dt.unsqueeze(-1), far.unsqueeze(-1))
    return starts, torch.minimum(starts + dt.unsqueeze(-1), far.unsqueeze(-1))


def _camera_axis_depth(uv: Tensor, intrinsics: Tensor, c2w: Tensor, t: Tensor) -> Tensor:
    return t  # ``camera_rays`` directions have a unit component along the camera axis: t is that depth


def _world_rays(uv: Tensor, intrinsics: Tensor, c2w: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    origins, directions = camera_rays(uv, intrinsics, c2w)
    return origins, directions, torch.nn.functional.normalize(directions, dim=-1)


@dataclass(frozen=True)
class BoxSpace:
    """World rays, clipped to ``box`` (min, max corners) when there is one; the field in world coordinates."""

    box: Box | None = None
    kind: ClassVar[str] = "box"

    def rays(self, uv: Tensor, intrinsics: Tensor, c2w: Tensor, near: Tensor, far: Tensor) -> RayBatch:
        origins, directions, viewdirs = _world_rays(uv, intrinsics, c2w)
        if self.box is not None:
            lo, hi = _box_tensors(self.box, origins)
            t_enter, t_exit = intersect_box(origins, directions, lo, hi)
            near_c, far_c = torch.maximum(near, t_enter), torch.minimum(far, t_exit)
            miss = near_c >= far_c
            # a ray that misses the box samples a zero-length interval at far: all weight goes to the background
            near = torch.where(miss, far, near_c)
            far = torch.where(miss, far, far_c)
        return RayBatch(origins, directions, viewdirs, near, far)

    def segment_rays(self, start: Tensor, end: Tensor, viewdirs: Tensor) -> RayBatch:
        return RayBatch.segment(start, end, viewdirs)

    def field_points(self, points: Tensor) -> Tensor:
        return points

    def to_field(self, points: Tensor) -> Tensor:
        return points

    def from_field(self, points: Tensor) -> Tensor:
        return points

    def steps(self, origins: Tensor, directions: Tensor, near: Tensor, far: Tensor, step: float,
              most: int) -> tuple[Tensor, Tensor]:
        return constant_steps(directions, near, far, step, most)

    camera_depth = staticmethod(_camera_axis_depth)

    def field_box(self, far: float | None = None) -> Box | None:
        return self.box

    def mesh_box(self, far: float, scene_box: Box, region: str) -> Box:
        return self.box or (tuple(scene_box[0]), tuple(scene_box[1]))

    def world_voxel(self, voxel: float, resolution: int, scene_box: Box) -> float:
        return voxel

    def seen_map(self) -> Callable[[Tensor], Tensor] | None:
        return self.from_field

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "box": None if self.box is None else [list(self.box[0]), list(self.box[1])]}

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> "BoxSpace":
        return cls(_box(doc["box"]))


def _scene_share(resolution: int, scene_box: Box) -> float:
    """NDC and contracted voxels vary in world size: the scene box's share stands in for them."""
    return max(float(h) - float(l) for l, h in zip(*scene_box)) / resolution


@dataclass(frozen=True)
class NdcSpace:
    """Forward-facing: rays go into the frame of ``c2w`` (the mean camera, OpenCV) and through ``ndc_rays``
    with ``focal``, ``size`` (width, height) and ``near``; sampled over t' in [0, 1]. The field lives in NDC."""

    c2w: tuple[tuple[float, ...], ...]
    focal: float
    size: tuple[int, int]
    near: float = 1.0
    kind: ClassVar[str] = "ndc"

    def _reference(self, like: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        ref = torch.as_tensor(self.c2w, dtype=like.dtype, device=like.device)
        flip = torch.tensor([1.0, -1.0, -1.0], dtype=like.dtype, device=like.device)  # OpenCV -> OpenGL
        return ref[:3, :3], ref[:3, 3], flip

    def _local(self, origins: Tensor, directions: Tensor) -> tuple[Tensor, Tensor]:
        """World rays in the reference camera's OpenGL frame."""
        rotation, center, flip = self._reference(origins)
        return ((origins - center) @ rotation) * flip, (directions @ rotation) * flip

    def rays(self, uv: Tensor, intrinsics: Tensor, c2w: Tensor, near: Tensor, far: Tensor) -> RayBatch:
        origins, directions, viewdirs = _world_rays(uv, intrinsics, c2w)
        o, d = ndc_rays(*self._local(origins, directions), self.focal, self.size[0], self.size[1], self.near)
        return RayBatch(o, d, viewdirs, torch.zeros_like(near), torch.ones_like(near))

    def segment_rays(self, start: Tensor, end: Tensor, viewdirs: Tensor) -> RayBatch:
        # NDC maps straight lines to straight lines: the segment between the ends' NDC points is the same one
        return RayBatch.segment(self.to_field(start), self.to_field(end), viewdirs)

    def field_points(self, points: Tensor) -> Tensor:
        return points

    def to_field(self, points: Tensor) -> Tensor:
        rotation, center, flip = self._reference(points)
        local = ((points - center) @ rotation) * flip
        return ndc_points(local, self.focal, self.size[0], self.size[1], self.near)

    def from_field(self, points: Tensor) -> Tensor:
        rotation, center, flip = self._reference(points)
        local = ndc_points_inverse(points, self.focal, self.size[0], self.size[1], self.near)
        return (local * flip) @ rotation.T + center

    def steps(self, origins: Tensor, directions: Tensor, near: Tensor, far: Tensor, step: float,
              most: int) -> tuple[Tensor, Tensor]:
        return constant_steps(directions, near, far, step, most)

    def camera_depth(self, uv: Tensor, intrinsics: Tensor, c2w: Tensor, t: Tensor) -> Tensor:
        """An NDC ray's t' lies on the reference camera's z = -near / (1 - t') (OpenGL), which the world ray
        o + s d reaches at s = (z - o_z) / d_z in that frame; s is the camera-axis depth (``camera_rays``)."""
        origins, directions = camera_rays(uv, intrinsics, c2w)
        o, d = self._local(origins, directions)
        z = -self.near / (1.0 - t.to(o))
        return (z - o[..., 2]) / d[..., 2]

    def field_box(self, far: float | None = None) -> Box:
        """NDC's [-1, 1]^3 cut at the depth ``far`` of the reference camera (z' = 1 - 2 near / far), as
        z' = 1 lies at infinity."""
        z_max = 1.0 - 2.0 * self.near / far if far is not None else 1.0
        return (-1.0, -1.0, -1.0), (1.0, 1.0, z_max)

    def mesh_box(self, far: float, scene_box: Box, region: str) -> Box:
        return self.field_box(far)

    def world_voxel(self, voxel: float, resolution: int, scene_box: Box) -> float:
        return _scene_share(resolution, scene_box)

    def seen_map(self) -> None:
        return None  # NDC's frustum is the cameras' view by design

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "c2w": [list(r) for r in self.c2w], "focal": self.focal, "size": list(self.size),
                "near": self.near}

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> "NdcSpace":
        return cls(tuple(tuple(float(v) for v in r) for r in doc["c2w"]), float(doc["focal"]),
                   (int(doc["size"][0]), int(doc["size"][1])), float(doc["near"]))


@dataclass(frozen=True)
class ContractedSpace:
    """World rays over each image's near/far; the field in contracted coordinates ([-2, 2]^3), ``box``
    (min, max corners) at full resolution as [-1, 1]^3 and everything beyond squeezed into the shell."""

    box: Box
    kind: ClassVar[str] = "contracted"

    @property
    def contraction(self) -> Contraction:
        return Contraction(tuple(self.box[0]), tuple(self.box[1]))

    def rays(self, uv: Tensor, intrinsics: Tensor, c2w: Tensor, near: Tensor, far: Tensor) -> RayBatch:
        return RayBatch(*_world_rays(uv, intrinsics, c2w), near, far)

    def segment_rays(self, start: Tensor, end: Tensor, viewdirs: Tensor) -> RayBatch:
        return RayBatch.segment(start, end, viewdirs)

    def field_points(self, points: Tensor) -> Tensor:
        return self.contraction.to_field(points)

    def to_field(self, points: Tensor) -> Tensor:
        return self.contraction.to_field(points)

    def from_field(self, points: Tensor) -> Tensor:
        return self.contraction.from_field(points)

    def steps(self, origins: Tensor, directions: Tensor, near: Tensor, far: Tensor, step: float,
              most: int) -> tuple[Tensor, Tensor]:
        """Inside the box a constant world step; beyond it one that grows with the squared distance from the
        box (``Contraction.step_scale_at``), so far content gets as many samples as its size in the field.
        Each step's length is set at its start, from the point's norm before contraction (5 tensor
        operations a step rather than 25 through the contracted point; on the CPU one loop in C,
        ``nerfpipe.nerf.native.contracted_steps``)."""
        x0, dx = self.contraction.box_rays(origins, directions)
        base = step / torch.linalg.vector_norm(dx, dim=-1).clamp_min(1e-12)
        edges = native.contracted_steps(x0, dx, base, near, far, most)  # the same loop in C, where it runs
        if edges is not None:
            return edges[:, :-1], edges[:, 1:]
        t = near.clone()
        edges = [t]
        for _ in range(most):
            norm = torch.addcmul(x0, t.unsqueeze(-1), dx).abs().amax(dim=-1)
            t = torch.minimum(torch.addcmul(t, base, Contraction.step_scale_at(norm)), far)
            edges.append(t)
            if not bool((t < far).any()):
                break
        stacked = torch.stack(edges, dim=-1)
        return stacked[:, :-1], stacked[:, 1:]

    camera_depth = staticmethod(_camera_axis_depth)

    def field_box(self, far: float | None = None) -> Box:
        return (-BOUND, -BOUND, -BOUND), (BOUND, BOUND, BOUND)

    def mesh_box(self, far: float, scene_box: Box, region: str) -> Box:
        """The scene box ([-1, 1]^3 here) or, for ``region="all"``, the whole contracted cube short of its
        surface, which lies at infinity."""
        edge = 1.0 if region == "box" else 1.99
        return (-edge,) * 3, (edge,) * 3

    def world_voxel(self, voxel: float, resolution: int, scene_box: Box) -> float:
        return _scene_share(resolution, scene_box)

    def seen_map(self) -> Callable[[Tensor], Tensor]:
        return self.from_field

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "box": [list(self.box[0]), list(self.box[1])]}

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> "ContractedSpace":
        return cls(_box(doc["box"]))


def _box(value: Any) -> Box | None:
    return None if value is None else (tuple(float(v) for v in value[0]), tuple(float(v) for v in value[1]))


def space_from_json(doc: dict[str, Any]) -> RaySpace:
    """The ray space a model.json holds: the class its ``kind`` names (``nerfpipe.nerf.registry.SPACES``)."""
    from nerfpipe.nerf.registry import SPACES, load

    if doc.get("kind") not in SPACES:
        raise ValueError(f"unknown ray space {doc.get('kind')!r}; known: {', '.join(SPACES)}")
    return load(SPACES[doc["kind"]]).from_json(doc)
