"""Whether a capture is forward-facing, inward 360 or unbounded, from its cameras and bounds."""

from __future__ import annotations

from typing import Any

import numpy as np

from nerfpipe.artifacts import Bounds
from nerfpipe.geometry.cameras import CameraSet
from nerfpipe.geometry.rig import axis_angles_to, azimuth_coverage, look_at_center, viewing_spread


# -- layout ----------------------------------------------------------------------------------------------
def decide_layout(world: CameraSet, bounds: Bounds, params: Any) -> tuple[str, str, dict[str, Any]]:
    """(value, evidence, measured) for the layout, from the normalized rig, its points and the near/far bounds."""
    c2ws = np.array([f.c2w for f in world.frames])
    centers = c2ws[:, :3, 3]
    mean_dir, angles = viewing_spread(c2ws)
    nears = np.array([f.near for f in bounds.frames])
    fars = np.array([f.far for f in bounds.frames])
    median_near = float(np.median(nears))
    advance = float(np.ptp(centers @ mean_dir)) if len(centers) > 1 else 0.0
    far_near = float(np.median(fars / np.maximum(nears, 1e-12)))
    measured: dict[str, Any] = {
        "cameras": len(c2ws),
        "max_angle_to_mean_deg": round(float(angles.max()), 2),
        "median_angle_to_mean_deg": round(float(np.median(angles)), 2),
        "advance_along_mean": round(advance, 4),
        "median_near": round(median_near, 4),
        "median_far_near_ratio": round(far_near, 3),
        "bounds_method": bounds.method,
    }
    spread = (
        f"viewing directions lie within {angles.max():.0f}° of their mean (median {np.median(angles):.0f}°), "
        f"camera centres spread {advance:.2f} along it vs a median near depth of {median_near:.2f}"
    )
    if angles.max() < params.forward_max_angle_deg and advance <= params.forward_max_advance * median_near:
        return "forward", f"all cameras face one way: {spread}; rays use NDC", measured

    center = look_at_center(c2ws)
    to_center = axis_angles_to(c2ws, center)
    ring = float(np.median(np.linalg.norm(centers - center, axis=1)))
    coverage = azimuth_coverage(c2ws, center)
    measured.update(
        median_axis_to_center_deg=round(float(np.median(to_center)), 2),
        ring_radius=round(ring, 4),
        azimuth_coverage_deg=round(coverage, 1),
    )
    if np.median(to_center) >= params.converge_max_angle_deg:
        return (
            "unbounded360",
            f"cameras do not share a viewing direction ({spread}) nor look at a common centre "
            f"(median {np.median(to_center):.0f}° off it); unbounded space is contracted",
            measured,
        )
    surround = (
        f"cameras look at a common centre (median {np.median(to_center):.1f}° off it) from {ring:.2f} away, "
        f"covering {coverage:.0f}° of azimuth, viewing directions up to {angles.max():.0f}° apart from their mean"
    )
    if world.points is not None and len(world.points.xyz):
        outside = float(np.mean(np.linalg.norm(world.points.xyz - center, axis=1) > ring))
        measured["points_outside_ring"] = round(outside, 4)
        content = f"{100 * outside:.1f}% of the {len(world.points.xyz)} sparse points lie farther out than the cameras"
    else:
        outside = 0.0
        content = "no sparse points (near/far from the rig)"
    content += f", median far/near {far_near:.1f}"
    if outside > params.unbounded_outside_fraction or far_near >= params.unbounded_far_near_ratio:
        return "unbounded360", f"{surround}, but the scene extends beyond them: {content}; unbounded space is contracted", measured
    return "inward360", f"{surround}; {content}; a bounded box", measured
