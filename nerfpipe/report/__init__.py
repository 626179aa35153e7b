"""The run report: one HTML page, with its PNGs beside it, that shows what a run did and how well.

Sections, each present when its stage has a result for the run's current settings: the capture
(thumbnails), structure from motion (summary and a plot of cameras and sparse points), the scene
decisions with their evidence, training (loss and PSNR against wall time, held-out renders beside
their ground truth), depth previews, screenshots of the mesh and point cloud, the novel-view videos,
the benchmark when ``nerfpipe bench`` ran, and the time each stage took.

``data`` gathers the run once, ``sections`` builds each section from it, ``page`` joins them;
``markup`` and ``images`` are the HTML and picture helpers.
"""

from nerfpipe.report.page import write_report

__all__ = ["write_report"]
