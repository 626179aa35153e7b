"""A stage's summary: what ``Stage.run`` returns, the manifest keeps and ``nerfpipe status`` describes.

Each stage declares one ``Summary`` dataclass beside it, with what it reports and its own ``describe()``.
``to_json`` writes it flat: a field that is itself a ``Summary`` (a group of figures, so that no dataclass
grows past twenty fields) has its fields written at the top level, and ``from_json`` reads them back from
there, so a summary reads the same whether it was grouped or not. Every field has a default: a manifest
written before a figure existed still loads.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from typing import Any, Mapping, TypeVar

S = TypeVar("S", bound="Summary")


@dataclass(frozen=True)
class Summary:
    """The base: nothing to report, nothing to say."""

    def describe(self) -> list[str]:
        """Lines ``nerfpipe status`` and the report print about the result."""
        return []

    def to_json(self) -> dict[str, Any]:
        doc: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, Summary):
                doc.update(value.to_json())
            else:
                doc[f.name] = value
        return doc

    @classmethod
    def from_json(cls: type[S], doc: Mapping[str, Any]) -> S:
        """The summary ``to_json`` wrote (keys it does not know are left out; missing ones take their default)."""
        hints = typing.get_type_hints(cls)
        values: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            kind = hints[f.name]
            if isinstance(kind, type) and issubclass(kind, Summary):
                values[f.name] = kind.from_json(doc)
            elif f.name in doc:
                values[f.name] = doc[f.name]
        return cls(**values)


def as_json(summary: Summary | Mapping[str, Any] | None) -> dict[str, Any]:
    """What a stage's ``run`` returned, as the manifest keeps it: a ``Summary``'s JSON (or a plain mapping's)."""
    return summary.to_json() if isinstance(summary, Summary) else dict(summary or {})
