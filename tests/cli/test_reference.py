"""docs/parameters.md is what scripts/gen_parameters.py writes from the help strings today."""

from __future__ import annotations

from pathlib import Path

from nerfpipe.cli.reference import parameters_markdown
from nerfpipe.pipeline import param_specs
from nerfpipe.stages import TrainParams, default_stages

DOC = Path(__file__).resolve().parents[2] / "docs" / "parameters.md"


def test_the_parameter_reference_is_current():
    assert DOC.read_text(encoding="utf-8") == parameters_markdown(default_stages()), (
        "docs/parameters.md is stale: run python scripts/gen_parameters.py")


def test_every_parameter_has_a_row_with_its_help():
    text = parameters_markdown(default_stages())
    for stage in default_stages():
        for spec in param_specs(stage.Params):
            assert f"| `{stage.name}.{spec.name}` |" in text
            assert spec.help, f"{stage.name}.{spec.name} has no help string"
    assert ("| `train.field.max_resolution` | int | `128` | [1, 8192] | (grid, hash, planes) cells a side of the "
            "finest level |") in text
    assert ("| `train.chunk` | int | `4096` | [1, 1_048_576] | rays per chunk when rendering whole views; changing it "
            "reruns nothing |") in text
    assert "- `draft`: `steps=500`, `field.levels=1`" in text
    assert {s.name for s in param_specs(TrainParams)} >= {"field.kind", "sampler.kind", "optim.lr", "per_image.appearance"}
