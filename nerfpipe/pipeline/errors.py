"""Typed errors.

``NerfpipeError`` and its subclasses are *user* errors: bad photos, bad pose files, bad flags, a run
directory in use. The CLI prints them as one line and exits non-zero; ``--debug`` adds the traceback.
Any other exception is a bug in nerfpipe and is shown with its traceback.
"""

from __future__ import annotations

from pathlib import Path


class NerfpipeError(Exception):
    """A problem the user can fix. ``str(err)`` is the one line the CLI prints."""

    exit_code = 1


class ParamError(NerfpipeError):
    """An unknown stage, parameter or preset, or a value of the wrong type or range."""

    exit_code = 2


class InputError(NerfpipeError):
    """A problem with the user's input files or folders."""

    def __init__(self, path: Path | str | None, problem: str, advice: str = "") -> None:
        self.path = Path(path) if path is not None else None
        self.problem = problem
        self.advice = advice
        where = f"{self.path}: " if self.path is not None else ""
        tail = f"; {advice}" if advice else ""
        super().__init__(f"{where}{problem}{tail}")


class BadPhotoError(InputError):
    """One photo cannot be used (corrupt, truncated, empty, unsupported, duplicate)."""


class RunLockedError(NerfpipeError):
    """Another nerfpipe process is using the run directory."""


class StageError(NerfpipeError):
    """A stage could not produce its result for a reason the user can act on."""


class UpstreamNotReadyError(NerfpipeError):
    """``--only STAGE`` was asked for while an upstream stage has no result for the current settings."""
