"""Check a run's exports with the tools that consume them (issue 50):

- ``mesh.glb`` with the Khronos glTF validator (npm's ``gltf-validator``: ``npm install --prefix DIR
  gltf-validator``, then ``--validator DIR``): its errors and warnings, and the attributes of each primitive;
- ``sparse/0`` read back by pycolmap: cameras, images, points;
- ``transforms.json`` against the rules of nerfstudio's own dataparser (``tests/export/test_bundle.py``'s
  ``check_nerfstudio_fields``), its optional fields listed;
- ``mesh.obj`` read by trimesh with its material and texture.

    python scripts/check_exports.py runs/temple --validator /tmp/gv
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

VALIDATE = """
const validator = require('gltf-validator');
const fs = require('fs');
validator.validateBytes(new Uint8Array(fs.readFileSync(process.argv[1]))).then(
  (report) => console.log(JSON.stringify({issues: report.issues, info: report.info})),
  (error) => { console.error(error); process.exit(1); });
"""


def glb(path: Path, validator: Path | None) -> None:
    from tests.export.test_texture import glb_json

    doc = glb_json(path)
    attributes = [sorted(p["attributes"]) for m in doc["meshes"] for p in m["primitives"]]
    print(f"{path.name}: primitives' attributes {attributes}")
    if validator is None:
        print("  (no --validator: the glTF validator not run)")
        return
    env = {**os.environ, "NODE_PATH": str(validator / "node_modules")}
    out = subprocess.run(["node", "-e", VALIDATE, str(path)], capture_output=True, text=True, env=env, check=True)
    report = json.loads(out.stdout)
    issues = report["issues"]
    print(f"  glTF validator: {issues['numErrors']} errors, {issues['numWarnings']} warnings, {issues['numInfos']} "
          f"infos, {issues['numHints']} hints; {report['info'].get('totalTriangleCount')} triangles")
    for message in issues["messages"][:10]:
        print(f"    {message['severity']}: {message['code']}: {message['message']} ({message.get('pointer', '')})")


def colmap(folder: Path) -> None:
    import pycolmap

    for kind, read in (("binary", "read_binary"), ("text", "read_text")):
        model = pycolmap.Reconstruction()
        getattr(model, read)(str(folder))
        print(f"sparse/0 ({kind}) read by pycolmap {pycolmap.__version__}: {model.num_cameras()} cameras, "
              f"{model.num_images()} images, {model.num_points3D()} points")


def transforms(folder: Path) -> None:
    from tests.export.test_bundle import check_nerfstudio_fields

    doc = json.loads((folder / "transforms.json").read_text())
    check_nerfstudio_fields(folder, doc)
    top = sorted(k for k in doc if k != "frames")
    per_frame = sorted({k for f in doc["frames"] for k in f})
    print(f"transforms.json: nerfstudio's dataparser rules met; {len(doc['frames'])} frames; top-level {top}; "
          f"per frame {per_frame}; train {len(doc.get('train_filenames', []))}, val {len(doc.get('val_filenames', []))}")


def obj(path: Path) -> None:
    import trimesh

    solid = trimesh.load(path, process=False)
    image = getattr(solid.visual.material, "image", None)
    print(f"{path.name}: {len(solid.faces)} triangles, texture {None if image is None else image.size} "
          f"({type(solid.visual).__name__})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--validator", type=Path, default=None, help="the npm prefix gltf-validator is installed in")
    args = parser.parse_args()
    exports = args.run_dir / "exports"
    glb(exports / "mesh.glb", args.validator)
    colmap(exports / "sparse" / "0")
    transforms(exports)
    obj(exports / "mesh.obj")


if __name__ == "__main__":
    main()
