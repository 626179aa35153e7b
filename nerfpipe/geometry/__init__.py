"""Camera geometry shared by the stages: camera models, poses, and their files on disk (numpy only)."""

from nerfpipe.geometry.cameras import CAMERA_MODELS, Camera, CameraSet, Frame, Points

__all__ = ["CAMERA_MODELS", "Camera", "CameraSet", "Frame", "Points"]
