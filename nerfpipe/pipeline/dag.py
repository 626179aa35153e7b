"""The stage graph, derived from what each stage requires and provides."""

from __future__ import annotations

import difflib
from typing import Sequence

from nerfpipe.pipeline.errors import ParamError
from nerfpipe.pipeline.stage import Stage


class Dag:
    """Stages in a valid execution order, with their upstream and downstream neighbours."""

    def __init__(self, stages: Sequence[Stage]) -> None:
        self.stages = {s.name: s for s in stages}
        if len(self.stages) != len(stages):
            raise ValueError("two stages share a name")
        self.provider: dict[str, str] = {}
        for stage in stages:
            for artifact in stage.provides:
                if artifact in self.provider:
                    raise ValueError(f"artifact {artifact!r} provided by {self.provider[artifact]} and {stage.name}")
                self.provider[artifact] = stage.name
        self.upstream: dict[str, list[str]] = {}
        for stage in stages:
            missing = [a for a in stage.requires if a not in self.provider]
            if missing:
                raise ValueError(f"stage {stage.name} requires {missing}, which no stage provides")
            self.upstream[stage.name] = sorted({self.provider[a] for a in stage.requires})
        self.order = self._topological_order()

    def _topological_order(self) -> list[str]:
        order: list[str] = []
        state: dict[str, int] = {}  # 1 = visiting, 2 = done

        def visit(name: str) -> None:
            if state.get(name) == 2:
                return
            if state.get(name) == 1:
                raise ValueError(f"stage graph has a cycle through {name}")
            state[name] = 1
            for up in self.upstream[name]:
                visit(up)
            state[name] = 2
            order.append(name)

        for name in self.stages:  # declaration order breaks ties, so the order is stable
            visit(name)
        return order

    def check_name(self, name: str) -> str:
        if name not in self.stages:
            close = difflib.get_close_matches(name, list(self.stages), n=1)
            hint = f"did you mean {close[0]}?" if close else f"stages are: {', '.join(self.order)}"
            raise ParamError(f"unknown stage {name!r}; {hint}")
        return name

    def ancestors(self, name: str) -> set[str]:
        seen: set[str] = set()
        todo = list(self.upstream[name])
        while todo:
            up = todo.pop()
            if up not in seen:
                seen.add(up)
                todo.extend(self.upstream[up])
        return seen

    def descendants(self, name: str) -> set[str]:
        return {other for other in self.stages if name in self.ancestors(other)}

    def select(self, until: str | None = None, only: str | None = None) -> list[str]:
        """Stages to consider, in order: all, those up to ``until``, or ``only`` one."""
        if until and only:
            raise ParamError("--until and --only do not combine; use one of them")
        if only:
            return [self.check_name(only)]
        if until:
            keep = self.ancestors(self.check_name(until)) | {until}
            return [n for n in self.order if n in keep]
        return list(self.order)
