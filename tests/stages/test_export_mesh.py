"""The mesh method `auto` stands for, from the scene stage's decisions (the full stage runs in the temple's
end-to-end test in test_train.py, by both methods)."""

from __future__ import annotations

import numpy as np
import pytest

from nerfpipe.pipeline.params import ParamError, build_params
from nerfpipe.export.texture import spread
from nerfpipe.stages.export_mesh import ExportMeshParams, ExportMeshStage, chosen_method
from tests.nerf.scenes import scene_of


def test_auto_meshes_an_object_by_its_density_and_a_scene_by_its_agreed_points() -> None:
    assert chosen_method("auto", scene_of("inward360", "alpha")) == "marching_cubes"
    assert chosen_method("auto", scene_of("inward360", "color", color=[0.0, 0.0, 0.0])) == "marching_cubes"
    assert chosen_method("auto", scene_of("unbounded360", "none")) == "poisson"
    assert chosen_method("auto", scene_of("forward", "none")) == "poisson"
    # a method asked for by name is kept, whatever the scene
    assert chosen_method("tsdf", scene_of("unbounded360", "none")) == "tsdf"
    assert chosen_method("marching_cubes", scene_of("forward", "none")) == "marching_cubes"


def test_the_default_is_auto_and_an_unknown_method_is_a_parameter_error() -> None:
    assert build_params("export_mesh", ExportMeshParams, ExportMeshStage.presets, None, {}).method == "auto"
    assert build_params("export_mesh", ExportMeshParams, ExportMeshStage.presets, "poisson", {}).method == "poisson"
    with pytest.raises(ParamError):
        build_params("export_mesh", ExportMeshParams, ExportMeshStage.presets, None, {"method": "voxels"})


def test_the_texture_is_baked_from_photos_spread_over_the_capture() -> None:
    names = [f"{i:03d}.jpg" for i in range(62)]
    assert spread(names, 0) == names and spread(names[:14], 24) == names[:14]
    chosen = spread(names, 24)
    assert len(chosen) == 24 and chosen[0] == "000.jpg" and chosen[-1] == "061.jpg"
    steps = np.diff([int(n[:3]) for n in chosen])
    assert set(steps) <= {2, 3}  # 61 / 23 = 2.65 between neighbours: no gap, no clump
