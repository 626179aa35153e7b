#!/usr/bin/env bash
# Issue 51's measurements on a lent CUDA machine, in two calls (docs/benchmarks.md, "The training step compiled at
# fixed shapes"). That machine has Python 3.12 with CUDA torch, and no pycolmap, open3d, rawpy, kornia or PyAV.
#
# Prepared here first (both folders are ignored by git, see .git/info/exclude):
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
#     -d .whl simplejpeg==1.9.0 kornia==0.9.0 kornia_rs==0.2.0
#   mkdir -p .devdata && cp -r ../shared/data/colmap_beer_yhuoyuh ../shared/data/nerf_synthetic_lego_400 .devdata/
#   nerfpipe run .devdata/colmap_beer_yhuoyuh --out .devdata/beer_run --until scene
#   nerfpipe run .devdata/nerf_synthetic_lego_400 --out .devdata/lego_run --until scene --set ingest.max_size=400
#   rm -rf .devdata/*_run/stages/{ingest,undistort}   # they run again there, to the same keys; sfm is what it lacks
# Then on the device (each call carries at most 64 MiB):
#   run(command="bash scripts/gpu_check.sh throughput tests", timeout_s=570,
#       carry=[".whl", ".devdata/colmap_beer_yhuoyuh", ".devdata/beer_run"])
#   run(command="bash scripts/gpu_check.sh lego beer", timeout_s=420,
#       carry=[".whl", ".devdata/colmap_beer_yhuoyuh", ".devdata/beer_run", ".devdata/nerf_synthetic_lego_400",
#              ".devdata/lego_run"])
# Each part writes what it printed to $OUT/PART.txt.
set -uo pipefail
OUT=${OUT:-/tmp/gpu_check}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD"
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH="$PWD:/tmp/site"
fi
PY=${PY:-python3}
BEER=.devdata/colmap_beer_yhuoyuh
LEGO=.devdata/nerf_synthetic_lego_400
(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
 $PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())") > "$OUT/machine.txt" 2>&1

throughput() {  # training samples a second on beer: the eager step (today's) against the compiled one, 2^14 and 2^18
  for run in "fast off" "fast kernels" "gpu off" "gpu kernels" "gpu graphs"; do
    set -- $run
    echo "== train preset $1, train.compile=$2"
    timeout 150 $PY scripts/bench_throughput.py --capture "$BEER" --out .devdata/beer_run --size 1600 --preset "$1" \
      --seconds 10 --window 10 --frames 1 --eval-views 1 --set "train.compile=$2" --set train.chunk=65536
  done
}

tests() {  # the CUDA suite, the compiled step's tests among them
  timeout 300 $PY -m pytest -q -p no:cacheprovider tests/nerf/test_cuda.py
}

lego() {  # 60 s of training at 400 px, scored on 10 held-out views at full size
  timeout 240 $PY -m nerfpipe bench "$LEGO" --out .devdata/lego_run --size 400 --config gpu --budget 60 \
    --checkpoints 15,30,60 --eval-views 10 --set train.eval_scale=1
}

beer() {  # the default main job from the cached sfm, as far as this machine's packages go (no open3d or PyAV)
  local start=$SECONDS
  timeout 300 $PY -m nerfpipe run "$BEER" --out .devdata/beer_run --until export_depth
  echo "beer main job to export_depth: $((SECONDS - start)) s"
  cp .devdata/beer_run/stages/train/*/metrics.json "$OUT/beer_metrics.json" 2>/dev/null
}

for part in "$@"; do
  echo "### $part"
  "$part" 2>&1 | tee "$OUT/$part.txt"
done
