"""The cache of files head360 can make again: made once, read back, never trusted blindly."""

import numpy as np
import pytest

from head360cli.cache import cache_file, cached_array


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("HEAD360_CACHE", str(folder))
    return folder


def counted(value: np.ndarray):
    calls = []

    def make():
        calls.append(1)
        return value

    return make, calls


def test_an_array_is_made_once_then_read_back(cache):
    value = np.arange(12, dtype=np.float32).reshape(3, 4) / 7
    make, calls = counted(value)
    first = cached_array("a.npy", make, (3, 4), np.float32)
    second = cached_array("a.npy", make, (3, 4), np.float32)
    assert len(calls) == 1
    np.testing.assert_array_equal(first, value)
    np.testing.assert_array_equal(second, value)
    assert second.dtype == np.float32
    assert sorted(p.name for p in cache.iterdir()) == ["a.npy"]  # no temporary left


@pytest.mark.parametrize("bad", ["damaged", "shape", "dtype", "pickle"])
def test_a_file_that_is_not_the_array_is_made_again_and_written_over(cache, bad):
    cache.mkdir()
    path = cache / "a.npy"
    if bad == "damaged":
        path.write_bytes(b"\x93NUMPY garbage")
    elif bad == "shape":
        np.save(path, np.zeros((4, 3), np.float32))
    elif bad == "dtype":
        np.save(path, np.zeros((3, 4), np.float64))
    else:
        np.save(path, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    value = np.ones((3, 4), np.float32)
    make, calls = counted(value)
    np.testing.assert_array_equal(cached_array("a.npy", make, (3, 4), np.float32), value)
    assert len(calls) == 1
    np.testing.assert_array_equal(np.load(path), value)


def test_no_cache_or_an_unwritable_one_only_costs_time(tmp_path, monkeypatch):
    value = np.ones(5, np.int32)
    monkeypatch.setenv("HEAD360_CACHE", "")
    assert cache_file("a.npy") is None
    make, calls = counted(value)
    for _ in range(2):
        np.testing.assert_array_equal(cached_array("a.npy", make, (5,), np.int32), value)
    assert len(calls) == 2
    blocked = tmp_path / "blocked"
    blocked.write_text("a file where the folder should be")
    monkeypatch.setenv("HEAD360_CACHE", str(blocked))
    np.testing.assert_array_equal(cached_array("a.npy", make, (5,), np.int32), value)
    assert blocked.read_text() == "a file where the folder should be"
