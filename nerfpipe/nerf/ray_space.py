"""How pixels become rays for a scene, and where the field is queried along them: world rays clipped to the
scene box (inward 360), NDC rays of the mean camera (forward-facing, the paper's Section 6.1), or world rays
into contracted space (mip-NeRF 360)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from nerfpipe.nerf.contraction import BOUND, Contraction
from nerfpipe.nerf.rays import camera_rays, intersect_box, ndc_points, ndc_points_inverse, ndc_rays
from nerfpipe.nerf.renderer import RayBatch


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
