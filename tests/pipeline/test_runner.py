"""The engine on real photos: keys, reruns, reasons, selection, restore and pruning."""

from __future__ import annotations

import json
import os
import shutil

import pytest

from nerfpipe.pipeline import ArtifactStore, ParamError, Pipeline, UpstreamNotReadyError
from nerfpipe.pipeline.hashing import sha256_file
from tests.helpers import TEMPLE, two_stages


def pipe(capture, run_dir, **kwargs) -> Pipeline:
    return Pipeline(two_stages(), capture, run_dir, **kwargs)


def keys(p: Pipeline) -> dict[str, str]:
    return {name: planned.key for name, planned in p.plan().items()}


def test_cache_key_changes_exactly_when_a_param_photo_or_upstream_changes(capture, tmp_path):
    run_dir = tmp_path / "run"
    base = keys(pipe(capture, run_dir))
    # ingest parameter: ingest and (through its key) count move
    k = keys(pipe(capture, run_dir, overrides={"ingest": {"max_size": "800"}}))
    assert k["ingest"] != base["ingest"] and k["count"] != base["count"]
    # downstream parameter: only count moves
    k = keys(pipe(capture, run_dir, overrides={"count": {"label": "n"}}))
    assert k["ingest"] == base["ingest"] and k["count"] != base["count"]
    # a value equal to the default, given as text, is the same parameter value: nothing moves
    assert keys(pipe(capture, run_dir, overrides={"ingest": {"max_size": "1600"}})) == base
    # touching a photo without changing its bytes, or adding a side-car file: nothing moves
    photo = capture / "templeSR0001.png"
    st = photo.stat()
    os.utime(photo, ns=(st.st_atime_ns, st.st_mtime_ns + 5 * 10**9))
    (capture / "notes.txt").write_text("shot on a tripod")
    assert keys(pipe(capture, run_dir)) == base
    # a modified photo moves ingest and count
    shutil.copy(TEMPLE / "templeSR0010.png", photo)
    k = keys(pipe(capture, run_dir))
    assert k["ingest"] != base["ingest"] and k["count"] != base["count"]


def test_rerun_with_nothing_changed_recomputes_nothing(capture, tmp_path, monkeypatch):
    run_dir = tmp_path / "run"
    first = pipe(capture, run_dir).run()
    assert [o.action for o in first] == ["ran", "ran"]
    committed = {o.name: (o.path / "manifest.json").stat().st_mtime_ns for o in first}

    import nerfpipe.pipeline.fingerprint as fingerprint
    import nerfpipe.stages.ingest as ingest

    hashed = []
    monkeypatch.setattr(fingerprint, "sha256_file", lambda p: hashed.append(p))
    monkeypatch.setattr(ingest.IngestStage, "run", lambda *a: pytest.fail("ingest ran again"))
    second = pipe(capture, run_dir).run()
    assert [o.action for o in second] == ["cached", "cached"]
    assert hashed == []  # photos were only stat'ed
    assert {o.name: (o.path / "manifest.json").stat().st_mtime_ns for o in second} == committed


def test_manifest_records_params_inputs_outputs_timings_and_libraries(capture, tmp_path):
    outcome = pipe(capture, tmp_path / "run").run(until="ingest")[0]
    manifest = json.loads((outcome.path / "manifest.json").read_text())
    assert manifest["stage"] == "ingest" and manifest["key"] == outcome.key == outcome.path.name
    assert manifest["params"]["max_size"] == 1600
    assert sorted(manifest["inputs"]) == [f"templeSR000{i}.png" for i in range(1, 5)]
    assert manifest["inputs"]["templeSR0001.png"]["sha256"] == sha256_file(capture / "templeSR0001.png")
    for rel, meta in manifest["outputs"].items():
        assert sha256_file(outcome.path / rel) == meta["sha256"]
        assert (outcome.path / rel).stat().st_size == meta["size"]
    assert "images.json" in manifest["outputs"] and "images/templeSR0001.png" in manifest["outputs"]
    assert manifest["timings"]["seconds"] >= 0
    assert {"python", "nerfpipe", "numpy", "rawpy"} <= set(manifest["libraries"])
    assert manifest["summary"]["images"] == 4


def test_status_reasons(capture, tmp_path):
    run_dir = tmp_path / "run"
    assert [s.state for s in pipe(capture, run_dir).status()] == ["missing", "missing"]
    pipe(capture, run_dir).run()
    assert [(s.state, s.reasons) for s in pipe(capture, run_dir).status()] == [("fresh", ()), ("fresh", ())]

    changed = pipe(capture, run_dir, overrides={"ingest": {"max_size": "800"}}).status()
    assert changed[0].state == "stale"
    assert changed[0].reasons == ("params changed: ingest.max_size 1600 -> 800",)
    assert changed[1].reasons == ("upstream ingest changed",)

    shutil.copy(TEMPLE / "templeSR0005.png", capture)
    shutil.copy(TEMPLE / "templeSR0006.png", capture)
    shutil.copy(TEMPLE / "templeSR0009.png", capture / "templeSR0002.png")
    photos = Pipeline.from_run_dir(two_stages(), run_dir).status()
    assert photos[0].reasons == ("photos changed: 2 added (templeSR0005.png, templeSR0006.png), 1 modified "
                                 "(templeSR0002.png)",)
    (capture / "templeSR0003.png").unlink()
    assert Pipeline.from_run_dir(two_stages(), run_dir).status()[0].reasons == (
        "photos changed: 2 added (templeSR0005.png, templeSR0006.png), 1 modified (templeSR0002.png), 1 removed "
        "(templeSR0003.png)",
    )


def test_status_reads_the_last_runs_settings_and_previews_changes(capture, tmp_path):
    run_dir = tmp_path / "run"
    pipe(capture, run_dir, overrides={"ingest": {"max_size": "800"}}).run()
    assert [s.state for s in Pipeline.from_run_dir(two_stages(), run_dir).status()] == ["fresh", "fresh"]
    preview = Pipeline.from_run_dir(two_stages(), run_dir, overrides={"ingest": {"max_size": "1600"}}).status()
    assert preview[0].reasons == ("params changed: ingest.max_size 800 -> 1600",)


def test_switching_a_parameter_back_restores_without_recomputing(capture, tmp_path, monkeypatch):
    run_dir = tmp_path / "run"
    first = pipe(capture, run_dir).run()
    pipe(capture, run_dir, overrides={"ingest": {"max_size": "200"}}).run()
    import nerfpipe.stages.ingest as ingest

    monkeypatch.setattr(ingest.IngestStage, "run", lambda *a: pytest.fail("ingest ran again"))
    back = pipe(capture, run_dir).run()
    assert [o.action for o in back] == ["restored", "restored"]
    assert [o.path for o in back] == [o.path for o in first]
    assert [s.state for s in pipe(capture, run_dir).status()] == ["fresh", "fresh"]


def test_until_only_and_force(capture, tmp_path):
    run_dir = tmp_path / "run"
    assert [o.name for o in pipe(capture, run_dir).run(until="ingest")] == ["ingest"]
    assert [s.state for s in pipe(capture, run_dir).status()] == ["fresh", "missing"]
    assert [(o.name, o.action) for o in pipe(capture, run_dir).run(only="count")] == [("count", "ran")]

    # --only on a stage whose upstream is stale says which and why
    with pytest.raises(UpstreamNotReadyError, match=r"upstream stage ingest is stale \(params changed: ingest.max_size 1600 -> 300\)"):
        pipe(capture, run_dir, overrides={"ingest": {"max_size": "300"}}).run(only="count")

    forced = pipe(capture, run_dir).run(force=["ingest"])
    # ingest reran to the same bytes: count, built on them, is kept (early cutoff), and status says why
    assert [(o.name, o.action) for o in forced] == [("ingest", "ran"), ("count", "cached")]
    assert forced[0].reasons == ("forced",)
    assert ArtifactStore(run_dir).keys("ingest") == [forced[0].key]  # replaced in place, one result
    count = pipe(capture, run_dir).status()[1]
    assert count.state == "fresh" and count.reasons == ("upstream ingest was computed again to the same outputs: kept",)
    both = pipe(capture, run_dir).run(force=["ingest", "count"])
    assert [(o.name, o.action) for o in both] == [("ingest", "ran"), ("count", "ran")]

    with pytest.raises(ParamError, match="unknown stage 'ingst'; did you mean ingest"):
        pipe(capture, run_dir).run(until="ingst")
    with pytest.raises(ParamError, match="do not combine"):
        pipe(capture, run_dir).run(until="ingest", only="count")


def test_an_upstream_computed_again_to_other_outputs_reruns_its_downstream(capture, tmp_path, monkeypatch):
    run_dir = tmp_path / "run"
    pipe(capture, run_dir).run()
    from nerfpipe.stages.ingest import IngestStage

    real = IngestStage.run

    def other_bytes(self, inputs, out, params, ctx):  # the same settings, other outputs (a nondeterministic stage)
        summary = real(self, inputs, out, params, ctx)
        (out / "note.txt").write_text("computed again")
        return summary

    monkeypatch.setattr(IngestStage, "run", other_bytes)
    forced = pipe(capture, run_dir).run(force=["ingest"])
    assert [(o.name, o.action) for o in forced] == [("ingest", "ran"), ("count", "ran")]
    assert forced[1].reasons == ("upstream ingest was computed again after this result",)


def test_a_setting_that_cannot_change_a_result_reruns_nothing(capture, tmp_path):
    run_dir = tmp_path / "run"
    first = pipe(capture, run_dir).run()
    again = pipe(capture, run_dir, overrides={"count": {"chunk": "7"}}).run()
    assert [o.action for o in again] == ["cached", "cached"] and again[1].key == first[1].key
    assert pipe(capture, run_dir, overrides={"count": {"chunk": "7"}}).plan()["count"].params.chunk == 7
    assert [o.action for o in pipe(capture, run_dir, overrides={"count": {"label": "n"}}).run()] == ["cached", "ran"]


def test_unknown_preset_and_stage_in_overrides(capture, tmp_path):
    with pytest.raises(ParamError, match="unknown preset 'fastest'; presets are: .*draft"):
        pipe(capture, tmp_path, preset="fastest")
    with pytest.raises(ParamError, match="unknown stage 'ingset'"):
        pipe(capture, tmp_path, overrides={"ingset": {"max_size": "1"}})


def test_preset_applies_to_every_stage_that_has_it(capture, tmp_path):
    planned = pipe(capture, tmp_path / "run", preset="draft").plan()
    assert planned["ingest"].params.max_size == 400 and planned["count"].params.label == "draft"


def test_clean_keeps_only_the_latest_result_of_each_stage(capture, tmp_path):
    run_dir = tmp_path / "run"
    pipe(capture, run_dir, overrides={"ingest": {"max_size": "200"}}).run()
    latest = pipe(capture, run_dir).run()
    store = ArtifactStore(run_dir)
    store.begin("ingest", "0123456789abcdef" * 4)  # what a killed attempt left
    assert len(store.keys("ingest")) == 2
    removed, freed = store.clean()
    assert removed == 3 and freed > 0
    assert store.keys("ingest") == [latest[0].key] and store.keys("count") == [latest[1].key]
    assert not any((run_dir / ".work").iterdir())
    assert [s.state for s in pipe(capture, run_dir).status()] == ["fresh", "fresh"]


def test_photos_are_never_modified(capture, tmp_path):
    before = {p.name: (sha256_file(p), p.stat().st_mtime_ns) for p in capture.iterdir()}
    pipe(capture, tmp_path / "run", overrides={"ingest": {"max_size": "100"}}).run()
    assert {p.name: (sha256_file(p), p.stat().st_mtime_ns) for p in capture.iterdir()} == before


def test_a_run_log_is_written(capture, tmp_path):
    run_dir = tmp_path / "run"
    pipe(capture, run_dir).run()
    logs = list((run_dir / "logs").glob("run-*.log"))
    assert len(logs) == 1
    text = logs[0].read_text()
    assert "ingest: running for the first time" in text and "count: done in" in text


def test_a_stage_takes_its_machine_preset_only_where_the_job_names_none(capture, tmp_path, monkeypatch, caplog):
    stages = two_stages()
    count = stages[1]
    monkeypatch.setattr(count, "presets", {**count.presets, "big": {"label": "big"}}, raising=False)
    monkeypatch.setattr(count, "machine_preset", lambda overrides: ("big", "sized for this machine"), raising=False)
    with caplog.at_level("INFO", logger="nerfpipe.pipeline.plan"):
        planned = Pipeline(stages, capture, tmp_path / "a").plan()
    assert planned["count"].params.label == "big"
    assert any("count: preset big, sized for this machine" in r.getMessage() for r in caplog.records)
    plain = Pipeline(two_stages(), capture, tmp_path / "b").plan()
    assert plain["count"].params.label != "big" and planned["count"].key != plain["count"].key  # in the key
    named = Pipeline(stages, capture, tmp_path / "c", preset="draft").plan()
    assert named["count"].params.label == "draft"  # a preset the job names wins
    exact = Pipeline(stages, capture, tmp_path / "d", preset="").plan()  # "": none at all (bench's configurations)
    assert exact["count"].key == plain["count"].key
