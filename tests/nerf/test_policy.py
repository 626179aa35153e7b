"""The model a scene calls for: ray space, fields, occupancy grid and background, each with its sentence;
the paper's switches (Table 2); and the training configuration of the train parameters."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nerfpipe.geometry.cameras import Camera, CameraSet, Frame
from nerfpipe.geometry.normalize import robust_box
from nerfpipe.nerf.policy import (
    HULL_RESOLUTION,
    NDC_NEAR_FACTOR,
    build_background,
    build_model,
    carve_scene_box,
    density_noise,
    sampler_for,
)
from nerfpipe.nerf.fields.mlp import NerfField
from nerfpipe.nerf.fields.grid import GridField
from nerfpipe.nerf.spaces.ray_space import BoxSpace, ContractedSpace, NdcSpace
from nerfpipe.nerf.samplers.marching import MarchingSampler
from nerfpipe.nerf.samplers.configs import HierarchicalConfig
from nerfpipe.nerf.train.trainer import final_lr, learning_rate
from nerfpipe.pipeline.errors import ParamError
from nerfpipe.pipeline.params import build_params
from nerfpipe.stages.train import PRESETS, TrainParams
from tests.geometry.sphere_photos import CENTER, RADIUS, sphere_views
from tests.helpers import look_at
from tests.nerf.scenes import bounds_of, scene_of, world_of_one_camera

CPU = torch.device("cpu")


def train_params(values: dict) -> TrainParams:
    """The default train parameters with ``values`` (by dotted name) set, as ``--set`` sets them."""
    return build_params("train", TrainParams, PRESETS, None, values)


@pytest.mark.parametrize(
    "overrides, first_in, view_in, n_fine, fine",
    [
        # the view layer sees the 128-d feature and gamma(d) (with d itself, include_input)
        ({}, 3 + 60, 128 + 3 + 24, 64, False),
        ({"field.positional_encoding": False}, 3, 128 + 3, 64, False),  # Table 2 row 2: raw x and d
        ({"field.view_dependence": False}, 63, 128, 64, False),  # row 3: colour from x alone
        ({"sampler.hierarchical": False, "field.fine_network": True}, 63, 155, 0, False),  # row 4: N_c samples, one network
        ({"field.pos_freqs": 5, "field.dir_freqs": 2}, 3 + 30, 128 + 3 + 12, 64, False),  # rows 7-8: L
        ({"field.fine_network": True}, 63, 155, 64, True),
    ],
)
def test_ablation_switches_build_the_tables_models(overrides, first_in, view_in, n_fine, fine) -> None:
    params = train_params({"field.kind": "mlp", "field.dir_freqs": 4, **overrides})  # Section 5.1's L = 4 for d
    model, _ = build_model(params, scene_of("inward360"), world_of_one_camera(), bounds_of(), CPU)
    assert model.coarse.trunk[0].in_features == first_in
    assert model.coarse.view.in_features == view_in
    assert model.sampler.config.fine == n_fine
    assert (model.fine is not None) == fine


def test_scene_decisions_choose_the_ray_space_and_background() -> None:
    world, bounds = world_of_one_camera(), bounds_of((2.0, 9.0))
    inward, said = build_model(TrainParams(), scene_of("inward360", "alpha", [1, 1, 1]), world, bounds, CPU)
    assert inward.ray_space == BoxSpace(((-1, -1, -1), (1, 1, 1)))
    assert inward.background == (1.0, 1.0, 1.0) and isinstance(inward.sampler, MarchingSampler)
    assert said[0] == "inward 360: world rays, each clipped to the scene box and its image's near/far"
    assert inward.info == {"layout": "inward360", "photometric": "srgb", "to_sfm": np.eye(4).tolist()}
    forward, said = build_model(train_params({"field.kind": "mlp"}), scene_of("forward"), world, bounds, CPU)
    assert isinstance(forward.ray_space, NdcSpace) and forward.ray_space.near == pytest.approx(NDC_NEAR_FACTOR * 2.0)
    assert forward.ray_space.focal == 50 and forward.ray_space.size == (40, 30) and forward.background is None
    assert said == [  # one sentence a choice, in this order: ray space, (field, occupancy,) background, noise
        "forward-facing: rays in NDC of the mean camera, near plane 1.5, samples linear in NDC depth (near to infinity)",
        "no background model: the background is part of the scene (composited onto black)",
        "noise of std 1 on raw density while training",  # the authors' regularizer for real forward scenes
    ]
    assert forward.sampler.stats() == {}  # the paper's sampler unless asked
    unbounded, said = build_model(train_params({"field.kind": "mlp"}), scene_of("unbounded360", photometric="linear_raw"),
                                  world, bounds, CPU)
    assert unbounded.sampler.config.lindisp
    assert unbounded.ray_space == ContractedSpace(((-1, -1, -1), (1, 1, 1)))  # the scene box, kept as it is
    assert said == ["unbounded 360: world rays over each image's near/far; the scene box at full resolution and the "
                    "space beyond it contracted into a shell around it (mip-NeRF 360, Eq. 10), steps growing with distance",
                    "no background model: the background is part of the scene (composited onto black)",
                    "linear RAW: trained on linear values; previews are sRGB-encoded"]
    clipped, said = build_model(train_params({"field.kind": "mlp", "space.contract": "off"}), scene_of("unbounded360"), world, bounds, CPU)
    assert isinstance(clipped.ray_space, BoxSpace) and said[0] == (
        "unbounded 360: world rays over each image's near/far, samples linear in disparity")


def test_inward_captures_contract_unless_a_backdrop_or_alpha_bounds_them() -> None:
    world, bounds = world_of_one_camera(), bounds_of((2.0, 9.0))
    for background, color in (("alpha", [1, 1, 1]), ("color", [0, 0, 0])):
        model, _ = build_model(TrainParams(), scene_of("inward360", background, color), world, bounds, CPU)
        assert isinstance(model.ray_space, BoxSpace) and model.ray_space.box is not None
    room, said = build_model(TrainParams(), scene_of("inward360", "none"), world, bounds, CPU)
    assert room.ray_space == ContractedSpace(((-1, -1, -1), (1, 1, 1)))
    assert said[0].startswith("inward 360 with the background part of the scene: world rays over each image's near/far")
    assert room.coarse.lo.tolist() == [-2] * 3 and room.sampler.grid.hi.tolist() == [2] * 3  # the contracted cube
    forced, _ = build_model(train_params({"space.contract": "on"}), scene_of("inward360", "alpha", [1, 1, 1]), world, bounds, CPU)
    assert isinstance(forced.ray_space, ContractedSpace)


def test_contracted_space_keeps_the_scene_box_or_the_cameras_too_at_full_resolution() -> None:
    # cameras 4 units away from a scene box of half-size 1 stand where the photos' floor and walls are
    frames = [Frame(f"{i}.png", 1, look_at(np.array([4.0 * np.cos(a), 4.0 * np.sin(a), 1.0]), np.zeros(3)))
              for i, a in enumerate(np.linspace(0, np.pi, 5))]
    world, bounds = CameraSet({1: Camera.pinhole(50, 50, 20, 15, 40, 30)}, frames), bounds_of((2.0, 9.0))
    around, said = build_model(train_params({"space.contract_around": "cameras"}), scene_of("inward360", "none"),
                               world, bounds, CPU)
    lo, hi = np.array(around.ray_space.box)
    # x from -4 to 4, y from -1 (the box) to 4, z from -1 to 1 (the box, above the cameras' 1), 5 % more a side
    np.testing.assert_allclose(lo, [-4.4, -1.25, -1.1], atol=1e-9)
    np.testing.assert_allclose(hi, [4.4, 4.25, 1.1], atol=1e-9)
    assert "the box of the scene and the cameras at full resolution" in said[0]
    scene_only, said = build_model(TrainParams(), scene_of("inward360", "none"), world, bounds, CPU)
    assert scene_only.ray_space == ContractedSpace(((-1, -1, -1), (1, 1, 1))) and "the scene box at full resolution" in said[0]


def test_the_default_grid_field_marches_the_box_or_the_ndc_frustum() -> None:
    world, bounds = world_of_one_camera(), bounds_of((2.0, 9.0))
    inward, said = build_model(TrainParams(), scene_of("inward360", "alpha", [1, 1, 1]), world, bounds, CPU)
    assert isinstance(inward.coarse, GridField) and inward.fine is None
    assert "occupancy" in inward.sampler.stats() and inward.sampler.grid.resolution == 64
    assert inward.sampler.grid.lo.tolist() == [-1] * 3 and inward.coarse.hi.tolist() == [1] * 3
    assert said[1] == "grid field: 3 levels of [32, 64, 128] cells a side, 4 features each, and a 64-wide MLP"
    # colour reads the 15 geometric features and the unit direction d itself, no sines of it (L = 0)
    assert inward.coarse.color_net[0].in_features == 15 + 3
    assert said[2].startswith("empty-space skipping: a 64^3 occupancy grid over the field box")
    forward, said = build_model(TrainParams(), scene_of("forward"), world, bounds, CPU)
    # NDC's [-1, 1]^2 x [-1, 1 - 2 near / far]: the frustum out to the farthest bound
    z_max = 1 - 2 * (0.75 * 2.0) / 9.0
    assert forward.sampler.grid.hi.tolist() == pytest.approx([1, 1, z_max]) and forward.sampler.grid.lo.tolist() == [-1] * 3
    assert not any("noise" in line for line in said)  # a regularizer of the MLP's raw density only
    unbounded, said = build_model(TrainParams(), scene_of("unbounded360"), world, bounds, CPU)
    assert isinstance(unbounded.coarse, GridField) and "occupancy" in unbounded.sampler.stats()  # no MLP fallback
    assert unbounded.coarse.lo.tolist() == [-2] * 3 and unbounded.coarse.hi.tolist() == [2] * 3
    # contracted, a ray crosses the shell's fog: MLPs half as wide, saved so (the spec holds 32, not "by the space")
    assert said[1].endswith("and a 32-wide MLP") and unbounded.coarse.color_net[2].in_features == 32
    assert unbounded.spec.field.hidden == 32 and inward.spec.field.hidden == 64
    wide, said = build_model(train_params({"field.hidden": 48}), scene_of("unbounded360"), world, bounds, CPU)
    assert wide.coarse.density_net[0].out_features == 48 and said[1].endswith("and a 48-wide MLP")  # as set
    uncontracted, said = build_model(train_params({"space.contract": "off"}), scene_of("unbounded360"), world, bounds, CPU)
    assert isinstance(uncontracted.coarse, NerfField) and uncontracted.sampler.stats() == {}
    assert "unbounded 360: the grid field needs a bounded box, so the MLP (Fig. 7) is trained" in said
    mlp_grid, _ = build_model(train_params({"field.kind": "mlp", "sampler.kind": "marching"}), scene_of("inward360"),
                              world, bounds, CPU)
    assert isinstance(mlp_grid.coarse, NerfField) and isinstance(mlp_grid.sampler, MarchingSampler)


def test_sampler_and_background_builders_say_why_not() -> None:
    config, said = sampler_for(train_params({"field.kind": "mlp", "sampler.kind": "marching"}), None, "unbounded360")
    assert config == HierarchicalConfig(lindisp="on")  # unbounded: linear in disparity
    assert said == "no occupancy grid: an unbounded scene has no box to grid; Section 5.2's sampling instead"
    config, said = sampler_for(train_params({"field.kind": "mlp"}), ((-1.0,) * 3, (1.0,) * 3), "inward360")
    assert config == HierarchicalConfig(n_coarse=32, n_fine=64, lindisp="off")
    assert said is None  # auto: the paper's sampling for the MLP, which needs no sentence
    assert build_background(scene_of("inward360", "color", [0, 0.5, 1])) == (
        (0.0, 0.5, 1.0), "background color: renders composited onto (0.00, 0.50, 1.00)")
    assert build_background(scene_of("inward360", "alpha", None))[0] is None  # no colour decided: none
    assert build_background(scene_of("inward360", "color", [0, 0, 0], tolerance=0.1)) == ((0.0, 0.0, 0.0), (
        "background color: the backdrop (pixels within 0.1 of (0.00, 0.00, 0.00) joined to the image border, "
        "grown by GrabCut over what looks like them) trains empty space against a random colour per ray; renders composited onto (0.00, 0.00, 0.00)"))


def test_the_trainer_reads_the_train_parameters_and_the_scene_decides_the_noise() -> None:
    params = train_params({"field.kind": "mlp", "optim.lr": 3e-3, "optim.lr_final": 1e-4})
    assert params.sampler.kind == "hierarchical"  # sampler.kind=auto: the one the MLP asks for
    assert density_noise(params, "forward") == 1.0 and density_noise(params, "inward360") == 0.0
    default = TrainParams()
    assert not default.tf32 and (default.steps, default.seconds) == (0, 120.0)  # trained by time
    assert (default.optim.lr, final_lr(default.optim), default.optim.mlp_lr_share) == (3e-2, 9e-3, 0.33)
    # exponential decay from lr to lr_final over the training, by the share done
    assert learning_rate(default, 0.0) == 3e-2 and learning_rate(default, 1.0) == pytest.approx(9e-3)
    assert learning_rate(default, 0.5) == pytest.approx((3e-2 * 9e-3) ** 0.5)
    # a learning rate set below the default final one trains at that rate throughout, not upwards
    assert final_lr(train_params({"optim.lr": 1e-3}).optim) == 1e-3
    assert density_noise(TrainParams(), "forward") == 0.0  # the grid field has no raw-density regularizer
    assert density_noise(train_params({"field.kind": "mlp", "optim.density_noise": "0.5"}), "inward360") == 0.5
    assert default.optim.distortion == 0.0  # off unless asked for (measured on beer, it cost more than it gave)
    with pytest.raises(ParamError, match="distortion must be >= 0|outside its bounds"):
        train_params({"optim.distortion": -1.0})


def test_per_image_exposure_and_camera_refinement_follow_the_data_unless_set() -> None:
    world, bounds, cpu = world_of_one_camera(), bounds_of((2.0, 6.0)), torch.device("cpu")
    names = ["a.png", "b.png", "c.png"]
    varying = scene_of("inward360", "color", [0, 0, 0], stops={"a.png": 0.5, "b.png": -0.5})
    model, said = build_model(TrainParams(), varying, world, bounds, cpu, names)
    # exposure varies: gains start from the measured stops (c.png unmeasured: 0), centred; photos: poses refined
    assert model.appearance is not None and model.refinement is not None
    assert torch.allclose(model.appearance.stops()[:, 0], torch.tensor([0.5, -0.5, 0.0]))
    assert any("exposure varies" in s for s in said) and any("no sparse points to check" in s for s in said)
    rendered, said = build_model(TrainParams(), scene_of("inward360", "alpha", [1, 1, 1]), world, bounds, cpu, names)
    assert rendered.appearance is None and rendered.refinement is None  # constant exposure; exact rendered poses
    assert any("exact" in s for s in said) and any("exposure constant" in s for s in said)
    forced, said = build_model(train_params({"per_image.appearance": "on", "per_image.refine_poses": "off"}), scene_of("inward360"), world, bounds,
                               cpu, names)
    assert forced.appearance is not None and forced.refinement is None
    assert "train.per_image.appearance=on" in " ".join(said) and "train.per_image.refine_poses=off" in " ".join(said)
    # poses whose points reproject within POSE_ERROR_PX (2 px) are kept, the cup's 1.29 px among them; beyond, refined
    from nerfpipe.geometry.cameras import CameraSet, Points

    for error, refined in ((0.4, False), (1.29, False), (2.6, True)):
        points = Points(np.zeros((3, 3)), np.zeros((3, 3), np.uint8), np.full(3, error), [np.arange(3)])
        checked = CameraSet(world.cameras, world.frames, points)
        model, said = build_model(TrainParams(), varying, checked, bounds, cpu, names)
        assert (model.refinement is not None) == refined and f"{error:.2f} px" in " ".join(said)
    without_names, _ = build_model(TrainParams(), varying, world, bounds, cpu)  # nothing per image to learn
    assert without_names.appearance is None and without_names.refinement is None


def test_silhouettes_shrink_the_scene_box_and_the_grids_over_it_to_their_visual_hull() -> None:
    views, world, bounds = sphere_views(), world_of_one_camera(), bounds_of((2.0, 9.0))  # a sphere in [-1, 1]^3
    scene = scene_of("inward360", "alpha", [1, 1, 1])
    model, said = build_model(TrainParams(), scene, world, bounds, CPU, silhouettes=views)
    lo, hi = (np.array(corner) for corner in model.ray_space.box)
    cell = 2 / HULL_RESOLUTION
    assert np.all(lo <= CENTER - RADIUS - cell + 1e-6) and np.all(hi >= CENTER + RADIUS + cell - 1e-6)
    assert np.all(hi - lo < 2 * RADIUS + 8 * cell)  # the ring looks down at it: a little taller than the sphere
    assert model.coarse.lo.tolist() == pytest.approx(lo.tolist()) and model.coarse.hi.tolist() == pytest.approx(hi.tolist())
    assert model.sampler.grid.lo.tolist() == pytest.approx(lo.tolist()) and model.sampler.grid.hi.tolist() == pytest.approx(hi.tolist())
    assert said[0].startswith("visual hull of 12 silhouettes: the scene box shrinks from 2.00 x 2.00 x 2.00 to ")
    # not asked for, or no box to shrink: the scene box as the bounds stage made it
    for params, kind in ((train_params({"space.hull": "off"}), scene), (TrainParams(), scene_of("inward360", "none")),
                         (train_params({"field.kind": "mlp"}), scene_of("forward", "alpha", [1, 1, 1]))):
        kept, said = build_model(params, kind, world, bounds, CPU, silhouettes=views)
        assert not said[0].startswith("visual hull")
        assert getattr(kept.ray_space, "box", None) in (None, ((-1, -1, -1), (1, 1, 1)))  # NDC has none
    kept, _ = build_model(TrainParams(), scene, world, bounds, CPU)  # no silhouettes
    assert kept.ray_space.box == ((-1, -1, -1), (1, 1, 1))


def test_the_visual_hull_never_cuts_off_the_sparse_points() -> None:
    # silhouettes of the sphere, and points SfM triangulated on a part the masks lost (x up to 0.9)
    views, bounds = sphere_views(), bounds_of((2.0, 9.0))
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(200, 3))
    on_sphere = CENTER + RADIUS * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    lost = np.column_stack([rng.uniform(0.5, 0.9, 100), rng.uniform(-0.1, 0.1, 100), rng.uniform(-0.1, 0.1, 100)])
    points = np.vstack([on_sphere, lost])
    carved, said = carve_scene_box(TrainParams(), bounds, views, points)
    lo, hi = (np.array(c) for c in carved.scene_box)
    p_lo, p_hi = robust_box(points)
    assert np.all(lo <= p_lo + 1e-9) and np.all(hi >= p_hi - 1e-9) and hi[0] > 0.85
    assert hi[1] < 0.5 and said.endswith("kept around the sparse points), the grids' cells with it")
    inside, said = carve_scene_box(TrainParams(), bounds, views, on_sphere)  # points within the hull: no say
    assert "sparse points" not in said and inside.scene_box[1][0] < 0.7
