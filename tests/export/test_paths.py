"""Camera paths: orbits look at their target from one distance and height, upright; spirals stay within the
spread of a forward-facing rig and look at LLFF's focus point; the layout picks the path."""

from __future__ import annotations

import numpy as np
import pytest

from nerfpipe.export.paths import (
    focus_depth,
    orbit_of,
    orbit_path,
    path_for_scene,
    spiral_path,
    spiral_radii,
    sweep_of,
    sweep_path,
    transform_poses,
)
from nerfpipe.geometry.cameras import mean_camera
from tests.helpers import look_at


def rotation_about(axis: np.ndarray, degrees: float) -> np.ndarray:
    """(3, 3) Rodrigues rotation."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.radians(degrees)
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


def rigid(rotation: np.ndarray, translation) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


def ring(n: int = 12, radius: float = 2.0, height: float = 0.8) -> np.ndarray:
    """(n, 4, 4) cameras on a level circle (world z up) looking at the origin."""
    angles = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.stack([look_at(np.array([radius * np.cos(a), radius * np.sin(a), height]), np.zeros(3)) for a in angles])


def grid() -> np.ndarray:
    """(6, 4, 4) forward-facing cameras on a 3 x 2 grid in the plane y = -3, all looking along +y (world z up)."""
    return np.stack([look_at(np.array([x, -3.0, z]), np.array([x, 0.0, z])) for x in (-0.2, 0.0, 0.2) for z in (-0.1, 0.1)])


def assert_rotations(poses: np.ndarray) -> None:
    rotations = poses[:, :3, :3]
    assert np.allclose(rotations.transpose(0, 2, 1) @ rotations, np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(rotations), 1.0)
    assert np.allclose(poses[:, 3], [0, 0, 0, 1])


# -- orbit --------------------------------------------------------------------------------------------------
def test_orbit_by_hand_on_a_level_ring() -> None:
    """Ring at radius 2, height 0.8: distance sqrt(4 + 0.64) = 2.154, elevation atan(0.8 / 2) = 21.80 deg."""
    c2ws = ring()
    orbit = orbit_of(c2ws, np.zeros(3))
    assert np.allclose(orbit.up, [0, 0, 1])
    assert orbit.radius == pytest.approx(np.sqrt(4.64))
    assert orbit.elevation == pytest.approx(np.degrees(np.arctan(0.4)))
    poses = orbit_path(c2ws, np.zeros(3), 8)
    # the auto orbit of a level ring is the ring itself, starting at its first camera
    assert np.allclose(poses[0], c2ws[0], atol=1e-9)
    assert np.allclose(poses[:, 2, 3], 0.8) and np.allclose(np.linalg.norm(poses[:, :2, 3], axis=1), 2.0)
    # eight equal steps of 45 degrees, counter-clockwise seen from above (+z), closing the loop
    azimuth = np.degrees(np.arctan2(poses[:, 1, 3], poses[:, 0, 3]))
    assert np.allclose(np.diff(np.unwrap(np.radians(np.append(azimuth, azimuth[0] + 360.0)), period=2 * np.pi)),
                       np.radians(45.0))


@pytest.mark.parametrize("elevation", [None, 35.0, -20.0])
def test_orbit_invariants_on_a_tilted_rig(elevation) -> None:
    """Any rigid motion of the rig, with the world's up moved along: the orbit is about that up."""
    motion = rigid(rotation_about([1.0, -2.0, 0.5], 40.0), [0.3, -1.0, 2.0])
    rng = np.random.default_rng(0)
    # cameras at distances 1.5 .. 2.5 and heights 0.3 .. 1.2: the median distance is the radius
    eyes = [np.array([r * np.cos(a), r * np.sin(a), h]) for r, a, h in
            zip(rng.uniform(1.5, 2.5, 15), np.linspace(0, 2 * np.pi, 15, endpoint=False), rng.uniform(0.3, 1.2, 15))]
    c2ws = np.stack([motion @ look_at(e, np.zeros(3)) for e in eyes])
    target = motion[:3, 3]  # the world origin, moved
    up = motion[:3, 2]  # the world's z, moved
    assert np.allclose(orbit_of(c2ws, target, up=up).up, up)
    poses = orbit_path(c2ws, target, 24, elevation, up)

    assert poses.shape == (24, 4, 4)
    assert_rotations(poses)
    offsets = poses[:, :3, 3] - target
    distances = np.linalg.norm(offsets, axis=1)
    median = np.median([np.linalg.norm(e) for e in eyes])
    assert np.allclose(distances, median)
    heights = offsets @ up
    assert np.allclose(heights, heights[0])
    if elevation is not None:
        assert heights[0] == pytest.approx(median * np.sin(np.radians(elevation)))
    else:
        mean_elevation = np.mean([np.degrees(np.arcsin((c2w[:3, 3] - target) @ up / np.linalg.norm(e)))
                                  for c2w, e in zip(c2ws, eyes)])
        assert heights[0] == pytest.approx(median * np.sin(np.radians(mean_elevation)))
    # every camera's z axis points at the target
    assert np.allclose(poses[:, :3, 2], -offsets / distances[:, None])
    # upright: y (down in the image) has a negative component along up, and x is level
    assert np.all(poses[:, :3, 1] @ up < -0.1)
    assert np.allclose(poses[:, :3, 0] @ up, 0.0, atol=1e-9)


def test_orbit_rejects_a_pole_and_bad_input() -> None:
    with pytest.raises(ValueError, match="elevation"):
        orbit_path(ring(), np.zeros(3), 4, elevation=90.0)
    with pytest.raises(ValueError, match="n_frames"):
        orbit_path(ring(), np.zeros(3), 0)
    with pytest.raises(ValueError, match=r"\(M, 4, 4\)"):
        orbit_path(np.eye(4), np.zeros(3), 4)


# -- spiral -------------------------------------------------------------------------------------------------
def test_spiral_radii_and_focus_by_hand() -> None:
    # |x| over the grid: 0.2, 0.2, 0, 0, 0.2, 0.2 -> 90th percentile 0.2; |y| (world -z) all 0.1; z all 0
    assert np.allclose(spiral_radii(grid()), [0.2, 0.1, 0.0])
    assert focus_depth(1.0, 10.0) == pytest.approx(1.0 / (0.25 + 0.075))
    with pytest.raises(ValueError, match="near"):
        focus_depth(2.0, 1.0)


def test_spiral_stays_near_the_mean_camera_and_looks_at_the_focus() -> None:
    c2ws = grid()
    near, far = 1.0, 10.0
    poses = spiral_path(c2ws, near, far, 30, n_rotations=2)
    mean = mean_camera(c2ws)
    radii = spiral_radii(c2ws)
    assert poses.shape == (30, 4, 4)
    assert_rotations(poses)
    local = (poses[:, :3, 3] - mean[:3, 3]) @ mean[:3, :3]
    assert np.all(np.abs(local) <= radii + 1e-12)
    # the first frame is at theta 0: (r_x, 0, 0) in the mean camera's frame
    assert np.allclose(local[0], [0.2, 0.0, 0.0])
    # it spans the radii: the x and y extremes are reached over the turns
    assert np.abs(local[:, 0]).max() == pytest.approx(0.2) and np.abs(local[:, 1]).max() == pytest.approx(0.1, rel=0.02)
    focus = mean[:3, 3] + focus_depth(near, far) * mean[:3, 2]
    to_focus = focus - poses[:, :3, 3]
    assert np.allclose(poses[:, :3, 2], to_focus / np.linalg.norm(to_focus, axis=1, keepdims=True))
    # roughly the mean viewing axis (0.2 off-axis at depth 3.08: within 4 degrees) and the mean down axis
    assert np.all(poses[:, :3, 2] @ mean[:3, 2] > np.cos(np.radians(4.0)))
    assert np.all(poses[:, :3, 1] @ mean[:3, 1] > np.cos(np.radians(4.0)))
    assert np.allclose(poses[:, :3, 0] @ mean[:3, 1], 0.0, atol=1e-9)  # x is perpendicular to the kept down axis


def test_paths_move_with_the_rig() -> None:
    """Two routes to one path: the path of a moved rig equals the moved path of the rig."""
    motion = rigid(rotation_about([0.2, 1.0, -0.4], 70.0), [1.0, 2.0, -0.5])

    def moved(poses: np.ndarray) -> np.ndarray:
        return np.einsum("ij,njk->nik", motion, poses)

    assert np.allclose(spiral_path(moved(grid()), 1.0, 10.0, 12), moved(spiral_path(grid(), 1.0, 10.0, 12)))
    target = np.array([0.1, -0.2, 0.3])
    assert np.allclose(orbit_path(moved(ring()), motion[:3, :3] @ target + motion[:3, 3], 12, up=motion[:3, 2]),
                       moved(orbit_path(ring(), target, 12)))
    arc = ring(9)[:4]
    assert np.allclose(sweep_path(moved(arc), motion[:3, :3] @ target + motion[:3, 3], 12, up=motion[:3, 2]),
                       moved(sweep_path(arc, target, 12)))


# -- choosing and moving ----------------------------------------------------------------------------------
def test_path_for_scene_picks_per_layout() -> None:
    poses, text = path_for_scene("forward", grid(), 1.0, 10.0, np.zeros(3), 6)
    assert text.startswith("spiral (forward scene)") and np.allclose(poses, spiral_path(grid(), 1.0, 10.0, 6))
    for layout in ("inward360", "unbounded360"):
        poses, text = path_for_scene(layout, ring(), 0.5, 4.0, np.zeros(3), 6)
        assert text.startswith(f"orbit ({layout} scene, cameras all round: 330 deg of azimuth)")
        assert np.allclose(poses, orbit_path(ring(), np.zeros(3), 6))
        poses, text = path_for_scene(layout, ring()[:5], 0.5, 4.0, np.zeros(3), 6)  # 120 deg of the circle
        assert text.startswith(f"sweep ({layout} scene, cameras on 120 deg of azimuth)")
        assert np.allclose(poses, sweep_path(ring()[:5], np.zeros(3), 6))
    poses, text = path_for_scene("forward", grid(), 1.0, 10.0, np.zeros(3), 6, kind="orbit", elevation=10.0)
    assert text.startswith("orbit (asked for, forward scene)") and "10.0 deg elevation (given)" in text
    assert np.allclose(poses, orbit_path(grid(), np.zeros(3), 6, 10.0))
    with pytest.raises(ValueError, match="layout"):
        path_for_scene("sideways", grid(), 1.0, 10.0, np.zeros(3), 6)


def test_transform_poses_keeps_them_rigid() -> None:
    # to_sfm = 2 R + t: centres scale and move, rotations only rotate
    rotation = rotation_about([0.0, 0.0, 1.0], 90.0)
    similarity = rigid(2.0 * rotation, [1.0, 0.0, -1.0])
    poses = ring(4)
    out = transform_poses(poses, similarity)
    assert_rotations(out)
    assert np.allclose(out[:, :3, :3], rotation @ poses[:, :3, :3])
    assert np.allclose(out[:, :3, 3], 2.0 * poses[:, :3, 3] @ rotation.T + [1.0, 0.0, -1.0])
    back = rigid(rotation.T / 2.0, -rotation.T @ [1.0, 0.0, -1.0] / 2.0)
    assert np.allclose(transform_poses(out, back), poses)


# -- up, whatever the photos' roll ----------------------------------------------------------------------------
def rolled(c2ws: np.ndarray, degrees: float = 90.0) -> np.ndarray:
    """The same cameras, each turned about its own optical axis (a portrait photo of a landscape rig)."""
    roll = np.eye(4)
    roll[:3, :3] = rotation_about([0.0, 0.0, 1.0], degrees)
    return c2ws @ roll


def test_a_rolled_capture_orbits_the_same_level_circle() -> None:
    # every photo turned 90 deg (the Middlebury temple's are): the cameras' mean "up" axis is then horizontal,
    # but the world's up is still z, so the orbit is the same circle at the cameras' height
    c2ws = ring(16, radius=2.0, height=0.9)
    poses = orbit_path(rolled(c2ws), np.zeros(3), 20)
    assert np.allclose(poses, orbit_path(c2ws, np.zeros(3), 20))
    assert np.allclose(poses[:, 2, 3], 0.9) and np.all(poses[:, :3, 1] @ [0, 0, 1] < 0)  # level and upright


def test_a_sweep_stays_where_the_photos_were_and_looks_at_their_focus() -> None:
    # a phone walked over a third of a circle around an object at (0.2, 0.1, 0), at distances 1.6 .. 2.4 and
    # heights 0.5 .. 0.9, every photo aimed at the object
    rng = np.random.default_rng(1)
    focus = np.array([0.2, 0.1, 0.0])
    angles = np.radians(np.linspace(-60.0, 60.0, 25))
    eyes = [focus + np.array([r * np.cos(a), r * np.sin(a), h]) for a, r, h in
            zip(angles, rng.uniform(1.6, 2.4, 25), rng.uniform(0.5, 0.9, 25))]
    c2ws = rolled(np.stack([look_at(e, focus) for e in eyes]), 90.0)
    poses, text = path_for_scene("inward360", c2ws, 0.5, 5.0, np.zeros(3), 40)
    assert text.startswith("sweep (inward360 scene, cameras on 111 deg of azimuth)")  # about the box centre
    assert "looking at (0.2, 0.1, " in text  # where the optical axes converge, not the box centre
    assert_rotations(poses)
    offsets = poses[:, :3, 3] - focus
    azimuth = np.degrees(np.arctan2(offsets[:, 1], offsets[:, 0]))
    assert azimuth.min() >= -60.0 and azimuth.max() <= 60.0  # within the photos' arc ...
    assert azimuth.max() - azimuth.min() > 90.0  # ... and most of it
    assert azimuth[0] == pytest.approx(azimuth.min()) and azimuth[20] == pytest.approx(azimuth.max())  # out and back
    horizontal = np.linalg.norm(offsets[:, :2], axis=1)
    assert np.all((horizontal >= 1.6 - 1e-9) & (horizontal <= 2.4 + 1e-9))
    assert np.all((offsets[:, 2] >= 0.5 - 1e-9) & (offsets[:, 2] <= 0.9 + 1e-9))
    to_focus = -offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    assert np.allclose(poses[:, :3, 2], to_focus)  # looking at the focus
    assert np.all(poses[:, :3, 1] @ [0, 0, 1] < 0) and np.allclose(poses[:, :3, 0] @ [0, 0, 1], 0.0, atol=1e-9)
    with pytest.raises(ValueError, match="all round"):
        sweep_of(ring(), np.zeros(3))


@pytest.mark.slow
def test_the_demo_orbit_stays_at_the_height_of_its_cameras(tmp_path) -> None:
    """The bundled temple through the bounds stage: its photos are rolled 90 deg, and the orbit the render
    stage builds stays within the training cameras' heights, +- 0.3 ring radii."""
    from nerfpipe import Pipeline, default_stages
    from nerfpipe.artifacts import Bounds
    from nerfpipe.geometry.cameras import CameraSet
    from tests.helpers import TEMPLE

    pipe = Pipeline(default_stages(), TEMPLE, tmp_path / "run")
    pipe.run(until="bounds")
    world = CameraSet.load(pipe.artifact("world"))
    bounds = Bounds.load(pipe.artifact("bounds"))
    c2ws = np.array([f.c2w for f in world.frames])
    lo, hi = bounds.box()
    poses, text = path_for_scene("inward360", c2ws, bounds.near, bounds.far, (lo + hi) / 2, 40)
    assert text.startswith("orbit (inward360 scene, cameras all round")
    heights, ring_radius = c2ws[:, 2, 3], np.median(np.linalg.norm(c2ws[:, :2, 3] - (lo + hi)[:2] / 2, axis=1))
    assert np.all(poses[:, 2, 3] >= heights.min() - 0.3 * ring_radius)
    assert np.all(poses[:, 2, 3] <= heights.max() + 0.3 * ring_radius)
    assert np.all(poses[:, :3, 1] @ [0, 0, 1] < 0)  # upright


def test_a_walk_three_quarters_round_sweeps_rather_than_orbit_through_its_gap() -> None:
    # 19 cameras on 270 deg of azimuth, as the cup's photos cover: an orbit would spend 90 deg of its turn
    # where no photo was taken, so the path sweeps along the cameras and never enters the gap
    eyes = [np.array([2 * np.cos(a), 2 * np.sin(a), 0.5]) for a in np.radians(np.arange(0.0, 271.0, 15.0))]
    c2ws = np.stack([look_at(e, np.zeros(3)) for e in eyes])
    poses, text = path_for_scene("inward360", c2ws, 0.5, 5.0, np.zeros(3), 12)
    assert text.startswith("sweep (inward360 scene, cameras on 270 deg of azimuth)"), text
    azimuth = np.degrees(np.arctan2(poses[:, 1, 3], poses[:, 0, 3])) % 360.0
    assert np.all(azimuth <= 270.0 + 1e-6), azimuth.round(1)  # none in the gap from 270 to 360 deg
    assert_rotations(poses)


def test_a_walk_with_one_wide_gap_sweeps_and_never_enters_it() -> None:
    # seven cameras round the centre with a 105 deg gap (coverage 255 < 300), their mean direction from it
    # only 0.17 long: framed on the gap rather than on that mean, the sweep stays on the photos' side of it
    eyes = [np.array([2 * np.cos(a), 2 * np.sin(a), 0.5]) for a in np.radians([0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 255.0])]
    c2ws = np.stack([look_at(e, np.zeros(3)) for e in eyes])
    poses, text = path_for_scene("inward360", c2ws, 0.5, 5.0, np.zeros(3), 8)
    assert text.startswith("sweep (inward360 scene, cameras on 255 deg of azimuth)"), text
    azimuth = np.degrees(np.arctan2(poses[:, 1, 3], poses[:, 0, 3])) % 360.0
    assert np.all(azimuth <= 255.0 + 1e-6), azimuth.round(1)
    assert_rotations(poses)


def test_a_walk_290_degrees_round_across_zero_sweeps_out_of_its_gap() -> None:
    # 30 cameras every 10 deg from 200 deg on round past 0 to 130 deg: coverage 290 < 300, yet their mean
    # direction is 0.24 long, short enough that a test on it would have called them all round; the gap from
    # 130 to 200 deg is 7 times the others, and the sweep keeps to the photos' side of it
    eyes = [np.array([2 * np.cos(a), 2 * np.sin(a), 0.5]) for a in np.radians(200.0 + np.arange(30) * 10.0)]
    c2ws = np.stack([look_at(e, np.zeros(3)) for e in eyes])
    poses, text = path_for_scene("inward360", c2ws, 0.5, 5.0, np.zeros(3), 20)
    assert text.startswith("sweep (inward360 scene, cameras on 290 deg of azimuth)"), text
    azimuth = np.degrees(np.arctan2(poses[:, 1, 3], poses[:, 0, 3])) % 360.0
    assert not np.any((azimuth > 130.0 + 1e-6) & (azimuth < 200.0 - 1e-6)), azimuth.round(1)
    assert np.ptp((azimuth - 345.0 + 180.0) % 360.0) > 200.0  # most of the 290 deg, centred on 345 deg
    assert_rotations(poses)


def test_a_few_cameras_evenly_all_round_orbit() -> None:
    # five cameras 72 deg apart: coverage 288 < 300, but no gap stands out from the others, so no side of the
    # object is the one the photos missed: an orbit, not a sweep, and no error
    eyes = [np.array([2 * np.cos(a), 2 * np.sin(a), 0.5]) for a in np.radians(np.arange(5) * 72.0 + 10.0)]
    c2ws = np.stack([look_at(e, np.zeros(3)) for e in eyes])
    poses, text = path_for_scene("inward360", c2ws, 0.5, 5.0, np.zeros(3), 8)
    assert text.startswith("orbit (inward360 scene, cameras on 288 deg of azimuth but all round the centre)"), text
    assert_rotations(poses)


def test_the_sweep_centres_opposite_the_largest_gap() -> None:
    # by hand: cameras at 0, 90 and 180 deg; the gap 180 .. 360 is the largest, its middle at 270, so the
    # sweep's azimuths count from 90 deg and run from -90 to +90
    eyes = [np.array([2 * np.cos(a), 2 * np.sin(a), 0.0]) for a in np.radians([0.0, 90.0, 180.0])]
    sweep = sweep_of(np.stack([look_at(e, np.zeros(3)) for e in eyes]), np.zeros(3), spread=0.0)
    assert np.allclose(sweep.e1, [0.0, 1.0, 0.0], atol=1e-9)
    assert sweep.lo == pytest.approx(-np.pi / 2) and sweep.hi == pytest.approx(np.pi / 2)
