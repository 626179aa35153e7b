"""A py-spy profile as a table of Python functions: the share of samples in each (inclusive) and in its own code.

    py-spy record -r 200 -f raw -o beer.raw -- python scripts/profile_train.py --profiler none --steps 200
    python scripts/pyspy_table.py beer.raw --root profiled_window

Only the stacks that pass through ``--root`` count (the profiled window, not the set-up before it); line numbers
are dropped, so a function is one row however many of its lines were sampled.
"""

from __future__ import annotations

import argparse
import collections
import re
from pathlib import Path


def table(raw: Path, root: str, rows: int) -> str:
    inclusive: collections.Counter[str] = collections.Counter()
    own: collections.Counter[str] = collections.Counter()
    total = 0
    for line in raw.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        frames = [re.sub(r":\d+\)$", ")", f) for f in stack.split(";")]
        start = next((i for i, f in enumerate(frames) if f.split(" (")[0].split(".")[-1] == root), None)
        if start is None:
            continue
        frames, n = frames[start:], int(count)
        total += n
        for f in set(frames):
            inclusive[f] += n
        own[frames[-1]] += n
    lines = [f"{total} samples under {root}", "", "| function | in it | its own code |", "|:--|--:|--:|"]
    for f, n in inclusive.most_common(rows):
        lines.append(f"| `{f}` | {100 * n / max(total, 1):.1f} % | {100 * own[f] / max(total, 1):.1f} % |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("raw", type=Path, help="py-spy record -f raw output")
    parser.add_argument("--root", default="profiled_window", help="count only stacks through this function")
    parser.add_argument("--rows", type=int, default=30)
    args = parser.parse_args()
    print(table(args.raw, args.root, args.rows))


if __name__ == "__main__":
    main()
