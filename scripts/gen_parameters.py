"""Write docs/parameters.md from the stages' parameter help strings.

    python scripts/gen_parameters.py            # rewrite docs/parameters.md
    python scripts/gen_parameters.py --check    # exit 1 when it is stale
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nerfpipe.cli.reference import parameters_markdown
from nerfpipe.stages import default_stages

TARGET = Path(__file__).resolve().parent.parent / "docs" / "parameters.md"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare instead of writing")
    args = parser.parse_args()
    text = parameters_markdown(default_stages())
    if args.check:
        stale = not TARGET.exists() or TARGET.read_text(encoding="utf-8") != text
        print(f"{TARGET}: {'stale: run python scripts/gen_parameters.py' if stale else 'up to date'}")
        return int(stale)
    TARGET.write_text(text, encoding="utf-8")
    print(f"wrote {TARGET}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
