"""Screenshot chosen sections of a run's report in headless Chromium (``apt-get install -y chromium``): a copy
of the page with only the sections whose title starts with one of the names given is written beside the report
(``report/.sections.html``), photographed at the given width, and removed; the report is not changed.

    python scripts/screenshot_report.py runs/temple docs/report_training.png Training --width 1100
"""

from __future__ import annotations

import argparse
import re
import subprocess
import tempfile
from pathlib import Path

CHROMIUM = ("chromium", "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("titles", nargs="+", help="sections whose <h2> starts with one of these")
    parser.add_argument("--width", type=int, default=1100)
    parser.add_argument("--height", type=int, default=1400)
    args = parser.parse_args()
    page = (args.run_dir / "report" / "index.html").read_text(encoding="utf-8")
    sections = re.findall(r"<section><h2>(.*?)</h2>.*?</section>", page, re.S)
    kept = [m.group(0) for m in re.finditer(r"<section><h2>(.*?)</h2>.*?</section>", page, re.S)
            if any(m.group(1).startswith(t) for t in args.titles)]
    if not kept:
        raise SystemExit(f"no section titled {args.titles}; the report has {sections}")
    head, _, _ = page.partition("<section>")
    copy = args.run_dir / "report" / ".sections.html"
    copy.write_text(head + "".join(kept) + "</body></html>", encoding="utf-8")
    try:
        with tempfile.TemporaryDirectory() as profile:
            subprocess.run([*CHROMIUM, f"--user-data-dir={profile}", f"--window-size={args.width},{args.height}",
                            f"--screenshot={args.out.resolve()}", copy.resolve().as_uri()],
                           check=True, capture_output=True, timeout=120)
    finally:
        copy.unlink(missing_ok=True)
    print(f"{args.out}: {', '.join(t for t in sections if any(t.startswith(x) for x in args.titles))}")


if __name__ == "__main__":
    main()
