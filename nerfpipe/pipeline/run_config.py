"""``RUN_DIR/run.json``: the capture folder and settings of the last ``nerfpipe run`` into a run directory, so
``status``, ``report`` and ``view`` see the run as it was made."""

from __future__ import annotations

import json
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from nerfpipe.pipeline.errors import InputError
from nerfpipe.pipeline.store import write_json_atomic

RUN_CONFIG = "run.json"


@dataclass(frozen=True)
class RunConfig:
    """source: the capture (absolute); preset: the --preset; overrides: stage -> {parameter: value} (--set);
    budget: the job's time budget in seconds, ``auto``, or None (``nerfpipe.pipeline.budget``)."""

    source: str
    preset: str | None = None
    overrides: dict[str, dict[str, Any]] = field(default_factory=dict)
    budget: float | str | None = None

    @staticmethod
    def load(run_dir: Path) -> "RunConfig":
        """Raises ``InputError`` for a folder that is no run directory, or whose run.json is damaged."""
        path = Path(run_dir) / RUN_CONFIG
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
            budget = doc.get("budget")
            if not (budget is None or budget == "auto" or (isinstance(budget, (int, float)) and budget > 0)):
                raise ValueError(budget)
            return RunConfig(str(doc["source"]), doc.get("preset"),
                             {k: dict(v) for k, v in doc.get("overrides", {}).items()}, budget)
        except FileNotFoundError:
            raise InputError(run_dir, "is not a nerfpipe run directory (no run.json)",
                             "pass the --out folder of a `nerfpipe run`") from None
        except (ValueError, KeyError, TypeError, AttributeError):
            raise InputError(path, "is damaged", "rerun `nerfpipe run PHOTOS_DIR --out` on this folder") from None

    def save(self, run_dir: Path) -> None:
        """Write run.json, unless it already says the same (its time then stays as it was)."""
        path = Path(run_dir) / RUN_CONFIG
        doc = {"source": self.source, "preset": self.preset, "overrides": self.overrides, "budget": self.budget}
        try:
            if json.loads(path.read_text(encoding="utf-8")) == doc:
                return
        except (FileNotFoundError, ValueError):
            pass
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, doc)


def run_command(source: Path, run_dir: Path, preset: str | None, overrides: Mapping[str, Mapping[str, Any]],
                budget: float | str | None, until: str | None = None) -> str:
    """The ``nerfpipe run`` command line with these settings (preset, every ``--set``, the budget), quoted for a
    POSIX shell: what a message suggests, so that following it keeps the run's settings."""
    words = ["nerfpipe", "run", str(source), "--out", str(run_dir)]
    if preset is not None:
        words += ["--preset", preset]
    for stage, values in overrides.items():
        for name, value in values.items():
            words += ["--set", f"{stage}.{name}={value}"]
    if budget is None:
        words += ["--budget", "off"]
    elif not isinstance(budget, str):
        words += ["--budget", f"{budget:g}"]
    if until is not None:
        words += ["--until", until]
    return shlex.join(words)
