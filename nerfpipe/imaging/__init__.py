"""Photo input for nerfpipe: read EXIF, check files are whole, and decode JPEG / PNG / TIFF / camera RAW.

``read_photo`` is the one entry point the stages need; ``read_exif`` and ``focal_prior_px`` give the metadata
and the focal-length prior for structure-from-motion; the extension sets and ``photo_kind`` /
``unsupported_advice`` let a folder scan sort photos from sidecars and explain everything else.
"""

from nerfpipe.imaging.decode import (
    IMAGE_EXTENSIONS,
    RAW_EXTENSIONS,
    SIDECAR_EXTENSIONS,
    PhotoHeader,
    apply_orientation,
    photo_kind,
    read_header,
    read_photo,
    unsupported_advice,
)
from nerfpipe.imaging.exif import ExifSummary, focal_prior_px, read_exif
from nerfpipe.imaging.photo import DecodedPhoto, PhotoSizeError, RawOptions, SizeLimits
from nerfpipe.imaging.integrity import check_integrity, sniff_container

__all__ = [
    "IMAGE_EXTENSIONS",
    "RAW_EXTENSIONS",
    "SIDECAR_EXTENSIONS",
    "DecodedPhoto",
    "ExifSummary",
    "PhotoHeader",
    "PhotoSizeError",
    "RawOptions",
    "SizeLimits",
    "apply_orientation",
    "check_integrity",
    "focal_prior_px",
    "photo_kind",
    "read_exif",
    "read_header",
    "read_photo",
    "sniff_container",
    "unsupported_advice",
]
