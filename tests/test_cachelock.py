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


TOY = """
import sys
from qpatrol.engines import cachelock
cachelock.install()
from numba import njit

@njit(cache=True)
def f(n):
    s = 0.0
    for i in range(n):
        s += i ** 0.5
    return s

f(3)
print(sum(f.stats.cache_misses.values()), sum(f.stats.cache_hits.values()))
"""


def test_two_processes_compile_one_function_once(tmp_path):
    """Two processes that need the same function on an empty cache take turns: one
    compiles it (a cache miss), the other waits and loads what the first saved (a hit)."""
    pytest.importorskip("numba")
    import os
    import subprocess
    import sys

    (tmp_path / "toy.py").write_text(TOY)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    procs = [
        subprocess.Popen(
            [sys.executable, str(tmp_path / "toy.py")],
            env=env,
            cwd=tmp_path,
            stdout=subprocess.PIPE,
            text=True,
        )
        for _ in range(2)
    ]
    outs = [p.communicate(timeout=120)[0].split() for p in procs]
    assert all(p.returncode == 0 for p in procs)
    misses = sorted(int(o[0]) for o in outs)
    assert misses == [0, 1], outs  # one compiled, one loaded
