"""nerfpipe: a folder of photos in, a Neural Radiance Field and its exports out.

Python API::

    from nerfpipe import Pipeline, default_stages
    pipe = Pipeline(default_stages(), "photos/", "runs/photos", overrides={"ingest": {"max_size": 800}})
    outcomes = pipe.run(until="ingest")
    for status in pipe.status():
        print(status.name, status.state, status.reasons)
"""

from nerfpipe.pipeline import NerfpipeError, Pipeline
from nerfpipe.stages import default_stages

__version__ = "0.1.0"
__all__ = ["NerfpipeError", "Pipeline", "default_stages", "__version__"]
