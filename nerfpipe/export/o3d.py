"""Open3D, imported where it is used (it takes a second to load) and told to keep its info lines to itself:
its own logger prints to the terminal (``[Open3D INFO] actual parallel_partitions 11``), past nerfpipe's
log. Warnings and errors still show, and everything with ``--debug``."""

from __future__ import annotations

import logging
from types import ModuleType


def open3d() -> ModuleType:
    """The ``open3d`` module, its verbosity at nerfpipe's: Debug when nerfpipe logs debug lines, else Warning."""
    import open3d as o3d

    debug = logging.getLogger("nerfpipe").isEnabledFor(logging.DEBUG)
    level = o3d.utility.VerbosityLevel.Debug if debug else o3d.utility.VerbosityLevel.Warning
    if o3d.utility.get_verbosity_level() != level:
        o3d.utility.set_verbosity_level(level)
    return o3d
