"""Which torch device a stage computes on."""

from __future__ import annotations

import contextlib
from typing import Iterator

import torch

from nerfpipe.nerf.cpu import cpu_rendering
from nerfpipe.pipeline.errors import StageError


def resolve_device(choice: str, param: str) -> torch.device:
    """``auto``: CUDA when torch sees a device, else the CPU; ``cuda`` where there is none is a user error
    that names ``param`` (e.g. ``export_mesh.device``), the setting to change."""
    if choice == "cuda" and not torch.cuda.is_available():
        raise StageError(f"{param}=cuda but torch sees no CUDA device; use {param}=auto or cpu")
    return torch.device("cuda" if choice == "cuda" or (choice == "auto" and torch.cuda.is_available()) else "cpu")


def synchronize(device: torch.device) -> None:
    """Wait for the work queued on ``device``, before reading a clock: CUDA runs kernels after the calls that
    queue them return. Nothing to wait for on the CPU."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


@contextlib.contextmanager
def rendering_device(choice: str, param: str) -> Iterator[torch.device]:
    """The device a stage that renders a trained field computes on (``resolve_device``), with the CPU
    settings of ``nerfpipe.nerf.cpu.cpu_rendering`` held while it works."""
    device = resolve_device(choice, param)
    with cpu_rendering(device):
        yield device
