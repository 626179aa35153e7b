"""The shape the code is kept in: modules of one job (at most 400 lines), parameter groups of at most 20
fields, a README that is an entry point (at most 300 lines)."""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path

from nerfpipe.pipeline.params import is_group
from nerfpipe.stages import default_stages

ROOT = Path(__file__).resolve().parents[1]


def test_no_module_is_over_400_lines():
    long = {str(p.relative_to(ROOT)): n for p in (ROOT / "nerfpipe").rglob("*.py")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > 400}
    assert not long, long


def test_no_parameter_dataclass_has_over_20_fields():
    seen: dict[str, int] = {}

    def visit(cls: type) -> None:
        seen[cls.__qualname__] = len(dataclasses.fields(cls))
        for hint in typing.get_type_hints(cls).values():
            if is_group(hint):
                visit(hint)

    for stage in default_stages():
        visit(stage.Params)
    assert {"TrainParams", "FieldParams", "SamplerParams", "OptimParams"} <= set(seen)
    assert max(seen.values()) <= 20, seen


def test_the_readme_is_at_most_300_lines():
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) <= 300
