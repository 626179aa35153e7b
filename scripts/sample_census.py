"""Where a trained model's samples are: marched, visible, in the contracted shell, and how much each carries.

Run by hand from the repository root, on a run whose train stage has finished:

    python scripts/sample_census.py runs/beer
    python scripts/sample_census.py runs/beer --rays 8000

It draws ``--rays`` training rays (as the train stage's loader gives them), marches them through the model's
occupancy grid as training does (deterministic), keeps what they reach before their transmittance falls below
the sampler's ``early_stop``, and prints per ray: samples marched and visible; the share of visible samples in
the contracted shell (a field point beyond [-1, 1]^3, in contracted space); how many have an opacity (1 - exp(-sigma delta)) or a
weight of at least a few thresholds, and the share of the rays' weight those carry; the mean accumulated
opacity. A field whose rays hold most samples above an opacity of 0.01 is a fog, not empty space that a
threshold could skip.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a run directory (nerfpipe run --out)")
    parser.add_argument("--rays", type=int, default=4000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    import torch

    from nerfpipe import Pipeline, default_stages
    from nerfpipe.nerf.train.images import ImageLoader, split_views
    from nerfpipe.nerf.samplers.march import at_samples, march, visible
    from nerfpipe.nerf.model import RadianceModel
    from nerfpipe.nerf.spaces.ray_space import ContractedSpace
    from nerfpipe.nerf.render.volume import optical_depth

    pipe = Pipeline.from_run_dir(default_stages(), args.run)
    params = pipe.plan()["train"].params
    loader = ImageLoader.from_inputs(pipe.stage_inputs("train"))
    views = split_views(loader.world, params.holdout_every, params.train_images, params.eval_stride)
    model = RadianceModel.load(pipe.result("train").path)
    pixels = loader.pixel_set(views.train)
    index = torch.randint(pixels.rgb.shape[0], (args.rays,), generator=torch.Generator().manual_seed(args.seed))
    image = pixels.image[index]
    rays = model.ray_space.rays(pixels.uv[index], pixels.intrinsics[image], pixels.c2w[image], pixels.near[image],
                                pixels.far[image])
    sampler, space = model.sampler, model.ray_space
    with torch.no_grad():
        marched = march(rays, space, sampler.grid, sampler.config.steps, False)
        kept = visible(rays, space, marched, at_samples(rays, space, model.coarse.density_features), sampler.config.early_stop, 16)
        points = space.field_points(rays.points(kept.ray, kept.t))
        sigma = model.coarse.query_density(points).float()
        tau = optical_depth(sigma, (kept.ends - kept.starts).clamp_min(0.0)).double()
        alpha = -torch.expm1(-tau)
        weight = torch.exp(-kept.exclusive_sums(tau)) * alpha
    n = len(rays)
    total = float(weight.sum())
    print(f"{args.run}: {n} training rays, {len(marched) / n:.2f} samples a ray marched, {len(kept) / n:.2f} visible")
    if isinstance(space, ContractedSpace):
        print(f"in the contracted shell: {float((points.abs().amax(dim=-1) > 1.0).float().mean()):.1%} of the visible")
    for name, values in (("opacity", alpha), ("weight", weight)):
        for threshold in (1e-3, 1e-2, 3e-2):
            over = values >= threshold
            print(f"{name} >= {threshold:g}: {int(over.sum()) / n:.2f} a ray, "
                  f"{float(weight[over].sum()) / max(total, 1e-12):.1%} of the weight")
    print(f"mean accumulated opacity {float(kept.per_ray(weight).mean()):.3f}")


if __name__ == "__main__":
    main()
