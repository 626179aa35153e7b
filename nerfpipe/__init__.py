"""nerfpipe: a folder of photos in, a Neural Radiance Field and its exports out.

Python API: a finished run (``nerfpipe.api``)::

    import nerfpipe
    run = nerfpipe.open("runs/temple")
    view = run.render(run.heldout[0], size=320)   # rgb, depth (SfM units), opacity as arrays

and the pipeline itself::

    from nerfpipe import Pipeline, default_stages
    pipe = Pipeline(default_stages(), "photos/", "runs/photos", overrides={"ingest": {"max_size": 800}})
    outcomes = pipe.run(until="ingest")
    for status in pipe.status():
        print(status.name, status.state, status.reasons)

The names below are loaded on first use (PEP 562), so ``import nerfpipe.geometry.cameras`` loads no stage.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"
__all__ = ["NerfpipeError", "Pipeline", "Run", "default_stages", "open", "__version__"]

_LAZY = {"NerfpipeError": "nerfpipe.pipeline", "Pipeline": "nerfpipe.pipeline", "default_stages": "nerfpipe.stages",
         "open": "nerfpipe.api", "Run": "nerfpipe.api"}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module 'nerfpipe' has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
