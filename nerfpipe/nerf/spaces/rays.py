"""Camera rays (Section 4) and normalized device coordinate rays for forward-facing scenes.

Conventions: cameras are OpenCV (x right, y down, looking along +z) with COLMAP's pixel convention (the
centre of the top-left pixel is at (0.5, 0.5)); see ``nerfpipe.geometry.cameras``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor


@dataclass
class RayBatch:
    """Rays to render, in a ray space's ray coordinates (``nerfpipe.nerf.spaces.ray_space``): origins,
    directions: (R, 3); viewdirs: (R, 3) unit world directions the field sees; near, far: (R,) bounds of
    the ray parameter t."""

    origins: Tensor
    directions: Tensor
    viewdirs: Tensor
    near: Tensor
    far: Tensor

    def __len__(self) -> int:
        return self.origins.shape[0]

    def _map(self, fn) -> "RayBatch":
        return RayBatch(*(fn(getattr(self, f.name)) for f in fields(self)))

    def slice(self, start: int, stop: int) -> "RayBatch":
        return self._map(lambda x: x[start:stop])

    def to(self, device: torch.device | str) -> "RayBatch":
        return self._map(lambda x: x.to(device))

    def points(self, ray: Tensor, t: Tensor) -> Tensor:
        """o + t d of samples (N,) on rays ``ray`` (N,). (N, 3)."""
        return torch.addcmul(self.origins[ray], t.unsqueeze(-1), self.directions[ray])

    @staticmethod
    def segment(start: Tensor, end: Tensor, viewdirs: Tensor) -> "RayBatch":
        """Rays from ``start`` to ``end`` (R, 3) over t in [0, 1]."""
        count = start.shape[0]
        return RayBatch(start, end - start, viewdirs, start.new_zeros(count), start.new_ones(count))


def pixel_centers(width: int, height: int, device: torch.device | str | None = None) -> Tensor:
    """Pixel centres of a ``width`` x ``height`` image in row-major order.

    Returns:
        uv: (height * width, 2), u = column + 0.5, v = row + 0.5.
    """
    v, u = torch.meshgrid(
        torch.arange(height, device=device, dtype=torch.float32) + 0.5,
        torch.arange(width, device=device, dtype=torch.float32) + 0.5,
        indexing="ij",
    )
    return torch.stack([u.reshape(-1), v.reshape(-1)], dim=-1)


def camera_rays(uv: Tensor, intrinsics: Tensor, c2w: Tensor) -> tuple[Tensor, Tensor]:
    """Rays r(t) = o + t d through pixel positions of pinhole cameras (Section 4).

    The direction has a unit component along the camera's optical axis, so ``t`` is the depth along that
    axis and the per-image near/far depths of the bounds stage bound ``t`` directly.

    Args:
        uv: (R, 2) pixel positions (u, v).
        intrinsics: (R, 4) or (4,) as (fx, fy, cx, cy).
        c2w: (R, 4, 4), (R, 3, 4) or a single (4, 4) / (3, 4) camera-to-world pose (OpenCV convention).

    Returns:
        origins: (R, 3); directions: (R, 3), not normalized (camera-frame z component 1).
    """
    intrinsics = intrinsics.to(uv.dtype)
    fx, fy, cx, cy = intrinsics.unbind(-1)
    d_cam = torch.stack([(uv[..., 0] - cx) / fx, (uv[..., 1] - cy) / fy, torch.ones_like(uv[..., 0])], dim=-1)
    c2w = c2w.to(uv.dtype)
    rotation, translation = c2w[..., :3, :3], c2w[..., :3, 3]
    directions = (rotation @ d_cam.unsqueeze(-1)).squeeze(-1) if rotation.dim() == 3 else d_cam @ rotation.T
    origins = translation.expand_as(directions)
    return origins, directions


def ndc_rays(
    origins: Tensor, directions: Tensor, focal: float, width: int, height: int, near: float = 1.0, eps: float = 1e-6
) -> tuple[Tensor, Tensor]:
    """Rays in normalized device coordinates for forward-facing captures (Section 6.1's real scenes; the
    derivation is Appendix C, "NDC ray space derivation", of the paper's arXiv version).

    Input rays are in the frame of the reference camera in the OpenGL convention of the derivation
    (looking down -z). Each origin is first moved along its ray onto the plane z = -near (Eq. 25 there),
    then (Eq. 25's projection)::

        o' = (-f/(W/2) ox/oz, -f/(H/2) oy/oz, 1 + 2 near / oz)
        d' = (-f/(W/2) (dx/dz - ox/oz), -f/(H/2) (dy/dz - oy/oz), -2 near / oz)

    so t' in [0, 1) spans near to infinity. A ray parallel to the image plane (dz = 0) never reaches
    infinity; its dz is pushed away from 0 by ``eps`` (keeping its sign) so every output stays finite.

    Args:
        origins, directions: (R, 3).
    Returns:
        ndc_origins, ndc_directions: (R, 3).
    """
    dz = directions[..., 2]
    dz = torch.where(dz.abs() < eps, torch.where(dz < 0, -eps, eps) * torch.ones_like(dz), dz)
    t = -(near + origins[..., 2]) / dz
    origins = origins + t.unsqueeze(-1) * directions
    oz = origins[..., 2]
    oz = torch.where(oz.abs() < eps, torch.full_like(oz, -eps), oz)  # only reachable after the dz guard
    ax, ay = -focal / (width / 2.0), -focal / (height / 2.0)
    o = torch.stack([ax * origins[..., 0] / oz, ay * origins[..., 1] / oz, 1.0 + 2.0 * near / oz], dim=-1)
    d = torch.stack(
        [
            ax * (directions[..., 0] / dz - origins[..., 0] / oz),
            ay * (directions[..., 1] / dz - origins[..., 1] / oz),
            -2.0 * near / oz,
        ],
        dim=-1,
    )
    return o, d


def ndc_points(points: Tensor, focal: float, width: int, height: int, near: float = 1.0) -> Tensor:
    """Points of the reference camera's frame (OpenGL: looking down -z, z < 0 in front) in NDC: the
    projection ``ndc_rays`` applies to ray origins, (-f/(W/2) x/z, -f/(H/2) y/z, 1 + 2 near / z).

    Args:
        points: (..., 3) with z < 0.
    Returns:
        (..., 3); z' runs from -1 on the near plane to 1 at infinity.
    """
    x, y, z = points.unbind(-1)
    ax, ay = -focal / (width / 2.0), -focal / (height / 2.0)
    return torch.stack([ax * x / z, ay * y / z, 1.0 + 2.0 * near / z], dim=-1)


def ndc_points_inverse(points: Tensor, focal: float, width: int, height: int, near: float = 1.0) -> Tensor:
    """The inverse of ``ndc_points``: z = 2 near / (z' - 1), x = -x' z (W/2) / f, y = -y' z (H/2) / f.

    Args:
        points: (..., 3) NDC points with z' < 1.
    Returns:
        (..., 3) points of the reference camera's frame (OpenGL).
    """
    xn, yn, zn = points.unbind(-1)
    z = 2.0 * near / (zn - 1.0)
    return torch.stack([-xn * z * (width / 2.0) / focal, -yn * z * (height / 2.0) / focal, z], dim=-1)


def intersect_box(origins: Tensor, directions: Tensor, box_min: Tensor, box_max: Tensor) -> tuple[Tensor, Tensor]:
    """Entry and exit parameters of rays through an axis-aligned box (the slab method).

    Args:
        origins, directions: (R, 3); box_min, box_max: (3,).
    Returns:
        t_enter, t_exit: (R,). A ray that misses the box has t_enter >= t_exit. Components of a direction
        that are 0 give +-inf slab bounds, handled without NaN.
    """
    safe = torch.where(directions.abs() < 1e-12, torch.full_like(directions, 1e-12), directions)
    t0 = (box_min - origins) / safe
    t1 = (box_max - origins) / safe
    t_enter = torch.minimum(t0, t1).amax(dim=-1)
    t_exit = torch.maximum(t0, t1).amin(dim=-1)
    return t_enter, t_exit
