"""Open3D as nerfpipe imports it prints none of its info or debug lines (they went straight to the terminal,
past nerfpipe's log and --quiet), whatever level nerfpipe's own log is at."""

from __future__ import annotations

import logging

from nerfpipe.export.o3d import open3d


def test_open3d_keeps_its_info_lines_to_itself(capfd):
    logging.getLogger("nerfpipe").setLevel(logging.DEBUG)  # as a run's log file asks
    o3d = open3d()
    box = o3d.geometry.TriangleMesh.create_box().subdivide_midpoint(2)
    box.remove_unreferenced_vertices()  # says how many at Debug
    solid = o3d.t.geometry.TriangleMesh.from_legacy(box)
    solid.compute_uvatlas(size=64, parallel_partitions=2)  # says "actual parallel_partitions" at Info
    captured = capfd.readouterr()
    assert "[Open3D" not in captured.out + captured.err
    assert o3d.utility.get_verbosity_level() == o3d.utility.VerbosityLevel.Warning
