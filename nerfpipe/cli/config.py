"""Run settings in a YAML file: ``nerfpipe run ... --config run.yaml`` reads the same keys as ``--set``
(``--set`` wins), and every run writes what it resolved to ``RUN_DIR/config.yaml``, every parameter of
every stage, so ``--config RUN_DIR/config.yaml`` repeats it.

The file is a mapping of stage names to their parameters; a group may be nested or written with dots::

    preset: draft          # optional
    budget: 10m            # optional: the job's time budget (``--budget``)
    ingest:
      max_size: 800
    train:
      seconds: 300
      field:
        max_resolution: 256
      optim.lr: 0.01
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import yaml

from nerfpipe.pipeline import ParamError, PlannedStage
from nerfpipe.pipeline.params import flatten, params_to_dict

CONFIG_FILE = "config.yaml"


class _DuplicateKey(Exception):
    pass


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (it would keep the last silently)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise _DuplicateKey(f"{key!r} is given twice (line {key_node.start_mark.line + 1})")
            seen.add(key)
        return super().construct_mapping(node, deep)


def read_config(path: Path) -> tuple[str | None, dict[str, dict[str, Any]], str | None]:
    """The preset, the overrides (stage -> {dotted name: value}) and the budget (as written) of a settings
    file; a file that cannot be read or is not such a mapping is a ``ParamError`` naming it."""
    try:
        doc = yaml.load(Path(path).read_text(encoding="utf-8"), Loader=_UniqueKeyLoader)
    except FileNotFoundError:
        raise ParamError(f"--config {path}: no such file") from None
    except _DuplicateKey as err:
        raise ParamError(f"--config {path}: {err}; keep one") from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError, ValueError, RecursionError) as err:
        # ValueError: an integer of thousands of digits, which Python refuses to convert
        where = getattr(err, "problem_mark", None)
        at = f" (line {where.line + 1})" if where is not None else ""
        raise ParamError(f"--config {path}: not a readable YAML file{at}; write STAGE: {{PARAM: VALUE}} mappings") from None
    if doc is None:
        return None, {}, None
    if not isinstance(doc, Mapping):
        raise ParamError(f"--config {path}: expected a mapping of stage names to parameters, got {type(doc).__name__}")
    preset = doc.get("preset")
    if preset is not None and not isinstance(preset, str):
        raise ParamError(f"--config {path}: preset must be a name, got {preset!r}")
    budget = doc.get("budget")
    budget = "off" if budget is False else budget  # YAML reads a bare off as false
    if budget is not None and (isinstance(budget, bool) or not isinstance(budget, (str, int, float))):
        raise ParamError(f"--config {path}: budget must be a duration such as 10m, or auto or off, got {budget!r}")
    overrides: dict[str, dict[str, Any]] = {}
    for stage, values in doc.items():
        if stage in ("preset", "budget"):
            continue
        if not isinstance(values, Mapping):
            raise ParamError(f"--config {path}: {stage} must map parameter names to values, got {values!r}")
        overrides[str(stage)] = flatten(values)
    return preset, overrides, None if budget is None else str(budget)


def merge(base: Mapping[str, Mapping[str, Any]], top: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """``base`` overrides with ``top``'s on top, stage by stage."""
    merged = {stage: dict(values) for stage, values in base.items()}
    for stage, values in top.items():
        merged.setdefault(stage, {}).update(values)
    return merged


def write_config(run_dir: Path, plan: Mapping[str, PlannedStage], budget: float | str | None = None) -> Path:
    """``RUN_DIR/config.yaml``: the budget, and every parameter of every stage as this run resolved it, less
    those the budget set (an elastic stage's, e.g. train.seconds), so the file repeats the run as it was asked."""
    doc: dict[str, Any] = {"budget": "off" if budget is None else budget}
    for name, planned in plan.items():
        values = flatten(params_to_dict(planned.params))
        doc[name] = {k: v for k, v in values.items() if not (planned.elastic and k in planned.stage.elastic)}
    path = Path(run_dir) / CONFIG_FILE
    header = "# every parameter of this run as resolved; `nerfpipe run PHOTOS --config this-file` repeats it\n"
    path.write_text(header + yaml.safe_dump(doc, sort_keys=False, allow_unicode=True), encoding="utf-8")
    return path


def one_preset(presets: list[str]) -> str | None:
    """The one ``--preset`` given, if any: presets do not combine, so two are refused rather than one dropped."""
    if len(presets) > 1:
        raise ParamError(f"--preset given {len(presets)} times ({', '.join(presets)}); presets do not combine: choose "
                         "one, and --set what you want on top")
    return presets[0] if presets else None
