"""``NERFPIPE_COMPILE``: whether rendering compiles its hot functions (``nerfpipe.nerf.kernels``). Read without torch,
so that the command line checks it before anything runs and a run that stops before training never imports torch."""

from __future__ import annotations

import os

from nerfpipe.pipeline.errors import ParamError

VARIABLE = "NERFPIPE_COMPILE"
CHOICES = ("auto", "off")


def choice() -> str:
    """``NERFPIPE_COMPILE`` (auto when unset); anything else than ``CHOICES`` is a user error naming it (exit 2)."""
    value = os.environ.get(VARIABLE, "auto").strip().lower() or "auto"
    if value not in CHOICES:
        raise ParamError(f"{VARIABLE}={value}: must be one of {', '.join(CHOICES)} (or unset, auto)")
    return value
