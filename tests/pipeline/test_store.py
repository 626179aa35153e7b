from __future__ import annotations

import hashlib
import json

from nerfpipe.pipeline.store import ArtifactStore, describe_outputs


def _work(store: ArtifactStore, key: str, payload: str):
    work = store.begin("s", key)
    (work / "sub").mkdir()
    (work / "sub" / "a.txt").write_text(payload)
    return work


def test_a_result_exists_only_once_committed(tmp_path):
    store = ArtifactStore(tmp_path)
    work = _work(store, "k" * 64, "hello")
    assert store.get("s", "k" * 64) is None and store.latest("s") is None
    committed = store.commit("s", "k" * 64, work, {"key": "k" * 64, "stage": "s"})
    assert not work.exists()
    assert committed.path == tmp_path / "stages" / "s" / ("k" * 64)
    a_txt = committed.path / "sub" / "a.txt"
    assert committed.manifest["outputs"] == {
        "sub/a.txt": {"size": 5, "mtime_ns": a_txt.stat().st_mtime_ns, "sha256": hashlib.sha256(b"hello").hexdigest()}
    }
    assert describe_outputs(committed.path) == committed.manifest["outputs"]
    assert store.get("s", "k" * 64).manifest == committed.manifest
    assert store.latest("s").key == "k" * 64
    assert store.keys("s") == ["k" * 64]


def test_a_folder_without_manifest_is_not_a_result(tmp_path):
    store = ArtifactStore(tmp_path)
    fake = tmp_path / "stages" / "s" / "abc"
    fake.mkdir(parents=True)
    (fake / "images.json").write_text("{}")
    (tmp_path / "stages" / "s" / "latest.json").write_text(json.dumps({"key": "abc"}))
    assert store.get("s", "abc") is None and store.latest("s") is None and store.keys("s") == []


def test_begin_wipes_what_a_killed_attempt_left(tmp_path):
    store = ArtifactStore(tmp_path)
    work = _work(store, "k" * 64, "partial")
    again = store.begin("s", "k" * 64)
    assert again == work and list(again.iterdir()) == []


def test_two_writers_of_the_same_key_leave_one_complete_result(tmp_path):
    a, b = ArtifactStore(tmp_path), ArtifactStore(tmp_path)
    work_a = a.begin("s", "k" * 64)
    (work_a / "x").write_text("from a")
    work_b = tmp_path / ".work" / "s-other-writer"  # another process has its own work folder
    work_b.mkdir()
    (work_b / "x").write_text("from b!")
    a.commit("s", "k" * 64, work_a, {"key": "k" * 64})
    result = b.commit("s", "k" * 64, work_b, {"key": "k" * 64})
    assert (result.path / "x").read_text() == "from a" and result.manifest["outputs"]["x"]["size"] == 6
    assert not work_b.exists()


def test_forced_commit_replaces_the_result_of_the_same_key(tmp_path):
    store = ArtifactStore(tmp_path)
    store.commit("s", "k" * 64, _work(store, "k" * 64, "old"), {"key": "k" * 64})
    result = store.commit("s", "k" * 64, _work(store, "k" * 64, "newer"), {"key": "k" * 64}, replace=True)
    assert (result.path / "sub" / "a.txt").read_text() == "newer" and store.keys("s") == ["k" * 64]
