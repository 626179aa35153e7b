"""Camera rays (Section 4), NDC rays (the paper's Appendix C) and ray/box intersection."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from nerfpipe.nerf.spaces.rays import camera_rays, intersect_box, ndc_rays, pixel_centers

K = torch.tensor([100.0, 100.0, 50.0, 50.0])  # fx, fy, cx, cy


def t64(values) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float64)


def rotation_z(angle: float) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    return t64([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose(rotation: torch.Tensor, translation) -> torch.Tensor:
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:3, :3] = rotation
    c2w[:3, 3] = t64(translation)
    return c2w


# --- camera rays -------------------------------------------------------------------------------------


def test_pixel_centers_row_major_half_offsets():
    # width 2, height 2: (0.5, 0.5), (1.5, 0.5), (0.5, 1.5), (1.5, 1.5).
    uv = pixel_centers(2, 2)
    assert torch.equal(uv, torch.tensor([[0.5, 0.5], [1.5, 0.5], [0.5, 1.5], [1.5, 1.5]]))


def test_camera_rays_identity_pose():
    # (u - cx) / fx, (v - cy) / fy, 1: (50, 50) -> (0, 0, 1); (150, 50) -> (1, 0, 1); (50, 0) -> (0, -0.5, 1).
    uv = torch.tensor([[50.0, 50.0], [150.0, 50.0], [50.0, 0.0]])
    origins, directions = camera_rays(uv, K, torch.eye(4))
    assert torch.equal(directions, torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, -0.5, 1.0]]))
    assert torch.equal(origins, torch.zeros(3, 3))


def test_camera_rays_with_pixel_centres_of_a_100px_image():
    # the centre pixel (column 49, row 49) of a 100 x 100 image is at (49.5, 49.5): direction (-0.005, -0.005, 1).
    uv = pixel_centers(100, 100)[49 * 100 + 49].unsqueeze(0)
    _, d = camera_rays(uv, K, torch.eye(4))
    assert torch.allclose(d, torch.tensor([[-0.005, -0.005, 1.0]]), rtol=0, atol=1e-7)


def test_camera_rays_rotated_and_translated():
    # R rotates 90 degrees about z: x -> y, y -> -x. Camera direction (1, 0, 1) -> (0, 1, 1);
    # (0, 0, 1) stays (0, 0, 1); the origin is the translation (1, 2, 3).
    c2w = pose(rotation_z(math.pi / 2), [1.0, 2.0, 3.0])
    uv = t64([[150.0, 50.0], [50.0, 50.0], [50.0, 150.0]])
    origins, directions = camera_rays(uv, K.double(), c2w)
    # (0, 1, 1) camera -> (-1, 0, 1) world
    assert torch.allclose(directions, t64([[0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 1.0]]), rtol=0, atol=1e-15)
    assert torch.equal(origins, t64([[1.0, 2.0, 3.0]] * 3))


def test_camera_rays_accepts_3x4_pose():
    c2w = pose(rotation_z(0.3), [1.0, -2.0, 0.5])
    uv = t64([[10.0, 80.0]])
    full, top = camera_rays(uv, K.double(), c2w), camera_rays(uv, K.double(), c2w[:3])
    assert torch.equal(full[0], top[0]) and torch.equal(full[1], top[1])


def test_camera_rays_batched_poses_equal_single_pose_path():
    g = torch.Generator().manual_seed(0)
    uv = torch.rand(5, 2, generator=g, dtype=torch.float64) * 100
    intrinsics = t64([[100.0, 120.0, 50.0, 40.0]]) + torch.rand(5, 4, generator=g, dtype=torch.float64)
    rotations = torch.linalg.qr(torch.randn(5, 3, 3, generator=g, dtype=torch.float64)).Q
    poses = torch.stack([pose(rotations[i], [i, -i, 2.0 * i]) for i in range(5)])
    origins, directions = camera_rays(uv, intrinsics, poses)
    for i in range(5):
        o_i, d_i = camera_rays(uv[i : i + 1], intrinsics[i], poses[i])
        assert torch.allclose(origins[i], o_i[0], rtol=0, atol=1e-14)
        assert torch.allclose(directions[i], d_i[0], rtol=0, atol=1e-14)
    # (R, 3, 4) too
    o34, d34 = camera_rays(uv, intrinsics, poses[:, :3])
    assert torch.equal(o34, origins) and torch.equal(d34, directions)


def test_camera_rays_have_unit_camera_z():
    # t is depth along the optical axis: the direction's component along the camera's z axis is 1.
    g = torch.Generator().manual_seed(1)
    c2w = pose(torch.linalg.qr(torch.randn(3, 3, generator=g, dtype=torch.float64)).Q, [0, 0, 0])
    _, d = camera_rays(t64([[3.0, 97.0], [60.0, 12.0]]), K.double(), c2w)
    assert torch.allclose(d @ c2w[:3, 2], t64([1.0, 1.0]), rtol=0, atol=1e-14)


# --- NDC ---------------------------------------------------------------------------------------------


def ndc_project(points: torch.Tensor, focal: float, width: int, height: int, near: float) -> torch.Tensor:
    """The perspective projection NDC space is built from: (-f/(W/2) x/z, -f/(H/2) y/z, 1 + 2 near / z)."""
    x, y, z = points.unbind(-1)
    return torch.stack([-focal / (width / 2) * x / z, -focal / (height / 2) * y / z, 1 + 2 * near / z], -1)


def test_ndc_optical_axis():
    # o = 0, d = (0, 0, -1), near 1: moved to z = -1, o' = (0, 0, 1 + 2/(-1)) = (0, 0, -1), d' = (0, 0, 2).
    o, d = ndc_rays(t64([[0.0, 0.0, 0.0]]), t64([[0.0, 0.0, -1.0]]), focal=50.0, width=100, height=80, near=1.0)
    assert torch.allclose(o, t64([[0.0, 0.0, -1.0]]), rtol=0, atol=1e-15)
    assert torch.allclose(d, t64([[0.0, 0.0, 2.0]]), rtol=0, atol=1e-15)
    # t' = 1 is z = 1 + 2/z -> 1 as z -> -inf: infinity
    far_point = ndc_project(t64([[0.0, 0.0, -1e12]]), 50.0, 100, 80, 1.0)
    assert torch.allclose(o + d, far_point, rtol=0, atol=1e-11)


def test_ndc_off_axis_by_hand():
    # o = (1, 2, 0), d = (0.5, -0.25, -1), near 1, f 100, W 200, H 100: ax = -1, ay = -2.
    # moved by t = 1 to o = (1.5, 1.75, -1):
    # o' = (-1 * 1.5 / -1, -2 * 1.75 / -1, 1 + 2 / -1) = (1.5, 3.5, -1)
    # d' = (-1 (0.5/-1 - 1.5/-1), -2 (-0.25/-1 - 1.75/-1), -2 / -1) = (-1, -4, 2)
    o, d = ndc_rays(t64([[1.0, 2.0, 0.0]]), t64([[0.5, -0.25, -1.0]]), focal=100.0, width=200, height=100)
    assert torch.allclose(o, t64([[1.5, 3.5, -1.0]]), rtol=0, atol=1e-14)
    assert torch.allclose(d, t64([[-1.0, -4.0, 2.0]]), rtol=0, atol=1e-14)


@settings(max_examples=30, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
    st.lists(st.floats(-0.8, 0.8), min_size=2, max_size=2),
    st.floats(0.5, 2.0),
)
def test_ndc_ray_passes_through_projected_points(origin, dxy, near):
    # Two routes: project points o + t d of the world ray, and walk the NDC ray; the projected points lie on it.
    origins = t64([origin])
    directions = t64([[dxy[0], dxy[1], -1.0]])
    focal, width, height = 80.0, 120, 90
    o, d = ndc_rays(origins, directions, focal, width, height, near=near)
    t_plane = near + origins[0, 2].item()  # where the world ray (dz = -1) crosses z = -near
    for t in (t_plane, t_plane + 0.5, t_plane + 3.0, t_plane + 100.0):
        p = ndc_project(origins + t * directions, focal, width, height, near)
        t_ndc = (p[0, 2] - o[0, 2]) / d[0, 2]
        assert 0.0 <= t_ndc.item() < 1.0
        assert torch.allclose(o + t_ndc * d, p, rtol=0, atol=1e-9)


# --- box intersection --------------------------------------------------------------------------------

BOX_MIN, BOX_MAX = t64([0.0, 0.0, 0.0]), t64([1.0, 1.0, 1.0])


def test_box_hits_by_hand():
    origins = t64([[-1.0, 0.5, 0.5], [-1.0, -1.0, -1.0], [0.5, 0.5, 0.5], [2.0, 0.5, 0.5]])
    directions = t64([[1.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 0.0], [-2.0, 0.0, 0.0]])
    # along +x from x = -1: enters at x = 0 (t 1), leaves at x = 1 (t 2)
    # along the diagonal from (-1, -1, -1): t 1 to 2
    # from the centre: t -0.5 to 0.5 (entry behind the origin)
    # along -x at speed 2 from x = 2: x = 1 at t 0.5, x = 0 at t 1
    t_enter, t_exit = intersect_box(origins, directions, BOX_MIN, BOX_MAX)
    assert torch.allclose(t_enter, t64([1.0, 1.0, -0.5, 0.5]), rtol=0, atol=1e-12)
    assert torch.allclose(t_exit, t64([2.0, 2.0, 0.5, 1.0]), rtol=0, atol=1e-12)


def test_box_misses():
    # parallel to x at y = 2, outside the y slab; and an oblique ray that passes the corner (1, 1) by.
    origins = t64([[-1.0, 2.0, 0.5], [-1.0, 1.5, 0.5]])
    directions = t64([[1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    t_enter, t_exit = intersect_box(origins, directions, BOX_MIN, BOX_MAX)
    assert torch.isfinite(t_enter).all() and torch.isfinite(t_exit).all()
    assert (t_enter >= t_exit).all()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_box_zero_direction_components_no_nan(dtype):
    origins = torch.tensor([[0.5, 0.5, -3.0], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5]], dtype=dtype)
    directions = torch.tensor([[0.0, 0.0, 1.0], [0.0, -0.0, 1.0], [0.0, 0.0, 0.0]], dtype=dtype)
    t_enter, t_exit = intersect_box(origins, directions, BOX_MIN.to(dtype), BOX_MAX.to(dtype))
    assert not torch.isnan(t_enter).any() and not torch.isnan(t_exit).any()
    # along +z from z = -3: t 3 to 4; from the centre: -0.5 to 0.5
    assert torch.allclose(t_enter[:2], torch.tensor([3.0, -0.5], dtype=dtype))
    assert torch.allclose(t_exit[:2], torch.tensor([4.0, 0.5], dtype=dtype))
    # a zero direction inside the box: "inside" for every t
    assert t_enter[2] < 0 < t_exit[2]
