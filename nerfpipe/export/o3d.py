"""Open3D, imported where it is used (it takes a second to load) and told to keep its info and debug lines to
itself: its own logger prints straight to the terminal (``[Open3D INFO] actual parallel_partitions 11``), past
nerfpipe's log and its ``--quiet``. Its warnings and errors still show."""

from __future__ import annotations

from types import ModuleType


def open3d() -> ModuleType:
    """The ``open3d`` module, its verbosity at Warning."""
    import open3d as o3d

    if o3d.utility.get_verbosity_level() != o3d.utility.VerbosityLevel.Warning:
        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Warning)
    return o3d
