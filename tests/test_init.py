"""The root package loads lazily (PEP 562): a library import loads no stage and no engine runner."""

from __future__ import annotations

import subprocess
import sys

import pytest

import nerfpipe


def loaded_after(statement: str) -> list[str]:
    code = f"import sys; {statement}; print(' '.join(sorted(m for m in sys.modules if m.startswith('nerfpipe'))))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return done.stdout.split()


def test_importing_a_library_module_loads_no_stage():
    loaded = loaded_after("import nerfpipe.geometry.cameras")
    assert "nerfpipe.geometry.cameras" in loaded
    assert not [m for m in loaded if m.startswith(("nerfpipe.stages", "nerfpipe.pipeline.runner", "nerfpipe.nerf"))]


def test_the_public_names_load_on_first_use():
    loaded = loaded_after("import nerfpipe")
    assert loaded == ["nerfpipe"]
    assert "nerfpipe.stages" in loaded_after("from nerfpipe import default_stages")
    assert nerfpipe.Pipeline.__module__ == "nerfpipe.pipeline.runner"
    assert [s.name for s in nerfpipe.default_stages()][:2] == ["ingest", "sfm"]
    assert set(nerfpipe.__all__) <= set(dir(nerfpipe))
    with pytest.raises(AttributeError, match="has no attribute 'Pipelin'"):
        nerfpipe.Pipelin  # noqa: B018
