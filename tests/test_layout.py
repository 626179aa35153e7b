"""The shape the code is kept in: modules of one job (at most 400 lines), dataclasses of at most 20 fields
(every one the package defines), a README that is an entry point (at most 300 lines)."""

from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path

from nerfpipe.stages import default_stages

ROOT = Path(__file__).resolve().parents[1]


def test_no_module_is_over_400_lines():
    long = {str(p.relative_to(ROOT)): n for p in (ROOT / "nerfpipe").rglob("*.py")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > 400}
    assert not long, long


def every_dataclass() -> dict[str, int]:
    """Every dataclass the package defines, by qualified name, with its number of fields: each module imported,
    and the classes it defines (nested ones too) looked at."""
    found: dict[str, int] = {}

    def visit(cls: type, module: str) -> None:
        if cls.__module__ != module:
            return
        if dataclasses.is_dataclass(cls):
            found[f"{module}.{cls.__qualname__}"] = len(dataclasses.fields(cls))
        for inner in vars(cls).values():
            if isinstance(inner, type) and inner.__qualname__.startswith(cls.__qualname__ + "."):
                visit(inner, module)

    for path in sorted(p for p in (ROOT / "nerfpipe").rglob("*.py") if p.name != "__main__.py"):
        name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        module = importlib.import_module(name)
        for value in vars(module).values():
            if isinstance(value, type):
                visit(value, name)
    return found


def test_no_dataclass_has_over_20_fields():
    seen = every_dataclass()
    # the layout test sees every dataclass: the parameter groups, the configs of every registered part, the
    # trainer's pixels, the stages' artifacts
    assert {"nerfpipe.stages.train.TrainParams", "nerfpipe.nerf.fields.configs.MlpConfig",
            "nerfpipe.nerf.samplers.configs.MarchingConfig", "nerfpipe.nerf.config.OptimParams",
            "nerfpipe.nerf.train.trainer.PixelSet", "nerfpipe.artifacts.SceneDecisions"} <= set(seen)
    for stage in default_stages():  # a stage's parameters and each group in them
        assert f"{stage.Params.__module__}.{stage.Params.__qualname__}" in seen
    assert len(seen) > 80
    assert max(seen.values()) <= 20, {name: n for name, n in seen.items() if n > 20}


def test_no_module_imports_itself_through_others():
    """No import cycle, lazy imports inside functions included (``export.web`` and ``web_panel`` had one, and
    ``imaging.decode`` and ``raw``): every strongly connected component of the module graph is one module."""
    import grimp

    graph = grimp.build_graph("nerfpipe", cache_dir=None)  # nothing written into the checkout
    imports = {m: {i for i in graph.find_modules_directly_imported_by(m) if i.startswith("nerfpipe")}
               for m in graph.modules}
    order, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def connect(v: str) -> None:  # Tarjan's strongly connected components
        order[v] = low[v] = len(order)
        stack.append(v)
        on_stack.add(v)
        for w in imports.get(v, ()):
            if w not in order:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], order[w])
        if low[v] == order[v]:
            component = []
            while not component or component[-1] != v:
                component.append(stack.pop())
                on_stack.discard(component[-1])
            if len(component) > 1:
                cycles.append(sorted(component))

    for module in sorted(imports):
        if module not in order:
            connect(module)
    assert len(imports) > 100 and not cycles, cycles


def test_the_readme_is_at_most_300_lines():
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) <= 300


def test_every_script_imports_names_the_package_has():
    """scripts/ run by hand, outside the suite: what each takes from nerfpipe still exists (a name moved in the
    package breaks a benchmark nobody runs until a figure is wanted)."""
    import ast
    import importlib.util

    missing = []
    for path in sorted((ROOT / "scripts").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "nerfpipe":
                module = importlib.import_module(node.module)
                missing += [f"{path.name}: {node.module}.{a.name}" for a in node.names if not hasattr(module, a.name)
                            and importlib.util.find_spec(f"{node.module}.{a.name}") is None]
    assert not missing, missing
