"""The stall guard: a training whose batch PSNR stays at the level of a render in the images' mean colour
restarts once, then is reported."""

from __future__ import annotations

import math
from dataclasses import dataclass

from torch import Tensor


def mse_to_psnr(mse: float) -> float:
    """PSNR in dB of images in [0, 1] from their mean squared error."""
    return -10.0 * math.log10(max(mse, 1e-12))


def mean_colour_psnr(rgb: Tensor) -> float:
    """PSNR of a render that is the training pixels' mean colour everywhere (rgb: (P, 3)): the level a
    training that learns nothing of the scene settles at."""
    return mse_to_psnr(float(((rgb - rgb.mean(dim=0)) ** 2).mean()))


@dataclass
class StallGuard:
    """Tells a training that learns nothing: one whose batch PSNR (an exponential moving average, weight
    ``smoothing`` per step) is within ``margin_db`` of the mean-colour level at ``check_step``.

    The first time, the trainer restarts from its initial weights with a fresh occupancy grid and half the
    learning rate (a diverged optimizer or an occupancy grid that lost the scene recover that way); a stall
    that outlasts the restart, or one found at the last step, is reported and left as it is.
    """

    floor_db: float  # the mean-colour level
    check_step: int
    margin_db: float = 1.0
    smoothing: float = 0.1
    ema: float | None = None
    restarted_at: int | None = None
    stalled: bool = False

    def observe(self, step: int, psnr: float, last: bool) -> str:
        """After ``step``: "restart", "stalled" (the first time a stall is found and no restart is left) or "ok"."""
        self.ema = psnr if self.ema is None else (1 - self.smoothing) * self.ema + self.smoothing * psnr
        due = last or step == self.check_step or (self.restarted_at is not None and step == self.restarted_at + self.check_step)
        if not due or self.stalled or self.ema > self.floor_db + self.margin_db:
            return "ok"
        if self.restarted_at is None and not last:
            self.restarted_at, self.ema = step, None
            return "restart"
        self.stalled = True
        return "stalled"

    def report(self) -> dict:
        return {"mean_colour_psnr": round(self.floor_db, 3), "batch_psnr_ema": None if self.ema is None else round(self.ema, 3),
                "restarted_at": self.restarted_at, "stalled": self.stalled}
