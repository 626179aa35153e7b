"""Training checkpoints: the model, the optimizer and the trainer's counters at a step, written atomically, the
newest ones kept, and loaded back with weights_only."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import torch

from nerfpipe.nerf.model import RadianceModel, load_tensors
from nerfpipe.pipeline.errors import InputError

log = logging.getLogger("nerfpipe.nerf.train.trainer")

CHECKPOINT_GLOB = "step_*.pt"


def checkpoints(folder: Path) -> list[Path]:
    return sorted(folder.glob(CHECKPOINT_GLOB), key=lambda p: int(p.stem.split("_")[1]))


def save_checkpoint(folder: Path, step: int, elapsed: float, model: RadianceModel, optimizer: torch.optim.Optimizer,
                    keep: int, extra: dict | None = None) -> Path:
    """Write ``step_<n>.pt`` atomically (a killed write leaves only a temp file), then prune old ones."""
    folder.mkdir(parents=True, exist_ok=True)
    state = {"step": step, "elapsed": elapsed, **model.state(), "optimizer": optimizer.state_dict(), **(extra or {})}
    path = folder / f"step_{step:07d}.pt"
    tmp = folder / f".{path.name}.tmp"
    try:
        torch.save(state, tmp)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:  # a full disk, an interrupt: no half-written file stays behind
        tmp.unlink(missing_ok=True)
        raise
    if keep > 0:
        for old in checkpoints(folder)[:-keep]:
            old.unlink()
    return path


def load_latest_checkpoint(folder: Path, device: torch.device) -> dict | None:
    """The newest checkpoint that loads (tensors only: ``weights_only=True``), or None."""
    for path in reversed(checkpoints(folder)):
        try:
            return load_tensors(path, device, "checkpoint")
        except InputError:
            log.warning("checkpoint %s is not a nerfpipe checkpoint (it holds Python objects, not only tensors) and "
                        "was not loaded; trying the one before", path.name)
        except Exception as err:  # a damaged file: fall back to the one before
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            log.warning("checkpoint %s is unreadable (%s); trying the one before", path.name, first)
    return None
