"""What this process may allocate: the smallest of the machine's memory, the process's data and address-space
limits (``ulimit -d``, ``ulimit -v``) and its cgroup's (a container's or a cluster job's) limit.

Parameters whose sizes multiply (grid levels and resolutions, textures, batches) are checked against it
before anything runs, so a size the machine cannot hold is one line, not a crash an hour in.
"""

from __future__ import annotations

import os
import resource
from pathlib import Path

from nerfpipe.pipeline.errors import format_bytes

MEMORY_SHARE = 0.5  # of ``memory_limit``, for one part's tables: the rest of the job needs the other half


def memory_limit() -> int:
    """Bytes this process may allocate at most."""
    limits = [os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")]
    for which in (resource.RLIMIT_DATA, resource.RLIMIT_AS):
        soft, _ = resource.getrlimit(which)
        if soft != resource.RLIM_INFINITY:
            limits.append(soft)
    for cgroup in (Path("/sys/fs/cgroup/memory.max"), Path("/sys/fs/cgroup/memory/memory.limit_in_bytes")):
        try:
            text = cgroup.read_text().strip()
        except OSError:
            continue
        if text.isdigit():
            limits.append(int(text))
    return min(limits)


def check_memory(names: str, what: str, needed: int, share: float = MEMORY_SHARE) -> None:
    """Raise ``ValueError`` naming the parameters ``names`` when ``what`` (``needed`` bytes) exceeds ``share`` of
    what this process may allocate (a parameter class's ``__post_init__`` calls it; the parameter layer turns the
    ``ValueError`` into one line)."""
    allowed = int(share * memory_limit())
    if needed > allowed:
        raise ValueError(f"{names}: {what} take about {format_bytes(needed)}, more than the {format_bytes(allowed)} "
                         "this machine allows them; lower one of them")
