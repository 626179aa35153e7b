"""A screenshot of `nerfpipe view RUN_DIR --web` in headless Chromium, after the live render has had time
to arrive (Chromium's own --screenshot fires at page load, before the websocket has delivered the scene).

Run by hand (needs `apt-get install -y chromium`):

    python scripts/screenshot_viewer.py runs/templeSparseRing docs/web_viewer.png
    python scripts/screenshot_viewer.py --training samples/templeSparseRing /tmp/watch docs/web_viewer_training.png
    python scripts/screenshot_viewer.py --keyframes 3 runs/templeSparseRing docs/web_viewer_panel.png

The third uses the panel as a user would: it clicks "Add keyframe", drags the view round, three times, then
"Save camera_path.json" (RUN_DIR/camera_path.json), and captures the page with the keyframes drawn.

The second watches a field in training: it starts `nerfpipe run PHOTOS --out RUN --until train --view`, takes
the picture ``WAIT_S`` seconds after the viewer answers, and interrupts the run (Ctrl-C; it resumes later).

It starts the viewer, drives Chromium through the DevTools protocol (the `websockets` package viser brings),
waits ``WAIT_S`` seconds, captures the page, and stops both.
"""

from __future__ import annotations

import asyncio
import base64
import json
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

WAIT_S = 12.0
SIZE = (1280, 800)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def printed_url(viewer: subprocess.Popen, port: int) -> str:
    """The URL the viewer prints once it serves (after the stages before training, for --training)."""
    for line in viewer.stdout:
        found = re.search(rf"http://localhost:{port}/\?token=[\w-]+", line)
        if found:
            return found.group(0)
    sys.exit("the viewer ended without printing its URL")


def wait_for(url: str, seconds: float = 60) -> None:
    deadline = time.time() + seconds
    while time.time() < deadline:
        try:
            urllib.request.urlopen(url, timeout=2)
            return
        except OSError:
            time.sleep(0.3)
    sys.exit(f"{url} did not answer within {seconds:.0f} s")


CLICK = "[...document.querySelectorAll('button')].find(b => b.textContent.trim() === {label!r}).click()"


async def capture(debug_port: int, url: str, out: Path, keyframes: int = 0) -> None:
    import websockets

    target = json.loads(urllib.request.urlopen(
        urllib.request.Request(f"http://localhost:{debug_port}/json/new?{url}", method="PUT")).read())
    async with websockets.connect(target["webSocketDebuggerUrl"], max_size=None) as ws:
        ids = iter(range(1, 10_000))

        async def call(method: str, **params) -> dict:
            number = next(ids)
            await ws.send(json.dumps({"id": number, "method": method, "params": params}))
            while True:
                reply = json.loads(await ws.recv())
                if reply.get("id") == number:
                    return reply.get("result", {})

        await asyncio.sleep(WAIT_S)
        for i in range(keyframes):
            await call("Runtime.evaluate", expression=CLICK.format(label="Add keyframe"))
            await asyncio.sleep(1.0)
            # drag the view a sixth of the way across: the camera orbits the centre, leaving the keyframe in sight
            x, y = SIZE[0] * 0.35, SIZE[1] * 0.5
            await call("Input.dispatchMouseEvent", type="mousePressed", x=x, y=y, button="left", clickCount=1)
            for step in range(1, 11):
                await call("Input.dispatchMouseEvent", type="mouseMoved", x=x + 22 * step, y=y - 2 * step,
                           button="left", buttons=1)
            await call("Input.dispatchMouseEvent", type="mouseReleased", x=x + 220, y=y - 20, button="left",
                       clickCount=1)
            await asyncio.sleep(3.0)
        if keyframes:
            await call("Runtime.evaluate", expression=CLICK.format(label="Save camera_path.json"))
            for _ in range(14):  # and step back, to see the keyframes and the path through them
                await call("Input.dispatchMouseEvent", type="mouseWheel", x=SIZE[0] * 0.4, y=SIZE[1] * 0.5,
                           deltaX=0, deltaY=200)
                await asyncio.sleep(0.3)
            await asyncio.sleep(4.0)
        result = await call("Page.captureScreenshot", format="png")
        out.write_bytes(base64.b64decode(result["data"]))


def main(run_dir: Path, out: Path, photos: Path | None = None, keyframes: int = 0) -> None:
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if browser is None:
        sys.exit("no Chromium found; apt-get install -y chromium")
    port, debug_port = free_port(), free_port()
    if photos is None:
        command = ["view", str(run_dir), "--web", "--port", str(port)]
    else:
        command = ["run", str(photos), "--out", str(run_dir), "--until", "train", "--view", "--port", str(port)]
    viewer = subprocess.Popen([sys.executable, "-m", "nerfpipe", *command],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    with tempfile.TemporaryDirectory() as profile:
        chrome = subprocess.Popen(
            [browser, "--headless", "--no-sandbox", "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
             "--ignore-gpu-blocklist", f"--window-size={SIZE[0]},{SIZE[1]}", f"--remote-debugging-port={debug_port}",
             f"--user-data-dir={profile}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            url = printed_url(viewer, port)  # the viewer answers only its URL, which carries a token
            wait_for(f"http://localhost:{debug_port}/json/version")
            asyncio.run(capture(debug_port, url, out, keyframes))
        finally:
            chrome.terminate()
            viewer.send_signal(signal.SIGINT)
            viewer.wait(timeout=30)
    print(f"wrote {out}")


if __name__ == "__main__":
    if len(sys.argv) == 3:
        main(Path(sys.argv[1]), Path(sys.argv[2]))
    elif len(sys.argv) == 5 and sys.argv[1] == "--training":
        main(Path(sys.argv[3]), Path(sys.argv[4]), photos=Path(sys.argv[2]))
    elif len(sys.argv) == 5 and sys.argv[1] == "--keyframes":
        main(Path(sys.argv[3]), Path(sys.argv[4]), keyframes=int(sys.argv[2]))
    else:
        sys.exit(__doc__)
