"""How far the undistorted photos still are from pinhole: the lens evidence per camera."""

from __future__ import annotations

from typing import Any

from nerfpipe.geometry.cameras import CameraSet

# -- lens, photometry, exposure ---------------------------------------------------------------------------
LENS_PER_CAMERA_MAX = 3  # up to this many cameras the lens evidence names each one


def decide_lens(pinhole: CameraSet) -> tuple[str, str, dict[str, Any]]:
    """``undistorted`` when the undistort stage resampled any camera's images, else ``pinhole``; the evidence
    names each camera when there are at most ``LENS_PER_CAMERA_MAX``, else summarises them all."""
    record = pinhole.hints.undistortion or {}
    if not record:
        return "pinhole", "no undistortion record: the cameras were pinhole as given", {"cameras": {}}
    cameras = sorted(record.items(), key=lambda kv: str(kv[0]))
    done = sum(bool(info.get("undistorted")) for _, info in cameras)
    value = "undistorted" if done else "pinhole"
    if len(cameras) > LENS_PER_CAMERA_MAX:
        return value, _lens_summary([info.get("max_displacement_px", 0.0) for _, info in cameras], done), {"cameras": record}
    parts = []
    for camera_id, info in cameras:
        shift = info.get("max_displacement_px", 0.0)
        size = "beyond 90° off-axis (fisheye)" if shift is None else f"by up to {float(shift):.2f} px"
        parts.append(f"camera {camera_id}: distortion moves pixels {size}, "
                     f"{'undistorted' if info.get('undistorted') else 'left as is'}")
    return value, "; ".join(parts), {"cameras": record}


def _lens_summary(shifts: list[float | None], undistorted: int) -> str:
    """'71 cameras: distortion 0.2-29 px, 70 undistorted, 1 left as is' (None: a fisheye beyond 90°)."""
    finite = [float(s) for s in shifts if s is not None]
    beyond = len(shifts) - len(finite)
    spread = []
    if finite:
        lo, hi = _px(min(finite)), _px(max(finite))
        spread.append(f"distortion {lo} px" if lo == hi else f"distortion {lo}-{hi} px")
    if beyond:
        spread.append(f"{beyond} beyond 90° off-axis (fisheye)")
    left = len(shifts) - undistorted
    return f"{len(shifts)} cameras: {', '.join(spread)}, {undistorted} undistorted, {left} left as is"


def _px(value: float) -> str:
    """Two significant digits, never in exponent form: 0.2, 3.1, 29, 140."""
    return f"{value:.0f}" if value >= 10 else f"{value:.2g}"
