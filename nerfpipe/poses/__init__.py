"""Where a capture's photos and poses are: layout detection and the pose-file importers."""

from nerfpipe.poses.layout import CaptureLayout, detect_layout, resolve_inside

__all__ = ["CaptureLayout", "detect_layout", "resolve_inside"]
