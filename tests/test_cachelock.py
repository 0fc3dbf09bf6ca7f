"""Two saves to numba's on-disk cache of one function at once each keep their own entry
(:mod:`qpatrol.engines.cachelock`): the second waits for the first, then reads the index
the first wrote."""

from __future__ import annotations

import threading

import pytest

from qpatrol.engines import cachelock


def test_two_saves_at_once_get_their_own_data_files(tmp_path, monkeypatch):
    caching = pytest.importorskip("numba.core.caching")
    assert cachelock.install()
    cls = caching.IndexDataCacheFile
    first_read, second_read = threading.Event(), threading.Event()
    read_index = cls._load_index

    def slow_read(self):
        """The first save, having read the index, waits (up to 1 s) for the second to
        read it too: without the lock both then read an index without the other's key."""
        index = read_index(self)
        if threading.current_thread().name == "first":
            first_read.set()
            second_read.wait(1.0)
        else:
            second_read.set()
        return index

    monkeypatch.setattr(cls, "_load_index", slow_read)
    cache = cls(str(tmp_path), "f-1.py311", ("stamp",))

    def save(key):
        cache.save(key, ("compiled", key))

    first = threading.Thread(target=save, args=("sig-a",), name="first")
    second = threading.Thread(target=save, args=("sig-b",), name="second")
    first.start()
    assert first_read.wait(10)
    second.start()
    first.join(10), second.join(10)
    monkeypatch.setattr(cls, "_load_index", read_index)
    fresh = cls(str(tmp_path), "f-1.py311", ("stamp",))
    assert fresh.load("sig-a") == ("compiled", "sig-a")
    assert fresh.load("sig-b") == ("compiled", "sig-b")
    assert sorted(p.name for p in tmp_path.glob("*.nbc")) == ["f-1.py311.1.nbc", "f-1.py311.2.nbc"]
