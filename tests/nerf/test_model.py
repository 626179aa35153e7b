"""RadianceModel: saved and loaded with its per-image parts, built from its spec, refusing pickles."""

from __future__ import annotations

import pytest
import torch

from nerfpipe.nerf.spaces.ray_space import NdcSpace


def test_per_image_exposure_and_camera_corrections_are_saved_and_loaded(tmp_path) -> None:
    from nerfpipe.nerf.policy import build_model
    from nerfpipe.nerf.model import RadianceModel
    from nerfpipe.stages.train import TrainParams
    from tests.nerf.scenes import bounds_of, scene_of, world_of_one_camera

    scene = scene_of("inward360", "color", [0, 0, 0], photometric="linear_raw", stops={"a.png": 1.0, "b.png": 0.0})
    model, _ = build_model(TrainParams(), scene, world_of_one_camera(), bounds_of((2.0, 6.0)), torch.device("cpu"),
                           ["a.png", "b.png"])
    with torch.no_grad():
        model.refinement.tangent.copy_(torch.arange(12.0).reshape(2, 6) / 100)
    model.save(tmp_path)
    loaded = RadianceModel.load(tmp_path)
    assert loaded.appearance.linear is True  # linear RAW: no sRGB curve around the gains
    assert torch.equal(loaded.appearance.log2_gains, model.appearance.log2_gains)
    assert torch.equal(loaded.refinement.tangent, model.refinement.tangent)


def test_a_model_is_built_from_its_spec_and_the_spec_survives_json(tmp_path) -> None:
    import json

    from nerfpipe.nerf.policy import build_model, resolve_spec
    from nerfpipe.nerf.model import RadianceModel, build
    from nerfpipe.nerf.spec import ModelSpec
    from nerfpipe.stages.train import TrainParams
    from tests.nerf.scenes import bounds_of, scene_of, world_of_one_camera

    scene = scene_of("forward", stops={"a.png": 0.5, "b.png": -0.5})
    args = (TrainParams(), scene, world_of_one_camera(), bounds_of((2.0, 6.0)))
    spec, said = resolve_spec(*args, ["a.png", "b.png"])
    model, said_again = build_model(*args, torch.device("cpu"), ["a.png", "b.png"])
    assert said == said_again and model.spec == spec  # resolving, then building, is what build_model does
    assert spec.field.kind == "grid" and spec.sampler.kind == "marching" and isinstance(spec.ray_space, NdcSpace)
    assert ModelSpec.from_json(json.loads(json.dumps(spec.to_json()))) == spec
    # the same seed builds the same weights; a saved model loads back through the same build
    torch.manual_seed(0)
    twin = build(spec)
    torch.manual_seed(0)
    assert torch.equal(twin.coarse.table, build(spec).coarse.table)
    model.save(tmp_path)
    loaded = RadianceModel.load(tmp_path)
    assert loaded.spec == spec and torch.equal(loaded.coarse.table, model.coarse.table)


class _RunsCode:
    """A pickle that would run code when loaded without ``weights_only``; it must never be."""

    def __reduce__(self):
        return (print, ("this pickle ran code",))


def test_a_model_pt_holding_python_objects_is_refused_with_one_line(tmp_path, capsys) -> None:
    from nerfpipe.nerf.model import load_tensors
    from nerfpipe.pipeline.errors import InputError

    torch.save({"weights": _RunsCode()}, tmp_path / "model.pt")
    with pytest.raises(InputError) as err:
        load_tensors(tmp_path / "model.pt", "cpu", "model")
    line = str(err.value)
    assert line == (f"{tmp_path / 'model.pt'}: is not a nerfpipe model: it holds Python objects, not only tensors, so "
                    "it was not loaded; rerun with `--force train` to train it again; load models only from sources "
                    "you trust")
    assert "\n" not in line and "weights_only" not in line
    assert "this pickle ran code" not in capsys.readouterr().out


def test_a_checkpoint_holding_python_objects_is_passed_over_for_the_one_before(tmp_path, caplog) -> None:
    from nerfpipe.nerf.train.checkpoints import load_latest_checkpoint

    torch.save({"step": 10, "x": torch.ones(2)}, tmp_path / "step_0000010.pt")
    torch.save({"step": 20, "x": _RunsCode()}, tmp_path / "step_0000020.pt")
    (tmp_path / "step_0000030.pt").write_bytes(b"PK\x03\x04 not a whole zip")
    with caplog.at_level("WARNING"):
        state = load_latest_checkpoint(tmp_path, torch.device("cpu"))
    assert state["step"] == 10
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and all("\n" not in line and "weights_only" not in line for line in lines)
    assert lines[0].startswith("checkpoint step_0000030.pt is unreadable (")
    assert lines[1] == ("checkpoint step_0000020.pt is not a nerfpipe checkpoint (it holds Python objects, not only "
                        "tensors) and was not loaded; trying the one before")


def test_a_checkpoint_write_that_fails_leaves_no_temporary_file(tmp_path, monkeypatch) -> None:
    import errno

    from nerfpipe.nerf.train import checkpoints
    from nerfpipe.nerf.policy import build_model
    from nerfpipe.stages.train import TrainParams
    from tests.nerf.scenes import bounds_of, scene_of, world_of_one_camera

    model, _ = build_model(TrainParams(), scene_of("forward"), world_of_one_camera(), bounds_of((2.0, 6.0)),
                           torch.device("cpu"), ["a.png"])
    optimizer = torch.optim.Adam(model.coarse.parameters())
    real_save = torch.save

    def disk_fills(state, path):  # writes part of the file, then the disk is full
        real_save({"part": torch.zeros(1000)}, path)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(checkpoints.torch, "save", disk_fills)
    with pytest.raises(OSError):
        checkpoints.save_checkpoint(tmp_path / "ck", 5, 1.0, model, optimizer, keep=3)
    assert list((tmp_path / "ck").iterdir()) == []
    monkeypatch.setattr(checkpoints.torch, "save", real_save)
    assert checkpoints.save_checkpoint(tmp_path / "ck", 5, 1.0, model, optimizer, keep=3).name == "step_0000005.pt"


def test_a_model_json_of_an_older_nerfpipe_is_one_line_naming_it(tmp_path) -> None:
    import json

    from nerfpipe.nerf.model import RadianceModel
    from nerfpipe.pipeline.errors import InputError

    older = {"field": {"kind": "grid", "field": {"levels": 2}, "field_box": [[-1] * 3, [1] * 3]},
             "sampler": {"kind": "marching", "occupancy": {}}, "ray_space": {"kind": "box", "box": None},
             "fine_network": False, "background": None}
    (tmp_path / "model.json").write_text(json.dumps(older))
    with pytest.raises(InputError, match="model.json: is not a model this nerfpipe can build") as err:
        RadianceModel.load(tmp_path)
    assert "--force train" in str(err.value)
