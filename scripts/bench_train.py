"""Training benchmark: the paper MLP's throughput against this machine's float32 matmul rate, and one run
of the train stage on lego as ``nerfpipe run`` trains it.

Run by hand from the repository root, with ../shared beside it:

    python scripts/bench_train.py                        # fast preset, lego train split at 100x100
    python scripts/bench_train.py --preset paper --size 400 --steps 5000     # on a GPU machine

First it times the paper MLP (Fig. 7: 8x256, view branch 128) training on random samples and a large
float32 matmul, in the same process, and prints achieved / peak FLOP rate. Then it trains lego's train
split at ``--size`` pixels with the train stage (preset and ``--set`` overrides as for ``nerfpipe run``)
and prints its steps, samples/s, held-out PSNR on every 4th val view and wall time with evaluation.

Held-out PSNR against training time is ``nerfpipe bench``'s to measure, e.g.

    nerfpipe bench ../shared/data/nerf_synthetic_lego_400 --out /tmp/lego --size 100 --config fast
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import torch

from nerfpipe import Pipeline, default_stages
from nerfpipe.nerf.cpu import keep_freed_memory
from nerfpipe.nerf.device import resolve_device
from nerfpipe.nerf.fields.configs import MlpConfig
from nerfpipe.nerf.fields.mlp import NerfField
from nerfpipe.pipeline.params import parse_assignments

REPO = Path(__file__).resolve().parents[1]
LEGO = REPO.parent / "shared" / "data" / "nerf_synthetic_lego_400"


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def matmul_rate(device: torch.device, n: int = 4096, repeats: int = 10) -> float:
    """Best float32 matmul rate in FLOP/s (2 n^3 per product)."""
    a, b = torch.randn(n, n, device=device), torch.randn(n, n, device=device)
    best = float("inf")
    for _ in range(repeats):
        sync(device)
        start = time.perf_counter()
        a @ b
        sync(device)
        best = min(best, time.perf_counter() - start)
    return 2 * n**3 / best


def paper_mlp_rate(device: torch.device, samples: int, repeats: int = 6) -> tuple[float, int]:
    """Training samples per second of the paper MLP (forward, backward, Adam step), and its FLOPs per sample."""
    torch.manual_seed(0)
    field = NerfField(MlpConfig(depth=8, width=256, skip_after=5, view_width=128, dir_freqs=4, include_input=False,
                                density_activation="relu")).to(device)
    optimizer = torch.optim.Adam(field.parameters(), lr=5e-4, eps=1e-7)
    x = torch.rand(samples, 3, device=device) * 2 - 1
    d = torch.nn.functional.normalize(torch.randn(samples, 3, device=device), dim=-1)
    best = float("inf")
    for i in range(repeats):
        sync(device)
        start = time.perf_counter()
        rgb, sigma = field(x, d)
        loss = rgb.square().mean() + sigma.mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        sync(device)
        if i:  # the first step allocates
            best = min(best, time.perf_counter() - start)
    # backward costs about twice the forward pass: 3x the forward FLOPs in all
    return samples / best, 3 * field.flops_per_sample()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--size", type=int, default=100, help="longest image side for training and evaluation")
    parser.add_argument("--steps", type=int, default=None, help="override train.steps")
    parser.add_argument("--set", action="append", default=[], help="STAGE.PARAM=VALUE, as for nerfpipe run")
    parser.add_argument("--run-dir", type=Path, default=None, help="keep the run here (default: a temporary folder)")
    parser.add_argument("--skip-throughput", action="store_true")
    args = parser.parse_args()
    if not LEGO.is_dir():
        sys.exit(f"lego not found at {LEGO}: put ../shared beside the checkout")
    keep_freed_memory()
    torch.set_flush_denormal(True)  # before torch's first parallel operation, as the train stage does in the CLI
    device = resolve_device("auto", "device")
    name = torch.cuda.get_device_name() if device.type == "cuda" else f"{os.cpu_count()} CPU cores"
    print(f"machine: {name}, torch {torch.__version__}, {torch.get_num_threads()} threads, Python {sys.version.split()[0]}")

    if not args.skip_throughput:
        peak = matmul_rate(device)
        rate, flops = paper_mlp_rate(device, 65536 if device.type == "cpu" else 4096 * 192)
        print(f"float32 matmul (4096^2): {peak / 1e9:.0f} GFLOP/s")
        print(f"paper MLP training: {rate:,.0f} samples/s x {flops / 1e6:.2f} MFLOP/sample = {rate * flops / 1e9:.0f} GFLOP/s"
              f" = {100 * rate * flops / peak:.0f} % of the matmul rate")

    overrides = parse_assignments([f"ingest.max_size={args.size}", "train.eval_stride=4", *args.set])
    if args.steps is not None:
        overrides.setdefault("train", {})["steps"] = args.steps
    with tempfile.TemporaryDirectory() as tmp:
        pipe = Pipeline(default_stages(), LEGO, args.run_dir or Path(tmp) / "lego", args.preset, overrides)
        pipe.run(until="scene")
        started = time.perf_counter()
        s = pipe.run(until="train")[-1].summary
        wall = time.perf_counter() - started
    print(f"\npreset {args.preset}, lego {args.size}px, {s['train_images']} training views, {s['heldout']} held-out "
          f"({s['heldout_rule']}, every 4th): {s['steps']} steps in {s['train_seconds']:.0f} s of training "
          f"({s['samples_per_s']:,} samples/s), held-out PSNR {s['psnr']:.2f} dB, SSIM {s['ssim']:.3f}; "
          f"stage wall time {wall:.0f} s with evaluation")


if __name__ == "__main__":
    main()
