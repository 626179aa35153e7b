"""The dense grid field's features and their gradient, torch's way and the native kernels', in milliseconds.

Run by hand from the repository root:

    python scripts/bench_grid_kernels.py
    python scripts/bench_grid_kernels.py --rays 4096 --samples 32     # a rendering chunk

The default field's levels (32^3, 64^3 and 128^3 cells, one table of 2,457,251 rows of 4 features) and points along
random rays through its box (``--rays`` x ``--samples``: 16,000, about beer's training step), or ``--random``
points scattered over the box (the occupancy grid's refresh). Each way is timed as a call within a training step
sees it: after a small matrix product (torch's threads have just run and are waiting for work), best of
``--repeat`` after one untimed call:

- ``torch``: the corners as some twenty operations (``trilinear_corners``), then ``F.embedding_bag`` (forward), and
  their contributions scattered by ``native.scatter_bags`` (backward): the field before the gather kernel;
- ``native, 1 thread`` and ``native, N threads``: ``native.grid_gather`` and ``native.grid_scatter``, which make
  the corners themselves (``nerfpipe.nerf.fields.grid._NativeGrid``), on one thread and on torch's.

The backward times include zeroing the table's gradient, as every step does.
"""

from __future__ import annotations

import argparse
import time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rays", type=int, default=400)
    parser.add_argument("--samples", type=int, default=40, help="samples a ray")
    parser.add_argument("--random", action="store_true", help="points scattered over the box instead of along rays")
    parser.add_argument("--repeat", type=int, default=30)
    args = parser.parse_args()

    import torch

    from nerfpipe.nerf import native
    from nerfpipe.nerf.cpu import keep_freed_memory
    from nerfpipe.nerf.fields.grid import GridField, gather_corners

    keep_freed_memory()
    if native.library() is None:
        raise SystemExit("no native kernels here (no C compiler, or NERFPIPE_COMPILE=off)")
    torch.manual_seed(0)
    field = GridField((-1.0, -2.0, -1.5), (1.0, 2.0, 1.5))
    table = field.table.detach()
    box = (field.lo, field.hi, field.resolutions, field.offsets)
    m = args.rays * args.samples
    if args.random:
        x = field.lo + (field.hi - field.lo) * torch.rand(m, 3)
    else:
        origins = field.lo + (field.hi - field.lo) * (torch.rand(args.rays, 1, 3) * 0.6 + 0.2)
        directions = torch.nn.functional.normalize(torch.randn(args.rays, 1, 3), dim=-1)
        x = (origins + directions * torch.linspace(0.0, 2.0, args.samples).view(1, -1, 1)).reshape(-1, 3)
    grad = torch.randn(m, 3, table.shape[1])
    table_grad = torch.zeros_like(table)
    a, b = torch.randn(m, 12), torch.randn(12, 32)

    def torch_forward() -> None:
        gather_corners(table, *field.corners((x - field.lo) / (field.hi - field.lo)))

    def torch_backward() -> None:  # the corners come from the forward pass; here made again, as they are not kept
        index, weights = field.corners((x - field.lo) / (field.hi - field.lo))
        table_grad.zero_()
        native.scatter_bags(table_grad, index.permute(2, 0, 1).reshape(-1, 8), weights.permute(2, 0, 1).reshape(-1, 8),
                            grad.view(-1, table.shape[1]))

    def native_forward() -> None:
        native.grid_gather(table, x, *box)

    def native_backward() -> None:
        table_grad.zero_()
        native.grid_scatter(table_grad, x, *box, grad)

    def timed(way) -> float:
        way()
        best = float("inf")
        for _ in range(args.repeat):
            a @ b  # torch's threads busy just before, as in a step
            started = time.perf_counter()
            way()
            best = min(best, time.perf_counter() - started)
        return best * 1e3

    threads = torch.get_num_threads()
    print(f"{m:,} points ({'scattered' if args.random else 'along rays'}), 3 levels x 8 corners, {threads} threads")
    print("| way | forward ms | backward ms (zeroing included) |\n|:--|--:|--:|")
    print(f"| torch's corners, embedding_bag, scatter_bags | {timed(torch_forward):.2f} | {timed(torch_backward):.2f} |")
    torch.set_num_threads(1)
    print(f"| native, 1 thread | {timed(native_forward):.2f} | {timed(native_backward):.2f} |")
    torch.set_num_threads(threads)
    print(f"| native, {threads} threads | {timed(native_forward):.2f} | {timed(native_backward):.2f} |")


if __name__ == "__main__":
    main()
