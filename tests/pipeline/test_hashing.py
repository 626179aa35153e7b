from __future__ import annotations

import hashlib
import json
import math

import pytest

from nerfpipe.pipeline.fingerprint import FingerprintCache, diff_inputs
from nerfpipe.pipeline.hashing import cache_key, canonical_json, sha256_file


def test_canonical_json_ignores_key_order_and_whitespace():
    assert canonical_json({"b": 1, "a": [1, 2]}) == '{"a":[1,2],"b":1}'
    assert cache_key({"b": 1, "a": 2}) == cache_key({"a": 2, "b": 1})
    # the key is the sha256 of exactly that text
    assert cache_key({"a": 1}) == hashlib.sha256(b'{"a":1}').hexdigest()


def test_canonical_json_refuses_nan():
    with pytest.raises(ValueError):
        canonical_json({"x": math.nan})


def test_every_part_of_the_material_moves_the_key():
    base = {"stage": "s", "version": 1, "params": {"n": 1}, "upstream": {"u": "k"}, "inputs": {"a.png": "h"}}
    variants = [
        {**base, "stage": "t"},
        {**base, "version": 2},
        {**base, "params": {"n": 2}},
        {**base, "upstream": {"u": "k2"}},
        {**base, "inputs": {"a.png": "h2"}},
        {**base, "inputs": {"b.png": "h"}},
    ]
    keys = {cache_key(v) for v in variants} | {cache_key(base)}
    assert len(keys) == len(variants) + 1


def test_fingerprint_cache_hashes_only_when_size_or_mtime_moved(tmp_path, monkeypatch):
    photo = tmp_path / "a.jpg"
    photo.write_bytes(b"abc")
    calls = []
    import nerfpipe.pipeline.fingerprint as fingerprint

    real = fingerprint.sha256_file
    monkeypatch.setattr(fingerprint, "sha256_file", lambda p: calls.append(p) or real(p))
    cache = FingerprintCache(tmp_path / "fp.json")
    first = cache.fingerprint(photo, tmp_path)
    assert first.sha256 == hashlib.sha256(b"abc").hexdigest() and first.relpath == "a.jpg"
    cache.save()
    again = FingerprintCache(tmp_path / "fp.json").fingerprint(photo, tmp_path)
    assert again == first and len(calls) == 1  # a fresh cache from disk: stat only
    # touched, same bytes: rehashed, same digest
    st = photo.stat()
    import os

    os.utime(photo, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    touched = FingerprintCache(tmp_path / "fp.json").fingerprint(photo, tmp_path)
    assert len(calls) == 2 and touched.sha256 == first.sha256
    photo.write_bytes(b"abd")
    assert FingerprintCache(tmp_path / "fp.json").fingerprint(photo, tmp_path).sha256 != first.sha256
    assert sha256_file(photo) == hashlib.sha256(b"abd").hexdigest()


def test_damaged_fingerprint_cache_only_costs_rehashing(tmp_path):
    (tmp_path / "fp.json").write_text("{not json")
    photo = tmp_path / "a.png"
    photo.write_bytes(b"x")
    assert FingerprintCache(tmp_path / "fp.json").fingerprint(photo, tmp_path).sha256 == hashlib.sha256(b"x").hexdigest()


@pytest.mark.parametrize("text", ["[]", '"text"', '{"/a.png": 5}', '{"/a.png": [1, 2]}', '{"/a.png": ["1", 2, "h"]}'])
def test_a_fingerprint_cache_of_another_shape_only_costs_rehashing(tmp_path, text):
    (tmp_path / "fp.json").write_text(text.replace("/a.png", str((tmp_path / "a.png").resolve())))
    photo = tmp_path / "a.png"
    photo.write_bytes(b"x")
    cache = FingerprintCache(tmp_path / "fp.json")
    assert cache.fingerprint(photo, tmp_path).sha256 == hashlib.sha256(b"x").hexdigest()
    cache.save()  # and the file is rewritten in the right shape
    assert json.loads((tmp_path / "fp.json").read_text()) == {
        str(photo.resolve()): [1, photo.stat().st_mtime_ns, hashlib.sha256(b"x").hexdigest()]}


def test_rehash_trusts_no_cached_fingerprint(tmp_path):
    """A photo replaced in place with its size and time kept: only hashing it again sees it (status --verify)."""
    import os

    photo = tmp_path / "a.png"
    photo.write_bytes(b"abc")
    cache = FingerprintCache(tmp_path / "fp.json")
    first = cache.fingerprint(photo, tmp_path)
    cache.save()
    st = photo.stat()
    photo.write_bytes(b"xyz")
    os.utime(photo, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert FingerprintCache(tmp_path / "fp.json").fingerprint(photo, tmp_path) == first  # size and time say nothing
    rehashed = FingerprintCache(tmp_path / "fp.json", rehash=True)
    assert rehashed.fingerprint(photo, tmp_path).sha256 == hashlib.sha256(b"xyz").hexdigest()
    rehashed.save()
    assert FingerprintCache(tmp_path / "fp.json").fingerprint(photo, tmp_path).sha256 == hashlib.sha256(b"xyz").hexdigest()


def test_diff_inputs():
    old = {"a": "1", "b": "2", "c": "3"}
    new = {"a": "1", "b": "9", "d": "4", "e": "5"}
    assert diff_inputs(old, new) == (["d", "e"], ["c"], ["b"])
