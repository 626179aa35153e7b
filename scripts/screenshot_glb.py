"""A GLB as three.js shows it: loaded by three.js's GLTFLoader in headless Chromium, lit by a hemisphere and a
sun, framed on its bounding box from the front (+Z) and above, and captured; every console error and failed
request is printed, and the script fails on any.

Run by hand (needs `apt-get install -y chromium` and three.js from npm, outside the repository):

    npm install --prefix /tmp/three three
    python scripts/screenshot_glb.py /tmp/three runs/templeSparseRing/exports/mesh.glb docs/mesh_threejs.png

It serves a folder holding the page, the GLB and three.js on a free local port, drives Chromium through the
DevTools protocol (the `websockets` package viser brings), and stops both.
"""

from __future__ import annotations

import asyncio
import base64
import functools
import http.server
import json
import shutil
import socketserver
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

SIZE = (960, 720)
PAGE = """<!doctype html><html><head><meta charset="utf-8"><style>body{margin:0;background:#fff;overflow:hidden}</style>
<script type="importmap">{"imports": {"three": "./three/build/three.module.js", "three/addons/": "./three/examples/jsm/"}}</script>
</head><body><script type="module">
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
const renderer = new THREE.WebGLRenderer({antialias: true, preserveDrawingBuffer: true});
renderer.setSize(%(w)d, %(h)d);
renderer.outputColorSpace = THREE.SRGBColorSpace;
document.body.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xffffff);
scene.add(new THREE.HemisphereLight(0xffffff, 0x444444, 2.0));
const sun = new THREE.DirectionalLight(0xffffff, 1.5);
sun.position.set(1, 2, 3);
scene.add(sun);
const camera = new THREE.PerspectiveCamera(40, %(w)d / %(h)d, 0.001, 1000);
new GLTFLoader().load("mesh.glb", (gltf) => {
  scene.add(gltf.scene);
  const box = new THREE.Box3().setFromObject(gltf.scene);
  const centre = box.getCenter(new THREE.Vector3()), size = box.getSize(new THREE.Vector3()).length();
  camera.position.copy(centre).add(new THREE.Vector3(0, 0.3 * size, 1.5 * size));
  camera.lookAt(centre);
  renderer.render(scene, camera);
  let material = null;
  gltf.scene.traverse((o) => { if (o.isMesh) material = o.material; });
  document.title = "loaded " + JSON.stringify({metalness: material.metalness, roughness: material.roughness,
                                               map: material.map !== null, colorSpace: material.map && material.map.colorSpace});
}, undefined, (error) => { document.title = "error " + error; console.error(error); });
</script></body></html>
"""


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def capture(debug_port: int, url: str, out: Path) -> list[str]:
    import websockets

    target = json.loads(urllib.request.urlopen(
        urllib.request.Request(f"http://127.0.0.1:{debug_port}/json/new?about:blank", method="PUT")).read())
    problems: list[str] = []
    async with websockets.connect(target["webSocketDebuggerUrl"], max_size=None) as ws:
        ids = iter(range(1, 10_000))

        async def call(method: str, **params) -> dict:
            number = next(ids)
            await ws.send(json.dumps({"id": number, "method": method, "params": params}))
            while True:
                reply = json.loads(await ws.recv())
                if reply.get("id") == number:
                    return reply.get("result", {})
                if reply.get("method") == "Runtime.consoleAPICalled" and reply["params"]["type"] == "error":
                    problems.append("console: " + " ".join(str(a.get("value", a.get("description")))
                                                           for a in reply["params"]["args"]))
                if reply.get("method") == "Runtime.exceptionThrown":
                    problems.append("exception: " + reply["params"]["exceptionDetails"].get("text", ""))
                if reply.get("method") == "Network.loadingFailed":
                    problems.append("request failed: " + reply["params"].get("errorText", ""))

        await call("Runtime.enable")
        await call("Network.enable")
        await call("Page.navigate", url=url)
        title = ""
        for _ in range(120):
            title = (await call("Runtime.evaluate", expression="document.title"))["result"].get("value", "")
            if title.startswith(("loaded", "error")):
                break
            await asyncio.sleep(0.5)
        print(f"three.js: {title or 'no answer'}")
        if not title.startswith("loaded"):
            problems.append(f"the GLB did not load: {title or 'timed out'}")
        result = await call("Page.captureScreenshot", format="png")
        out.write_bytes(base64.b64decode(result["data"]))
    return problems


def main(three: Path, glb: Path, out: Path) -> None:
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if browser is None:
        sys.exit("no Chromium found; apt-get install -y chromium")
    package = three / "node_modules" / "three" if (three / "node_modules" / "three").is_dir() else three
    with tempfile.TemporaryDirectory() as site, tempfile.TemporaryDirectory() as profile:
        (Path(site) / "index.html").write_text(PAGE % {"w": SIZE[0], "h": SIZE[1]})
        shutil.copyfile(glb, Path(site) / "mesh.glb")
        (Path(site) / "three").symlink_to(package.resolve())
        handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=site)
        http.server.SimpleHTTPRequestHandler.log_message = lambda *args: None
        port, debug_port = free_port(), free_port()
        server = socketserver.TCPServer(("127.0.0.1", port), handler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        chrome = subprocess.Popen(
            [browser, "--headless", "--no-sandbox", "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
             "--ignore-gpu-blocklist", f"--window-size={SIZE[0]},{SIZE[1]}", f"--remote-debugging-port={debug_port}",
             f"--user-data-dir={profile}", "about:blank"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            for _ in range(60):
                try:
                    urllib.request.urlopen(f"http://127.0.0.1:{debug_port}/json/version", timeout=2)
                    break
                except OSError:
                    time.sleep(0.5)
            problems = asyncio.run(capture(debug_port, f"http://127.0.0.1:{port}/index.html", out))
        finally:
            chrome.terminate()
            server.shutdown()
    print(f"wrote {out}")
    if problems:
        sys.exit("\n".join(problems))


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    main(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]))
