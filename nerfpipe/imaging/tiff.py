"""Bounds-checked reading of TIFF image file directories (IFDs).

TIFF is the container of EXIF (inside a JPEG APP1 segment or a PNG ``eXIf`` chunk), of ``.tif`` photos and of
most camera RAW formats (DNG, NEF, CR2, ARW, KDC, ...). Both the EXIF reader and the truncation check walk IFDs,
so the walking lives here once.

The bytes are untrusted: every offset is checked against the buffer, entry counts are capped, and IFD chains are
followed with cycle protection. A garbled file therefore yields fewer entries (or ``None``), never an exception
or a runaway loop.

Layout (TIFF 6.0, section 2): an 8-byte header (``II*\\0`` little-endian or ``MM\\0*`` big-endian, then the
offset of the first IFD); an IFD is a 2-byte entry count, 12-byte entries (tag, type, count, value-or-offset)
and the 4-byte offset of the next IFD (0 ends the chain). A value that fits in 4 bytes is stored inline.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

TIFF_LITTLE_ENDIAN_MAGIC = b"II*\x00"
TIFF_BIG_ENDIAN_MAGIC = b"MM\x00*"

# Bytes per value for each TIFF field type (TIFF 6.0 section 2, plus type 13 IFD from the TIFF tech note 1).
_TYPE_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 13: 4}
# struct codes for the types read as plain numbers; RATIONAL (5) and SRATIONAL (10) are pairs, handled apart.
_NUMBER_CODES = {1: "B", 3: "H", 4: "I", 6: "b", 8: "h", 9: "i", 11: "f", 12: "d", 13: "I"}
_RATIONAL_CODES = {5: "I", 10: "i"}
# BYTE, SHORT, LONG, SBYTE, SSHORT, SLONG, IFD: the types an offset or a count may be stored as.
_INTEGER_TYPES = frozenset({1, 3, 4, 6, 8, 9, 13})

# Real IFDs hold tens to a few hundred entries; a larger count means we are reading garbage.
MAX_IFD_ENTRIES = 1000
# Multi-page TIFFs and RAWs chain a handful of IFDs (full image, previews, thumbnails).
MAX_IFD_CHAIN = 64
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

    Entries with an unknown type or whose value lies (partly) outside the buffer are kept: readers ask
    ``entry_numbers``/``entry_bytes``, which answer ``None`` for those, and the truncation check needs to see them.
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


def ifd_chain(tiff: TiffView, offset: int) -> list[Ifd]:
    """The IFD at ``offset`` and the ones chained after it, stopping at a bad offset or a cycle."""
    chain: list[Ifd] = []
    seen: set[int] = set()
    while offset and offset not in seen and len(chain) < MAX_IFD_CHAIN:
        seen.add(offset)
        ifd = read_ifd(tiff, offset)
        if ifd is None:
            break
        chain.append(ifd)
        offset = ifd.next_offset
    return chain


def entry_in_bounds(tiff: TiffView, entry: TiffEntry) -> bool:
    """Whether the entry's value bytes lie wholly inside the buffer."""
    return entry.value_offset + entry.nbytes <= len(tiff.data)


def entry_numbers(tiff: TiffView, entry: TiffEntry) -> tuple[float, ...] | None:
    """The entry's values as numbers (RATIONALs divided out, ``nan`` for a zero denominator).

    ``None`` for non-numeric types (ASCII, UNDEFINED), for values outside the buffer and for absurd counts.
    """
    if entry.count == 0 or entry.count > MAX_VALUES or not entry_in_bounds(tiff, entry):
        return None
    order = tiff.byte_order
    if entry.type in _NUMBER_CODES:
        code = _NUMBER_CODES[entry.type]
        return struct.unpack_from(f"{order}{entry.count}{code}", tiff.data, entry.value_offset)
    if entry.type in _RATIONAL_CODES:
        code = _RATIONAL_CODES[entry.type]
        pairs = struct.unpack_from(f"{order}{2 * entry.count}{code}", tiff.data, entry.value_offset)
        return tuple(
            numerator / denominator if denominator else math.nan
            for numerator, denominator in zip(pairs[0::2], pairs[1::2], strict=True)
        )
    return None


def entry_ints(tiff: TiffView, entry: TiffEntry) -> tuple[int, ...] | None:
    """The entry's values if it has an integer type (offsets, byte counts, IFD pointers), else ``None``."""
    if entry.type not in _INTEGER_TYPES:
        return None
    values = entry_numbers(tiff, entry)
    return tuple(int(value) for value in values) if values is not None else None


def entry_bytes(tiff: TiffView, entry: TiffEntry) -> bytes | None:
    """The entry's raw value bytes (for ASCII and UNDEFINED fields); ``None`` if they leave the buffer."""
    if entry.nbytes == 0 or not entry_in_bounds(tiff, entry):
        return None
    return tiff.data[entry.value_offset : entry.value_offset + entry.nbytes]
