"""``NERFPIPE_COMPILE``: what is compiled on this machine at run time. ``auto`` (the default): rendering's hot
functions (``nerfpipe.nerf.kernels``, by torch.compile, seconds once a process) and the native C kernels
(``nerfpipe.nerf.native``, a second once a machine); ``native``: the native kernels alone (the test suite's choice:
its many short processes would each compile rendering again); ``off``: neither. Read without torch, so that the
command line checks it before anything runs and a run that stops before training never imports torch."""

from __future__ import annotations

import os

from nerfpipe.pipeline.errors import ParamError

VARIABLE = "NERFPIPE_COMPILE"
CHOICES = ("auto", "native", "off")


def choice() -> str:
    """``NERFPIPE_COMPILE`` (auto when unset); anything else than ``CHOICES`` is a user error naming it (exit 2)."""
    value = os.environ.get(VARIABLE, "auto").strip().lower() or "auto"
    if value not in CHOICES:
        raise ParamError(f"{VARIABLE}={value}: must be one of {', '.join(CHOICES)} (or unset, auto)")
    return value
