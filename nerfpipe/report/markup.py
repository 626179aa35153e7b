"""Small HTML helpers of the report: a figure, a video, a table, paragraphs, a titled section."""

from __future__ import annotations

import html
from typing import Any, Iterable, Sequence


def figure(src: str, caption: str = "", width: int | None = None) -> str:
    """An ``<img>`` in a ``<figure>``, its caption below it (and as its alt text)."""
    size = f' width="{width}"' if width else ""
    cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    return f'<figure><img src="{html.escape(src)}" alt="{html.escape(caption or src)}"{size}>{cap}</figure>'


def video(src: str, caption: str = "", width: int | None = None) -> str:
    """A looping, muted (so browsers let it autoplay) ``<video>`` in a ``<figure>``, with a link to the file."""
    size = f' width="{width}"' if width else ""
    link = f'<a href="{html.escape(src)}">{html.escape(src)}</a>'
    cap = f"<figcaption>{html.escape(caption)}{': ' if caption else ''}{link}</figcaption>"
    return (f'<figure><video src="{html.escape(src)}" controls autoplay loop muted playsinline preload="metadata"'
            f'{size}></video>{cap}</figure>')


def table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A table of escaped cells, one header row."""
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def paragraphs(lines: Iterable[str]) -> str:
    """One escaped ``<p>`` per line."""
    return "".join(f"<p>{html.escape(line)}</p>" for line in lines)


def grid(figures: Iterable[str]) -> str:
    """Figures side by side, wrapping."""
    return f"<div class='grid'>{''.join(figures)}</div>"


def section(title: str, body: str) -> str:
    """A section of the page: an ``<h2>`` title and its body."""
    return f"<section><h2>{html.escape(title)}</h2>{body}</section>"
