"""The grid field's table gradient, ten ways: the scatter-add that is a fifth of a training step on beer.

Run by hand from the repository root:

    python scripts/bench_table_gradient.py
    python scripts/bench_table_gradient.py --rays 1600 --samples 10

Samples along random rays through the unit cube (``--rays`` x ``--samples``), their trilinear corners on the
default field's levels (32^3, 64^3 and 128^3 cells, one stacked table of 2,457,251 rows of 4 features), and a
random gradient of their features; then each way of summing the corners' contributions into the table's
gradient, in milliseconds per call (best of ``--repeat`` after one untimed call). The first nine (zeroing alone
among them) are given the corners' contributions (gradient times weight) computed; the last two compute them too:
``index_add_`` as the field did before the native kernel, and the native kernel
(``nerfpipe.nerf.native.scatter_bags``), the field's own on a CPU with a C compiler
(``nerfpipe.nerf.fields.grid._Trilinear.backward``).
"""

from __future__ import annotations

import argparse
import time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rays", type=int, default=400)
    parser.add_argument("--samples", type=int, default=40, help="samples a ray")
    parser.add_argument("--repeat", type=int, default=20)
    args = parser.parse_args()

    import torch

    from nerfpipe.nerf import native
    from nerfpipe.nerf.fields.configs import level_resolutions
    from nerfpipe.nerf.fields.grid import trilinear_corners

    torch.manual_seed(0)
    resolutions = level_resolutions(3, 32, 128)
    sizes = [(r + 1) ** 3 for r in resolutions]
    rows, features = sum(sizes), 4
    offsets = torch.tensor([0, *sizes[:-1]]).cumsum(0)
    origins = torch.rand(args.rays, 3) * 0.6 + 0.2
    directions = torch.nn.functional.normalize(torch.randn(args.rays, 3), dim=-1)
    t = torch.linspace(0.0, 0.5, args.samples)
    u = (origins[:, None] + t[None, :, None] * directions[:, None]).clamp(0.0, 1.0).reshape(-1, 3)
    index, weights = trilinear_corners(u, torch.tensor(resolutions), offsets)  # (L, 8, M)
    levels, corners, m = index.shape
    flat = index.permute(2, 0, 1).reshape(-1)
    grad = torch.randn(m * levels, features)
    contributions = (grad.unsqueeze(1) * weights.permute(2, 0, 1).reshape(-1, corners).unsqueeze(-1)).reshape(-1, features)
    table_grad = torch.zeros(rows, features)

    def index_add() -> None:
        table_grad.zero_()
        table_grad.index_add_(0, flat, contributions)

    def scatter_add() -> None:
        table_grad.zero_()
        table_grad.scatter_add_(0, flat.unsqueeze(-1).expand(-1, features), contributions)

    def index_put() -> None:
        table_grad.zero_()
        table_grad.index_put_((flat,), contributions, accumulate=True)

    def flat_index_add() -> None:
        table_grad.zero_()
        table_grad.view(-1).index_add_(0, (flat.unsqueeze(-1) * features + torch.arange(features)).reshape(-1),
                                       contributions.reshape(-1))

    def sorted_index_add() -> None:
        order = torch.argsort(flat)
        table_grad.zero_()
        table_grad.index_add_(0, flat[order], contributions[order])

    def bincount() -> None:
        table_grad.zero_()
        for f in range(features):
            table_grad[:, f] += torch.bincount(flat, weights=contributions[:, f], minlength=rows)

    def unique_then_add() -> None:
        unique, inverse = torch.unique(flat, return_inverse=True)
        summed = torch.zeros(len(unique), features).index_add_(0, inverse, contributions)
        table_grad.zero_()
        table_grad[unique] = summed

    def embedding_dense_backward() -> None:
        torch.ops.aten.embedding_dense_backward(contributions, flat, rows, -1, False)

    def zero_only() -> None:
        table_grad.zero_()

    bags = index.permute(2, 0, 1).reshape(-1, corners).contiguous()
    bag_weights = weights.permute(2, 0, 1).reshape(-1, corners).contiguous()

    def products_then_index_add() -> None:  # what the field did before the native kernel: the products, then index_add
        table_grad.zero_()
        table_grad.index_add_(0, flat, (grad.unsqueeze(1) * bag_weights.unsqueeze(-1)).reshape(-1, features))

    def native_scatter_bags() -> None:  # the field's own on a CPU with a C compiler (products included)
        table_grad.zero_()
        if not native.scatter_bags(table_grad, bags, bag_weights, grad):
            raise SystemExit("no native kernel here (no C compiler, or NERFPIPE_COMPILE=off)")

    print(f"{m} samples x {levels} levels x {corners} corners into {rows:,} rows of {features}, "
          f"{torch.get_num_threads()} threads")
    for way in (index_add, scatter_add, index_put, flat_index_add, sorted_index_add, bincount, unique_then_add,
                embedding_dense_backward, zero_only, products_then_index_add, native_scatter_bags):
        way()
        best = float("inf")
        for _ in range(args.repeat):
            started = time.perf_counter()
            way()
            best = min(best, time.perf_counter() - started)
        print(f"{way.__name__:26s} {best * 1e3:7.2f} ms")


if __name__ == "__main__":
    main()
