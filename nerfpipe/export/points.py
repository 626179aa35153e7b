"""Point clouds from rendered depth: back-projection, filtering and the move back to the SfM frame."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from nerfpipe.geometry.normalize import Similarity
from nerfpipe.export.o3d import open3d


@dataclass
class Cloud:
    """Points (N, 3), colours (N, 3) in [0, 1], normals (N, 3) or None."""

    xyz: np.ndarray
    rgb: np.ndarray
    normals: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.xyz)


def backproject(depth: np.ndarray, K: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """World points of every pixel centre at its depth along the camera axis (OpenCV camera).

    x_cam = depth * K^-1 (u + 1/2, v + 1/2, 1); x_world = R x_cam + c.

    Args:
        depth: (H, W); K: (3, 3); c2w: (4, 4).
    Returns:
        (H, W, 3).
    """
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    cam = rays * depth[..., None]
    return cam @ np.asarray(c2w)[:3, :3].T + np.asarray(c2w)[:3, 3]


View = tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]  # rendered {depth, acc, rgb}, K (3, 3), c2w (4, 4)


def solid(rendered: dict[str, np.ndarray], acc_threshold: float) -> np.ndarray:
    """(H, W) pixels whose accumulated opacity reaches ``acc_threshold`` at a finite positive depth."""
    depth = rendered["depth"]
    return (rendered["acc"] >= acc_threshold) & np.isfinite(depth) & (depth > 0)


def nearest_views(c2ws: Sequence[np.ndarray], count: int, max_angle: float = 60.0) -> list[list[int]]:
    """For each camera, up to ``count`` others that look the most the same way (optical axes within
    ``max_angle`` degrees), the smallest angle first."""
    forward = np.stack([np.asarray(c)[:3, 2] for c in c2ws])
    cosines = forward @ forward.T
    np.fill_diagonal(cosines, -2.0)
    order = np.argsort(-cosines, axis=1)[:, :count]
    limit = np.cos(np.radians(max_angle))
    return [[int(j) for j in row if cosines[i, j] >= limit] for i, row in enumerate(order)]


def agreement(views: Sequence[View], acc_threshold: float, neighbours: int, tolerance: float) -> list[np.ndarray]:
    """How many other views each pixel's depth is confirmed by: the multi-view geometric consistency check
    of depth-map fusion (as COLMAP's stereo fusion and MVSNet filter their depth maps).

    A pixel's back-projected point, projected into a neighbouring view (``nearest_views``), agrees with it
    when it lands inside that view on a solid pixel whose depth is within ``tolerance`` (relative) of the
    point's depth there. A depth that is an average of two surfaces along the ray -- the starburst of
    points between an object and what is behind it, and floaters -- finds no other view that agrees.

    Returns:
        per view, (H, W) counts of agreeing neighbours (0 where the pixel is not solid itself).
    """
    solids = [solid(rendered, acc_threshold) for rendered, _, _ in views]
    others = nearest_views([c2w for _, _, c2w in views], neighbours)
    counts = []
    for i, (rendered, K, c2w) in enumerate(views):
        count = np.zeros(rendered["depth"].shape, dtype=np.int32)
        pixels = np.flatnonzero(solids[i])
        points = backproject(rendered["depth"], K, c2w).reshape(-1, 3)[pixels]
        for j in others[i]:
            other, K_j, c2w_j = views[j]
            c2w_j = np.asarray(c2w_j)
            cam = (points - c2w_j[:3, 3]) @ c2w_j[:3, :3]  # R^T (p - c), row vectors
            z = cam[:, 2]
            ahead = z > 1e-9
            u = np.floor(K_j[0, 0] * cam[:, 0] / np.where(ahead, z, 1.0) + K_j[0, 2]).astype(np.int64)
            v = np.floor(K_j[1, 1] * cam[:, 1] / np.where(ahead, z, 1.0) + K_j[1, 2]).astype(np.int64)
            h, w = other["depth"].shape
            seen = ahead & (u >= 0) & (u < w) & (v >= 0) & (v < h)
            rows = np.flatnonzero(seen)
            found = other["depth"][v[rows], u[rows]]
            agree = solids[j][v[rows], u[rows]] & (np.abs(found - z[rows]) <= tolerance * z[rows])
            count.reshape(-1)[pixels[rows[agree]]] += 1
        counts.append(count)
    return counts


def views_to_points(views: Sequence[View], acc_threshold: float, box: tuple[Sequence[float], Sequence[float]] | None = None,
                    masks: Sequence[np.ndarray] | None = None) -> tuple[Cloud, np.ndarray]:
    """Back-project every view's pixels whose accumulated opacity reaches ``acc_threshold``.

    Args:
        views: (rendered {depth (H, W), acc (H, W), rgb (H, W, 3)}, K (3, 3), c2w (4, 4)) per view.
        box: keep points inside this (min, max) box only.
        masks: per view, (H, W) the pixels to keep besides (``agreement``'s).
    Returns:
        the cloud, with each point's unit direction towards the camera that saw it as its normal (a hint
        for orienting estimated normals), and the index of that camera (N,).
    """
    xyz, rgb, towards, source = [], [], [], []
    for index, (rendered, K, c2w) in enumerate(views):
        keep = solid(rendered, acc_threshold) & (True if masks is None else masks[index])
        points = backproject(rendered["depth"], K, c2w)[keep]
        if box is not None:
            inside = np.all((points >= np.asarray(box[0])) & (points <= np.asarray(box[1])), axis=1)
            points, keep_idx = points[inside], np.flatnonzero(keep.ravel())[inside]
        else:
            keep_idx = np.flatnonzero(keep.ravel())
        colours = rendered["rgb"].reshape(-1, 3)[keep_idx]
        to_camera = np.asarray(c2w)[:3, 3] - points
        to_camera /= np.maximum(np.linalg.norm(to_camera, axis=1, keepdims=True), 1e-12)
        xyz.append(points)
        rgb.append(colours)
        towards.append(to_camera)
        source.append(np.full(len(points), index))
    if not xyz:
        return Cloud(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))), np.zeros(0, dtype=int)
    return Cloud(np.concatenate(xyz), np.concatenate(rgb), np.concatenate(towards)), np.concatenate(source)


def to_open3d(cloud: Cloud) -> Any:
    o3d = open3d()

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(cloud.xyz, dtype=np.float64)))
    pcd.colors = o3d.utility.Vector3dVector(np.clip(np.asarray(cloud.rgb, dtype=np.float64), 0.0, 1.0))
    if cloud.normals is not None:
        pcd.normals = o3d.utility.Vector3dVector(np.asarray(cloud.normals, dtype=np.float64))
    return pcd


def from_open3d(pcd: Any) -> Cloud:
    normals = np.asarray(pcd.normals) if pcd.has_normals() else None
    rgb = np.asarray(pcd.colors) if pcd.has_colors() else np.full((len(pcd.points), 3), 0.5)
    return Cloud(np.asarray(pcd.points).copy(), rgb.copy(), None if normals is None else normals.copy())


@dataclass(frozen=True)
class CleanReport:
    """What cleaning did, for the stage summary."""

    raw: int
    voxel: float
    after_voxel: int
    after_outliers: int


def clean_cloud(cloud: Cloud, voxel: float, target_points: int, outlier_neighbors: int = 20,
                outlier_std: float = 2.0) -> tuple[Cloud, CleanReport]:
    """Voxel down-sampling (growing the voxel until at most ``target_points`` remain), statistical
    outlier removal and normals estimated from neighbours (Open3D), oriented like the hint normals
    (towards the cameras that saw each point), so surfaces face outward.

    Args:
        voxel: the smallest voxel edge; 0 skips down-sampling unless the target asks for it.
    """
    o3d = open3d()

    pcd = to_open3d(cloud)
    raw = len(pcd.points)
    size = voxel
    down = pcd.voxel_down_sample(size) if size > 0 else pcd
    if target_points > 0:
        extent = float(np.linalg.norm(np.ptp(cloud.xyz, axis=0))) if raw else 1.0
        size = size if size > 0 else extent / 2048
        for _ in range(12):  # points on surfaces scale with 1 / voxel^2
            if len(down.points) <= target_points:
                break
            size *= max(1.05, float(np.sqrt(len(down.points) / target_points)))
            down = pcd.voxel_down_sample(size)
    after_voxel = len(down.points)
    if after_voxel > outlier_neighbors:
        down, _ = down.remove_statistical_outlier(nb_neighbors=outlier_neighbors, std_ratio=outlier_std)
    if len(down.points) >= 3:
        radius = 4 * size if size > 0 else 0.0
        search = (o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30) if radius > 0
                  else o3d.geometry.KDTreeSearchParamKNN(30))
        hint = np.asarray(down.normals).copy() if down.has_normals() else None
        down.estimate_normals(search)
        if hint is not None:
            normals = np.asarray(down.normals)
            flip = np.sum(normals * hint, axis=1) < 0
            normals[flip] *= -1
            down.normals = o3d.utility.Vector3dVector(normals)
    return from_open3d(down), CleanReport(raw, size, after_voxel, len(down.points))


def write_ply(path, cloud: Cloud) -> None:
    """A binary PLY with colours (and normals when present), through Open3D."""
    o3d = open3d()

    if not o3d.io.write_point_cloud(str(path), to_open3d(cloud), write_ascii=False):
        raise OSError(f"open3d could not write {path}")


def read_ply(path) -> Cloud:
    o3d = open3d()

    return from_open3d(o3d.io.read_point_cloud(str(path)))


def transformed(cloud: Cloud, similarity: np.ndarray | Sequence[Sequence[float]]) -> Cloud:
    """The cloud under a 4x4 similarity such as bounds' ``to_sfm``: points by it, normals by its rotation."""
    move = Similarity.from_matrix(np.asarray(similarity))
    normals = None if cloud.normals is None else cloud.normals @ move.rotation.T
    return Cloud(move.apply_points(cloud.xyz), cloud.rgb, normals)
