"""Do the videos in a run's report play in a browser? Opens the report in headless Chromium and prints, for
each <video>, its duration once the browser has read its metadata (``loadedmetadata``), or why not.

Run by hand (needs `apt-get install -y chromium`), on a run directory with a report:

    python scripts/check_report_videos.py runs/templeSparseRing

Exits non-zero when a video has no duration. A copy of the page with a small script added is written
beside the report (``report/.video_check.html``) and removed afterwards; the report is not changed.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

PROBE = """
<script>
window.addEventListener("load", () => {
  const videos = [...document.querySelectorAll("video")];
  const results = videos.map(() => null);
  const report = () => { document.getElementById("video-check").textContent = JSON.stringify(results); };
  videos.forEach((v, i) => {
    const done = (value) => { results[i] = value; report(); };
    if (v.readyState >= 1) done({src: v.getAttribute("src"), duration: v.duration, width: v.videoWidth});
    v.addEventListener("loadedmetadata", () => done({src: v.getAttribute("src"), duration: v.duration, width: v.videoWidth}));
    v.addEventListener("error", () => done({src: v.getAttribute("src"), error: v.error ? v.error.code : "unknown"}));
    v.load();
  });
  report();
});
</script>
<pre id="video-check"></pre>
"""


def main(run_dir: Path) -> int:
    page = run_dir / "report" / "index.html"
    if not page.is_file():
        sys.exit(f"{page}: no report; run `nerfpipe report {run_dir}` first")
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if browser is None:
        sys.exit("no Chromium found; apt-get install -y chromium")
    probe = page.with_name(".video_check.html")
    probe.write_text(page.read_text(encoding="utf-8").replace("</body>", PROBE + "</body>"), encoding="utf-8")
    try:
        dom = subprocess.run(
            [browser, "--headless", "--no-sandbox", "--disable-gpu", "--autoplay-policy=no-user-gesture-required",
             "--virtual-time-budget=15000", "--dump-dom", probe.resolve().as_uri()],
            capture_output=True, text=True, timeout=120,
        ).stdout
    finally:
        probe.unlink(missing_ok=True)
    found = re.search(r'<pre id="video-check">(.*?)</pre>', dom, re.S)
    results = json.loads(found.group(1)) if found and found.group(1).strip() else []
    if not results:
        print(f"{page}: no <video> elements found")
        return 1
    failed = 0
    for result in results:
        if result is None:
            print("a video: no metadata event within the time budget")
            failed += 1
        elif "error" in result:
            print(f"{result['src']}: the browser could not decode it (MediaError code {result['error']})")
            failed += 1
        else:
            print(f"{result['src']}: loadedmetadata, duration {result['duration']:.2f} s, {result['width']} px wide")
            failed += not result["duration"] > 0
    return 1 if failed else 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    sys.exit(main(Path(sys.argv[1])))
