"""Fingerprints of input files: mtime + size first, content hash when those changed.

A rerun with nothing changed only stats the files. A file whose mtime or size moved is hashed again,
so touching a photo without changing its bytes does not invalidate anything downstream.
"""

from __future__ import annotations

import json
import os
import uuid
from dataclasses import dataclass
from pathlib import Path

from nerfpipe.pipeline.errors import InputError
from nerfpipe.pipeline.hashing import sha256_file


@dataclass(frozen=True)
class Fingerprint:
    """What the cache key records about one input file. ``relpath`` is relative to its root folder, or absolute
    for a file outside it."""

    relpath: str
    size: int
    mtime_ns: int
    sha256: str


class FingerprintCache:
    """Remembers (size, mtime_ns) -> sha256 per absolute path, in one JSON file of the run directory.

    ``rehash`` hashes every file whatever its size and time say (``status --verify``: a photo replaced in place
    with its size and time kept), and remembers the new hashes."""

    def __init__(self, path: Path, rehash: bool = False) -> None:
        self.path, self.rehash = path, rehash
        self._entries: dict[str, list] = {}
        self._dirty = False
        try:
            entries = json.loads(path.read_text())
        except (OSError, ValueError):
            entries = {}  # a missing or damaged cache only costs rehashing
        if isinstance(entries, dict):  # and one of another shape is dropped, entry by entry
            self._entries = {k: v for k, v in entries.items() if _well_formed(v)}

    def fingerprint(self, file: Path, root: Path) -> Fingerprint:
        st = file.stat()
        key = str(file.resolve())
        cached = self._entries.get(key)
        if not self.rehash and cached is not None and cached[0] == st.st_size and cached[1] == st.st_mtime_ns:
            digest = cached[2]
        else:
            try:
                digest = sha256_file(file)
            except OSError as err:
                raise InputError(file, f"cannot be read ({err.strerror or err})",
                                 "check that you may read it, or move it out of the capture folder") from None
            self._dirty = self._dirty or self._entries.get(key) != [st.st_size, st.st_mtime_ns, digest]
            self._entries[key] = [st.st_size, st.st_mtime_ns, digest]
        # a file outside the capture (a camera path a parameter names) is known by its absolute path
        relpath = file.relative_to(root).as_posix() if file.is_relative_to(root) else Path(key).as_posix()
        return Fingerprint(relpath, st.st_size, st.st_mtime_ns, digest)

    def save(self) -> None:
        """Keep the hashes for the next run; a cache only, so a disk that takes no writes (full, read-only)
        costs the next run the hashing and nothing else."""
        if not self._dirty:
            return
        tmp = self.path.with_name(f"{self.path.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp")  # unique across nodes too
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(self._entries))
            os.replace(tmp, self.path)
        except OSError:
            tmp.unlink(missing_ok=True)
            return
        self._dirty = False


def _well_formed(entry: object) -> bool:
    """[size, mtime_ns, sha256], as ``fingerprint`` stores them."""
    return (isinstance(entry, list) and len(entry) == 3 and isinstance(entry[0], int) and isinstance(entry[1], int)
            and isinstance(entry[2], str))


def diff_inputs(old: dict[str, str], new: dict[str, str]) -> tuple[list[str], list[str], list[str]]:
    """Compare {relpath: sha256} maps; returns (added, removed, modified) relpaths, sorted."""
    added = sorted(set(new) - set(old))
    removed = sorted(set(old) - set(new))
    modified = sorted(p for p in set(old) & set(new) if old[p] != new[p])
    return added, removed, modified
