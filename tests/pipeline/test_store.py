from __future__ import annotations

import hashlib
import json
import os

import pytest

from nerfpipe.pipeline.errors import InputError
from nerfpipe.pipeline.store import BROKEN, MANIFEST, ArtifactStore, Damage, describe_outputs, verify_outputs


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


@pytest.mark.parametrize("change", [
    lambda m: m["outputs"]["sub/a.txt"].pop("size"),
    lambda m: m["outputs"].update({"sub/a.txt": "5 bytes"}),
    lambda m: m.update(outputs=[]),
    lambda m: m.update(key=7),
    lambda m: m.update(summary=[]),
    lambda m: m.update(timings="fast"),
])
def test_a_manifest_of_another_shape_is_damage_not_a_crash(tmp_path, change):
    store = ArtifactStore(tmp_path)
    committed = store.commit("s", "k" * 64, _work(store, "k" * 64, "hello"), {"key": "k" * 64, "stage": "s"})
    manifest = json.loads((committed.path / MANIFEST).read_text())
    change(manifest)
    (committed.path / MANIFEST).write_text(json.dumps(manifest))
    found = store.inspect("s", "k" * 64)
    assert isinstance(found, Damage) and found.file == MANIFEST
    assert found.problem == "has no key or outputs, or an output without its size and sha256"
    assert store.get("s", "k" * 64) is None


@pytest.mark.parametrize("text", ["[]", "{}", '{"key": 5}', '["k"]', '"k"', "{"])
def test_a_latest_pointer_of_another_shape_only_loses_which_key_ran_last(tmp_path, text):
    store = ArtifactStore(tmp_path)
    store.commit("s", "k" * 64, _work(store, "k" * 64, "hello"), {"key": "k" * 64, "stage": "s"})
    store.set_latest("s", "k" * 64)
    assert store.latest_key("s") == "k" * 64
    (tmp_path / "stages" / "s" / "latest.json").write_text(text)
    assert store.latest_key("s") is None and store.latest("s") is None
    assert store.get("s", "k" * 64) is not None  # the result itself is still there for the key that needs it


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


def test_verify_outputs_cheap_and_full(tmp_path):
    store = ArtifactStore(tmp_path)
    committed = store.commit("s", "k" * 64, _work(store, "k" * 64, "hello"), {"key": "k" * 64})
    a_txt = committed.path / "sub" / "a.txt"
    outputs = committed.manifest["outputs"]
    assert verify_outputs(committed.path, outputs) is None and verify_outputs(committed.path, outputs, full=True) is None

    stat = a_txt.stat()
    a_txt.write_text("jello")  # same size, new content; time put back as it was
    os.utime(a_txt, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert verify_outputs(committed.path, outputs) is None  # the cheap check cannot see it...
    assert verify_outputs(committed.path, outputs, full=True) == Damage(
        committed.path, "sub/a.txt", "changed content (its sha256 is not the manifest's)")  # ...sha256 does
    os.utime(a_txt, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1))
    assert str(verify_outputs(committed.path, outputs)) == "sub/a.txt changed content (its sha256 is not the manifest's)"

    a_txt.write_text("hello")  # content back, time new: hashed again, and intact
    assert verify_outputs(committed.path, outputs) is None
    a_txt.write_text("hello!")
    assert str(verify_outputs(committed.path, outputs)) == "sub/a.txt changed size (5 -> 6 bytes)"
    a_txt.unlink()
    assert str(verify_outputs(committed.path, outputs)) == "sub/a.txt is missing"
    assert store.get("s", "k" * 64) is None and store.latest("s") is None
    assert isinstance(store.inspect("s", "k" * 64), Damage)


def test_a_damaged_result_is_moved_aside_with_its_reason_and_replaced(tmp_path):
    store = ArtifactStore(tmp_path)
    key = "k" * 64
    first = store.commit("s", key, _work(store, key, "hello"), {"key": key})
    (first.path / MANIFEST).write_text("{")
    damage = store.inspect("s", key)
    assert damage == Damage(first.path, MANIFEST, "is not readable JSON")
    second = store.commit("s", key, _work(store, key, "again"), {"key": key})  # moves the damaged one aside first
    assert (second.path / "sub" / "a.txt").read_text() == "again" and second.commit_id != first.commit_id
    aside = store.set_aside_as("s", key)
    assert aside.parent == tmp_path / BROKEN and (aside / MANIFEST).read_text() == "{"
    assert (aside / "REASON.txt").read_text() == f"s result {key}: manifest.json is not readable JSON\n"
    size = sum(p.stat().st_size for p in aside.rglob("*") if p.is_file())
    assert store.clean() == (1, size) and not aside.exists()


def test_prepare_refuses_a_file_and_a_path_through_one(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="is a file, not a folder; pass --out a new folder"):
        ArtifactStore(tmp_path / "f").prepare()
    with pytest.raises(InputError, match="does not run through a file"):
        ArtifactStore(tmp_path / "f" / "run").prepare()
    ArtifactStore(tmp_path / "new" / "run").prepare()
    assert (tmp_path / "new" / "run").is_dir()


def test_clean_removes_only_what_the_store_made_and_counts_its_bytes(tmp_path):
    """--out may name a folder that already held the user's own broken/ or .work/: those files stay."""
    store = ArtifactStore(tmp_path)
    old, new = "a" * 64, "b" * 64
    for key, payload in ((old, "x" * 100), (new, "y" * 7)):
        store.commit("s", key, _work(store, key, payload), {"key": key, "stage": "s"})
    old_bytes = sum(p.stat().st_size for p in (tmp_path / "stages" / "s" / old).rglob("*") if p.is_file())
    left = store.begin("s", "c" * 64)  # an unfinished attempt
    (left / "part.bin").write_bytes(b"z" * 1000)
    aside = store.set_aside("s", new, Damage(tmp_path, "sub/a.txt", "is missing"))
    aside_bytes = sum(p.stat().st_size for p in aside.rglob("*") if p.is_file())
    mine = {tmp_path / ".work" / "notes.txt": b"my notes", tmp_path / BROKEN / "photo.jpg": b"\xff\xd8" * 50,
            tmp_path / BROKEN / "s-drafts" / "a.txt": b"draft", tmp_path / "stages" / "s" / "keep-me": b"mine"}
    for path, data in mine.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    store.set_latest("s", new)  # the latest result went aside: the older one is not the latest either

    removed, freed = store.clean()
    assert removed == 3 and freed == old_bytes + 1000 + aside_bytes
    assert all(path.read_bytes() == data for path, data in mine.items())
    assert not left.exists() and not aside.exists() and not (tmp_path / "stages" / "s" / old).exists()
