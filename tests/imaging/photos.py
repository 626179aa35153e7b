"""Photo files for the tests, written with Pillow: JPEG, PNG and TIFF carrying the EXIF a test asks for.

Pillow writes the EXIF (``Image.Exif``, with its Exif and GPS IFDs) and the files; nerfpipe reads them with
ExifRead, an independent implementation. Two camera RAW containers Pillow cannot write are wrapped around
Pillow's output here, in their documented layouts: a Fujifilm RAF is a header pointing at a full JPEG, and a
Canon CR3 keeps IFD0, the Exif IFD and the GPS IFD as TIFF structures in boxes of an ISO base-media file.

Arrays are RGB(A) as Pillow takes them (OpenCV's BGR arrays need ``[..., ::-1]`` first).
"""

from __future__ import annotations

import io
import struct
from fractions import Fraction
from typing import Any

import numpy as np
from PIL import Image, TiffImagePlugin

EXIF_IFD = 0x8769
GPS_IFD = 0x8825
CR3_CANON_UUID = bytes.fromhex("85c0b687820f11e08111f4ce462b6a48")


def _value(value: Any) -> Any:
    """A Fraction as the RATIONAL Pillow writes exactly (a float would be approximated)."""
    if isinstance(value, Fraction):
        return TiffImagePlugin.IFDRational(value.numerator, value.denominator)
    if isinstance(value, tuple):
        return tuple(_value(part) for part in value)
    return value


def exif(
    ifd0: dict[int, Any] | None = None,
    photo: dict[int, Any] | None = None,
    gps: dict[int, Any] | None = None,
    byte_order: str = "<",
) -> Image.Exif:
    """EXIF with these tags in IFD0, the Exif IFD and the GPS IFD: ``{tag: value}``.

    Values: ``str`` (ASCII), ``int`` (SHORT or LONG by Pillow's tag table), ``Fraction`` (RATIONAL), ``bytes``
    (BYTE / UNDEFINED), or a tuple of those.
    """
    data = Image.Exif()
    data.endian = byte_order
    for tag, value in (ifd0 or {}).items():
        data[tag] = _value(value)
    for pointer, tags in ((EXIF_IFD, photo), (GPS_IFD, gps)):
        if tags:
            ifd = data.get_ifd(pointer)
            for tag, value in tags.items():
                ifd[tag] = _value(value)
    return data


def orientation(value: int) -> Image.Exif:
    """EXIF holding only an Orientation tag."""
    return exif({0x0112: value})


def tiff_structure(data: Image.Exif) -> bytes:
    """The EXIF as a bare TIFF structure (what follows ``Exif\\0\\0`` in a JPEG)."""
    raw = data.tobytes()
    return raw[6:] if raw.startswith(b"Exif\x00\x00") else raw


def _save(pixels: np.ndarray, format_name: str, **options: Any) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(pixels)).save(buffer, format_name, **options)
    return buffer.getvalue()


def jpeg(rgb: np.ndarray, data: Image.Exif | None = None, quality: int = 95, progressive: bool = False) -> bytes:
    """A JPEG of an (H, W, 3) uint8 RGB array, with ``data`` as its EXIF."""
    options: dict[str, Any] = {"quality": quality, "progressive": progressive}
    if data is not None:
        # As bytes: Pillow skips an Exif object whose IFD0 is empty, even when its Exif IFD is not.
        options["exif"] = data.tobytes()
    return _save(rgb, "JPEG", **options)


def png(pixels: np.ndarray, data: Image.Exif | None = None) -> bytes:
    """A PNG of an (H, W), (H, W, 2 grey+alpha), (H, W, 3) or (H, W, 4) uint8 array, EXIF in an ``eXIf`` chunk."""
    return _save(pixels, "PNG", **({"exif": data.tobytes()} if data is not None else {}))


def tiff(rgb: np.ndarray, data: Image.Exif | None = None) -> bytes:
    """An uncompressed RGB TIFF; ``data``'s IFD0 tags join the image's own directory, which comes first."""
    return _save(rgb, "TIFF", **({"exif": data} if data is not None else {}))


def raf(embedded_jpeg: bytes) -> bytes:
    """A Fujifilm RAF: its 84-byte header, the JPEG's offset and length at byte 84, then the JPEG."""
    header = b"FUJIFILMCCD-RAW 0201FF383501".ljust(84, b"\x00")
    offset = len(header) + 16
    return header + struct.pack(">IIII", offset, len(embedded_jpeg), 0, 0) + embedded_jpeg


def _box(box_type: bytes, payload: bytes) -> bytes:
    return struct.pack(">I", 8 + len(payload)) + box_type + payload


def cr3(ifd0: Image.Exif, photo: Image.Exif | None = None, gps: Image.Exif | None = None) -> bytes:
    """A Canon CR3 skeleton: ``ftyp crx``, then ``moov`` holding Canon's ``uuid`` box with CMT1, CMT2, CMT4.

    Each CMT box is a TIFF whose IFD0 holds that IFD's tags (so ``photo`` and ``gps`` pass their tags as IFD0).
    """
    boxes = _box(b"CMT1", tiff_structure(ifd0))
    if photo is not None:
        boxes += _box(b"CMT2", tiff_structure(photo))
    if gps is not None:
        boxes += _box(b"CMT4", tiff_structure(gps))
    canon = _box(b"uuid", CR3_CANON_UUID + _box(b"CNCV", b"CanonCR3_001/00.09.00/00.00.00") + boxes)
    return _box(b"ftyp", b"crx \x00\x00\x00\x01crx isom") + _box(b"moov", canon) + _box(b"mdat", bytes(64))
