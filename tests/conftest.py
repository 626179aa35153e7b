"""Fixtures shared by every test module."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest
from hypothesis import settings
from hypothesis.configuration import set_hypothesis_home_dir

from tests.helpers import REPO, SHARED_DATA, TEMPLE

# hypothesis keeps no example database, and its other files (a cache of constants) in a temporary folder: a test
# run changes no file outside its temporary folders
settings.register_profile("nerfpipe", database=None)
settings.load_profile("nerfpipe")
set_hypothesis_home_dir(tempfile.mkdtemp(prefix="nerfpipe-tests-hypothesis-"))

# rendering evaluates its fields eagerly in tests (``nerfpipe.nerf.kernels``): compiling a graph for each of the
# suite's many small models would cost more than it saves; tests/nerf/test_kernels.py compiles them on purpose.
# The native C kernels (``nerfpipe.nerf.native``) are built once, into a temporary folder, and used
os.environ.setdefault("NERFPIPE_COMPILE", "native")
os.environ.setdefault("NERFPIPE_CACHE_DIR", tempfile.mkdtemp(prefix="nerfpipe-tests-cache-"))

# what the tests may write in the checkout: caches of Python and pytest
_SCRATCH = ("__pycache__", ".pytest_cache", ".egg-info", ".git")


def _tree(root: Path) -> dict[str, tuple[int, int]]:
    """(size, mtime_ns) of every file under ``root`` but scratch folders: what a test must leave as it was."""
    state = {}
    for path in root.rglob("*"):
        if any(part.endswith(_SCRATCH) for part in path.relative_to(root).parts):
            continue
        if path.is_file() and not path.is_symlink():
            stat = path.stat()
            state[path.relative_to(root).as_posix()] = (stat.st_size, stat.st_mtime_ns)
    return state


def pytest_sessionstart(session: pytest.Session) -> None:
    session.config.stash[_BEFORE] = {root: _tree(root) for root in (REPO, SHARED_DATA) if root.is_dir()}


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Fail the run when a test added, changed or removed a file of the checkout or of ../shared (the photos,
    the samples, the docs): tests write only into their temporary folders."""
    before = session.config.stash.get(_BEFORE, {})
    changed = []
    for root, state in before.items():
        after = _tree(root)
        changed += [f"{root / rel}" for rel in sorted(set(state) ^ set(after) | {r for r in state if r in after
                                                                                  and state[r] != after[r]})]
    if changed:
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        if reporter is not None:
            reporter.write_line(f"tests changed {len(changed)} files outside their temporary folders: "
                                + ", ".join(changed[:10]), red=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


_BEFORE = pytest.StashKey[dict]()


@pytest.fixture
def capture(tmp_path: Path) -> Path:
    """A writable plain folder: four bundled temple photos and a side-car text file (no pose file)."""
    folder = tmp_path / "capture"
    folder.mkdir()
    for name in ("templeSR0001.png", "templeSR0002.png", "templeSR0003.png", "templeSR0004.png"):
        shutil.copy2(TEMPLE / name, folder / name)
    shutil.copy2(TEMPLE / "README.txt", folder / "README.txt")
    return folder
