"""The database cache: hits on the same key, rebuilds on a stale, corrupt or truncated file, never pickles."""

import numpy as np
import pytest

from startracker import cache


def builder(counter):
    def build():
        counter.append(1)
        return {"angles": np.linspace(0, 1, 50), "ids": np.arange(50, dtype=np.int32)}

    return build


def test_hit_after_build_and_identical_arrays(tmp_path):
    calls = []
    key = {"kind": "test", "version": 1, "fov_deg": 20.0}
    a = cache.load_or_build(key, builder(calls), folder=tmp_path)
    b = cache.load_or_build(key, builder(calls), folder=tmp_path)
    assert len(calls) == 1
    for k in a:
        assert np.array_equal(a[k], b[k]) and a[k].dtype == b[k].dtype


def test_other_version_is_a_different_entry(tmp_path):
    calls = []
    cache.load_or_build({"kind": "test", "version": 1}, builder(calls), folder=tmp_path)
    cache.load_or_build({"kind": "test", "version": 2}, builder(calls), folder=tmp_path)
    assert len(calls) == 2


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage", "wrong_key"])
def test_corrupt_or_stale_file_is_rebuilt_not_trusted(tmp_path, damage):
    calls = []
    key = {"kind": "test", "version": 1}
    good = cache.load_or_build(key, builder(calls), folder=tmp_path)
    path = cache.entry_path(key, tmp_path)
    raw = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(raw[: len(raw) // 2])
    elif damage == "flip":
        # change one data byte of the stored array (an npy payload near the end of the zip)
        i = raw.find(np.linspace(0, 1, 50).tobytes()[8:16])
        assert i > 0
        path.write_bytes(raw[:i] + bytes([raw[i] ^ 0xFF]) + raw[i + 1 :])
    elif damage == "garbage":
        path.write_bytes(b"not a zip at all")
    else:
        other = tmp_path / "other"
        cache.load_or_build({"kind": "other"}, builder([]), folder=other)
        cache.entry_path({"kind": "other"}, other).replace(path)
    rejected = cache.STATS.rejected
    again = cache.load_or_build(key, builder(calls), folder=tmp_path)
    assert len(calls) == 2 and cache.STATS.rejected == rejected + 1
    assert np.array_equal(again["angles"], good["angles"])
    # and the rebuilt file is good again
    cache.load_or_build(key, builder(calls), folder=tmp_path)
    assert len(calls) == 2


def test_object_arrays_are_refused(tmp_path):
    with pytest.raises(TypeError, match="object"):
        cache.load_or_build({"k": 1}, lambda: {"x": np.array([{"a": 1}], dtype=object)}, folder=tmp_path)


def test_no_temporary_files_left(tmp_path):
    cache.load_or_build({"k": 2}, builder([]), folder=tmp_path)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
