"""A small software rasterizer for pictures without a display: triangles with a z-buffer and flat shading,
points splatted as discs, line segments clipped to the view."""

from __future__ import annotations

from typing import Any

import numpy as np

from nerfpipe.export.views import ViewCamera
from nerfpipe.export.o3d import open3d

MESH_GREY = 0.72  # meshes without colours


def render_mesh(mesh: Any, view: ViewCamera) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast a mesh, headlight Lambert shading: colour (0.25 + 0.75 |n . d|) per pixel.

    Returns:
        depth: (H, W) camera z of the first hit, inf where no triangle is hit; rgb: (H, W, 3) in [0, 1].
    """
    o3d = open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    origins, directions = view.pixel_rays()
    rays = np.concatenate([origins, directions], axis=-1).astype(np.float32)
    hits = scene.cast_rays(o3d.core.Tensor(rays))
    t_hit = hits["t_hit"].numpy()  # in units of the direction, whose z is 1: the depth
    hit = np.isfinite(t_hit)
    rgb = np.zeros((len(rays), 3))
    ids = hits["primitive_ids"].numpy()[hit].astype(np.int64)
    if mesh.has_vertex_colors():
        # primitive_uvs (a, b) are barycentrics: p = (1 - a - b) v0 + a v1 + b v2
        ab = hits["primitive_uvs"].numpy()[hit].astype(np.float64)
        weights = np.stack([1.0 - ab[:, 0] - ab[:, 1], ab[:, 0], ab[:, 1]], axis=-1)
        corner_colors = np.asarray(mesh.vertex_colors)[np.asarray(mesh.triangles)[ids]]  # (n, 3, 3)
        base = np.einsum("nk,nkc->nc", weights, corner_colors)
    else:
        base = np.full((len(ids), 3), MESH_GREY)
    normals = hits["primitive_normals"].numpy()[hit].astype(np.float64)
    d = directions[hit] / np.linalg.norm(directions[hit], axis=-1, keepdims=True)
    cosine = np.abs(np.sum(normals * d, axis=-1)) / np.maximum(np.linalg.norm(normals, axis=-1), 1e-12)
    rgb[hit] = np.clip(base * (0.25 + 0.75 * cosine)[:, None], 0.0, 1.0)
    depth = np.where(hit, t_hit, np.inf)
    return depth.reshape(view.height, view.width), rgb.reshape(view.height, view.width, 3)


def disc_offsets(radius: int) -> list[tuple[int, int]]:
    # r^2 + r rather than r^2 rounds the disc: radius 1 is the full 3x3 block, radius 2 a 21-pixel disc
    r = int(radius)
    return [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if dy * dy + dx * dx <= r * r + r]


def splat_points(
    xyz: np.ndarray, rgb: np.ndarray, view: ViewCamera, radius: int
) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffered disc splats of ``radius`` pixels; where splats overlap the nearest point wins.

    Two passes, so the cost of the splat size does not grow with the number of points: first the nearest
    point of each pixel, then a min-depth filter with the disc over that image. Both give the same
    picture as drawing every disc with a depth test.

    Args:
        xyz: (N, 3) world points; rgb: (N, 3) in [0, 1].
    Returns:
        depth: (H, W), inf where no splat; rgb: (H, W, 3).
    """
    H, W, r = view.height, view.width, int(radius)
    uv, z = view.project(xyz)
    with np.errstate(invalid="ignore"):
        ok = (z > 0) & np.all(np.isfinite(uv), axis=-1)
        col = np.floor(uv[:, 0], where=ok, out=np.zeros(len(z)))
        row = np.floor(uv[:, 1], where=ok, out=np.zeros(len(z)))
    # padded by r, so points just off the image still spill their disc onto it
    ok &= (col >= -r) & (col < W + r) & (row >= -r) & (row < H + r)
    col, row, z, rgb = col[ok].astype(np.int64) + r, row[ok].astype(np.int64) + r, z[ok], rgb[ok]
    Wp, Hp = W + 2 * r, H + 2 * r
    index = row * Wp + col
    order = np.lexsort((z, index))  # by pixel, then nearest first
    first = order[np.r_[True, index[order][1:] != index[order][:-1]]] if len(order) else order
    nearest_z = np.full(Hp * Wp, np.inf)
    nearest_rgb = np.zeros((Hp * Wp, 3))
    nearest_z[index[first]] = z[first]
    nearest_rgb[index[first]] = rgb[first]
    nearest_z, nearest_rgb = nearest_z.reshape(Hp, Wp), nearest_rgb.reshape(Hp, Wp, 3)

    depth = np.full((H, W), np.inf)
    out = np.zeros((H, W, 3))
    for dy, dx in disc_offsets(r):
        shifted_z = nearest_z[r + dy : r + dy + H, r + dx : r + dx + W]
        nearer = shifted_z < depth
        depth[nearer] = shifted_z[nearer]
        out[nearer] = nearest_rgb[r + dy : r + dy + H, r + dx : r + dx + W][nearer]
    return depth, out


def clip_segments(p0: np.ndarray, p1: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """Liang-Barsky clipping of 2D segments to the box [lo, hi].

    Args:
        p0, p1: (M, 2); lo, hi: (2,).
    Returns:
        keep: (M,) bool; q0, q1: (M, 2) clipped end points (meaningful where ``keep``).
    """
    d = p1 - p0
    t0, t1 = np.zeros(len(p0)), np.ones(len(p0))
    keep = np.ones(len(p0), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in range(2):
            for p, q in ((-d[:, axis], p0[:, axis] - lo[axis]), (d[:, axis], hi[axis] - p0[:, axis])):
                parallel = p == 0
                keep &= ~(parallel & (q < 0))
                t = q / p
                t0 = np.where(~parallel & (p < 0), np.maximum(t0, t), t0)
                t1 = np.where(~parallel & (p > 0), np.minimum(t1, t), t1)
    keep &= t0 <= t1
    return keep, p0 + t0[:, None] * d, p0 + t1[:, None] * d


def draw_segments(image: np.ndarray, segments: np.ndarray, view: ViewCamera, color: tuple[int, int, int]) -> None:
    """Draw world segments (M, 2, 3) into ``image`` (H, W, 3) uint8, no depth test; the parts behind the
    camera are cut off at a near plane first, since a projection through z <= 0 flips them across the image."""
    import cv2

    if len(segments) == 0:
        return
    cam = view.to_camera_frame(segments.reshape(-1, 3)).reshape(-1, 2, 3)
    near = 1e-6 * max(1.0, float(np.abs(cam).max()))
    za, zb = cam[:, 0, 2], cam[:, 1, 2]
    keep = (za > near) | (zb > near)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip((near - za) / (zb - za), 0.0, 1.0)  # where the segment crosses z = near
    crossing = cam[:, 0] + t[:, None] * (cam[:, 1] - cam[:, 0])
    a = np.where((za > near)[:, None], cam[:, 0], crossing)
    b = np.where((zb > near)[:, None], cam[:, 1], crossing)
    fx, fy, cx, cy = view.intrinsics
    focal, centre = np.array([fx, fy]), np.array([cx, cy])
    with np.errstate(divide="ignore", invalid="ignore"):
        # cv2 puts integer coordinates on pixel centres; ours are at +0.5
        pa = a[:, :2] / a[:, 2:] * focal + centre - 0.5
        pb = b[:, :2] / b[:, 2:] * focal + centre - 0.5
    keep &= np.all(np.isfinite(pa), axis=-1) & np.all(np.isfinite(pb), axis=-1)
    pa, pb = pa[keep], pb[keep]
    # clipped in float first: cv2 takes int32 coordinates, which a point near the camera plane overflows
    inside, pa, pb = clip_segments(pa, pb, np.array([-2.0, -2.0]), np.array([view.width + 1.0, view.height + 1.0]))
    shift = 4  # sub-pixel end points: cv2 reads coordinates as fixed point with 4 fractional bits
    thickness = max(1, round(min(view.width, view.height) / 400))
    starts = np.round(pa[inside] * 2**shift).astype(int)
    ends = np.round(pb[inside] * 2**shift).astype(int)
    for (x0, y0), (x1, y1) in zip(starts, ends, strict=True):
        cv2.line(image, (int(x0), int(y0)), (int(x1), int(y1)), color, thickness, cv2.LINE_AA, shift)
