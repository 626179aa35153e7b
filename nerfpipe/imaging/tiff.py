"""Bounds-checked walking of TIFF image file directories (IFDs), for the truncation check of TIFF and RAW files.

EXIF is read with ExifRead and pixels are decoded by libtiff (through OpenCV) or LibRaw; none of them says
whether a file was cut short: libtiff fills missing strips with zeros and only warns, ExifRead reads a missing
value as 0. This module answers exactly that question: which IFDs, tags and strips lie inside the buffer.

The bytes are untrusted: every offset is checked against the buffer, entry counts are capped, and IFD chains are
followed with cycle protection. A garbled file therefore yields fewer entries (or ``None``), never an exception
or a runaway loop.

Layout (TIFF 6.0, section 2): an 8-byte header (``II*\\0`` little-endian or ``MM\\0*`` big-endian, then the
offset of the first IFD); an IFD is a 2-byte entry count, 12-byte entries (tag, type, count, value-or-offset)
and the 4-byte offset of the next IFD (0 ends the chain). A value that fits in 4 bytes is stored inline.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

TIFF_LITTLE_ENDIAN_MAGIC = b"II*\x00"
TIFF_BIG_ENDIAN_MAGIC = b"MM\x00*"

# Bytes per value for each TIFF field type (TIFF 6.0 section 2, plus type 13 IFD from the TIFF tech note 1).
_TYPE_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 13: 4}
# BYTE, SHORT, LONG, SBYTE, SSHORT, SLONG, IFD: the types an offset or a count may be stored as (struct codes).
_INTEGER_CODES = {1: "B", 3: "H", 4: "I", 6: "b", 8: "h", 9: "i", 13: "I"}

# Real IFDs hold tens to a few hundred entries; a larger count means we are reading garbage.
MAX_IFD_ENTRIES = 1000
# Enough for the tile offsets of any real RAW (a 100 MP DNG in 256x256 tiles has ~1,500), bounded for memory.
MAX_VALUES = 1 << 22


@dataclass(frozen=True)
class TiffView:
    """A TIFF byte buffer with its byte order (``"<"`` or ``">"``) and the offset of its first IFD.

    Offsets inside a TIFF are relative to the start of its header, so ``data`` must begin at the header
    (for EXIF in a JPEG that is just after ``Exif\\0\\0``).
    """

    data: bytes
    byte_order: str
    first_ifd_offset: int


@dataclass(frozen=True)
class TiffEntry:
    """One IFD entry; ``value_offset`` is where its value bytes start in the buffer (inline or pointed to)."""

    tag: int
    type: int
    count: int
    value_offset: int

    @property
    def nbytes(self) -> int:
        """Size of the value in bytes (0 for an unknown field type)."""
        return _TYPE_SIZES.get(self.type, 0) * self.count


@dataclass(frozen=True)
class Ifd:
    """One image file directory: its position, its entries by tag and the offset of the next IFD (0: none)."""

    offset: int
    entries: dict[int, TiffEntry]
    next_offset: int


def open_tiff(data: bytes) -> TiffView | None:
    """Read the 8-byte TIFF header; ``None`` if ``data`` does not start with a classic TIFF header.

    BigTIFF (magic 43) is not handled: it uses 8-byte offsets and is not used for EXIF or camera RAW.
    """
    if len(data) < 8:
        return None
    magic = data[:4]
    if magic == TIFF_LITTLE_ENDIAN_MAGIC:
        byte_order = "<"
    elif magic == TIFF_BIG_ENDIAN_MAGIC:
        byte_order = ">"
    else:
        return None
    (first_ifd_offset,) = struct.unpack_from(byte_order + "I", data, 4)
    return TiffView(data=data, byte_order=byte_order, first_ifd_offset=first_ifd_offset)


def read_ifd(tiff: TiffView, offset: int) -> Ifd | None:
    """Read the IFD at ``offset``; ``None`` if its entry table does not lie wholly inside the buffer.

    Entries with an unknown type or whose value lies (partly) outside the buffer are kept: ``entry_ints``
    answers ``None`` for those, and the truncation check needs to see them.
    """
    data, order = tiff.data, tiff.byte_order
    # Offset 0 and offsets inside the header are never valid IFD positions.
    if offset < 8 or offset + 2 > len(data):
        return None
    (count,) = struct.unpack_from(order + "H", data, offset)
    table_end = offset + 2 + 12 * count
    if count > MAX_IFD_ENTRIES or table_end + 4 > len(data):
        return None
    entries: dict[int, TiffEntry] = {}
    for position in range(offset + 2, table_end, 12):
        tag, field_type, value_count = struct.unpack_from(order + "HHI", data, position)
        nbytes = _TYPE_SIZES.get(field_type, 0) * value_count
        if nbytes <= 4:
            value_offset = position + 8
        else:
            (value_offset,) = struct.unpack_from(order + "I", data, position + 8)
        # The first occurrence of a tag wins, as in libtiff.
        entries.setdefault(tag, TiffEntry(tag, field_type, value_count, value_offset))
    (next_offset,) = struct.unpack_from(order + "I", data, table_end)
    return Ifd(offset=offset, entries=entries, next_offset=next_offset)


def ifd_runs_past_end(tiff: TiffView, offset: int) -> bool:
    """Whether the IFD at ``offset`` (its count, entry table or next-IFD offset) would end beyond the buffer.

    Tells a cut-off file (the directory is simply missing) from a corrupt one (the directory is garbage).
    """
    if offset + 2 > len(tiff.data):
        return True
    (count,) = struct.unpack_from(tiff.byte_order + "H", tiff.data, offset)
    return offset + 2 + 12 * count + 4 > len(tiff.data)


def entry_in_bounds(tiff: TiffView, entry: TiffEntry) -> bool:
    """Whether the entry's value bytes lie wholly inside the buffer."""
    return entry.value_offset + entry.nbytes <= len(tiff.data)


def entry_ints(tiff: TiffView, entry: TiffEntry) -> tuple[int, ...] | None:
    """The entry's values if it has an integer type (offsets, byte counts, IFD pointers), else ``None``.

    ``None`` too for values outside the buffer and for absurd counts.
    """
    code = _INTEGER_CODES.get(entry.type)
    if code is None or entry.count == 0 or entry.count > MAX_VALUES or not entry_in_bounds(tiff, entry):
        return None
    return struct.unpack_from(f"{tiff.byte_order}{entry.count}{code}", tiff.data, entry.value_offset)
