"""``engine: auto`` on a cold numba cache (:mod:`qpatrol.engines.coldstart`): the cost
model, the cache probe, the lock, the background warm-up, and the same files either way.

No test compiles a loop of the compiled engine cold: the probe is mocked where a
config runs, and tested on a one-line function of its own."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

from qpatrol import engines
from qpatrol.config import from_flat, load_config
from qpatrol.engines import coldstart
from qpatrol.engines.coldstart import cached as real_cached
from qpatrol.engines.coldstart import warm_in_background as real_warm_in_background
from qpatrol.run import warmup

pytest.importorskip("numba")

PAPER = load_config("paper")


def not_cached(monkeypatch, warmed: list | None = None) -> None:
    """No loop is in numba's cache; ``warmed`` collects the background warm-ups asked."""
    monkeypatch.setattr(coldstart, "cached", lambda loop, disp=None, folder=None: False)
    monkeypatch.setattr(coldstart, "_compiling_for", lambda loop, folder=None: 0.0)
    sink = warmed if warmed is not None else []
    monkeypatch.setattr(
        coldstart,
        "warm_in_background",
        lambda cfg, loop, folder=None: sink.append((cfg, loop)) or True,
    )


# ------------------------------------------------------------------ the cost model


def test_numpy_seconds_follow_steps_runs_and_agents():
    cfg = from_flat(
        {"policy": "qlearning", "agents": 4, "runs": 4, "steps": 5000, "battery.enabled": False}
    )
    fixed, per_robot, per = coldstart.NUMPY_US
    want = 5000 * (fixed + per_robot * 4 + per * 16) / 1e6
    assert coldstart.numpy_seconds(cfg) == pytest.approx(want)
    assert coldstart.numpy_seconds(cfg.replace(steps=10_000)) == pytest.approx(2 * want)
    more = cfg.replace(runs=64)
    assert coldstart.numpy_seconds(more) > coldstart.numpy_seconds(cfg)
    # a batch of several sweep points: its rows, not the config's runs
    assert coldstart.numpy_seconds(cfg, 64) == coldstart.numpy_seconds(more)
    assert coldstart.compile_seconds("unknown") == max(coldstart.COMPILE_SECONDS.values())


def test_the_paper_runs_on_numpy_until_its_loop_is_cached(monkeypatch):
    """The paper's default experiment (map_a, 4 agents, 4 runs, 5,000 steps, battery):
    numpy while loop ``any`` is not cached, with the reason in the note; compiled once
    it is; and at 200,000 steps the compile pays (numba, as before)."""
    assert engines.choose(PAPER) == ("numba", "")  # cached (tests/conftest.py)
    not_cached(monkeypatch)
    engine, note = engines.choose(PAPER)
    assert engine == "numpy"
    assert note.startswith(coldstart.COLD) and "'any' not cached yet" in note
    assert engines.choose(PAPER.replace(steps=200_000)) == ("numba", "")
    assert engines.choose(PAPER, rows=3000) == ("numba", "")  # points sharing a batch
    # what the cache holds does not change which loop a config takes (sweep ordering)
    assert engines.compiled_loop(PAPER) == "any"
    # asked for explicitly: always the engine asked for
    assert engines.choose(PAPER.replace(engine="numba")) == ("numba", "")
    assert engines.choose(PAPER.replace(engine="numpy")) == ("numpy", "")
    # a batch numpy finishes within AUTO_NUMPY_SECONDS: numpy (loading the loop costs
    # more); just above it, the compiled engine (the estimate is linear in the steps)
    per_step = coldstart.numpy_seconds(PAPER.replace(runs=1, steps=1))
    under = int(engines.AUTO_NUMPY_SECONDS / per_step * 0.9)
    over = int(engines.AUTO_NUMPY_SECONDS / per_step * 1.1)
    assert "small batch" in engines.choose(PAPER.replace(runs=1, steps=under))[1]
    assert engines.choose_by_config(PAPER.replace(runs=1, steps=over)) == ("numba", "")


def test_cold_note_weighs_numpy_against_the_compile_left(monkeypatch):
    monkeypatch.setattr(coldstart, "cached", lambda loop, disp=None, folder=None: False)
    monkeypatch.setattr(coldstart, "COMPILE_SECONDS", {"any": 20.0})
    est = coldstart.numpy_seconds(PAPER)
    assert 0 < est < 20
    monkeypatch.setattr(coldstart, "_compiling_for", lambda loop, folder=None: 0.0)
    assert coldstart.cold_note(PAPER, "any") is not None
    # another process has been compiling it for a while: less left to wait for
    monkeypatch.setattr(coldstart, "_compiling_for", lambda loop, folder=None: 20.0 - est / 2)
    assert coldstart.cold_note(PAPER, "any") is None
    monkeypatch.setattr(coldstart, "cached", lambda loop, disp=None, folder=None: True)
    monkeypatch.setattr(coldstart, "_compiling_for", lambda loop, folder=None: 0.0)
    assert coldstart.cold_note(PAPER, "any") is None


# ------------------------------------------------------------------ cold vs warm runs


def train(*args: str) -> int:
    """``qpatrol ARGS`` in this process: its exit code."""
    from qpatrol import cli

    try:
        cli.main(list(args))
    except SystemExit as e:
        return int(e.code or 0)
    return 0


def test_a_cold_start_and_a_warm_one_write_the_same_files(monkeypatch, tmp_path):
    """``qpatrol train paper`` on a cold cache (numpy, a warm-up of loop ``any`` asked
    for in the background) and on a warm one (compiled): the same files, byte for byte,
    but for the engine in meta.json, whose note says why numpy ran."""
    args = ["train", "paper", "--set", "steps=2000", "-q"]
    assert train(*args, "--out", str(tmp_path / "warm")) == 0
    warmed: list = []
    not_cached(monkeypatch, warmed)
    assert train(*args, "--out", str(tmp_path / "cold")) == 0
    assert [loop for _, loop in warmed] == ["any"]
    a, b = tmp_path / "warm", tmp_path / "cold"
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for name in names:
        if name != "meta.json":
            assert (a / name).read_bytes() == (b / name).read_bytes(), name
    warm_meta, cold_meta = (json.loads((f / "meta.json").read_text()) for f in (a, b))
    assert warm_meta["engine"]["ran"] == "numba" and warm_meta["engine"]["note"] == ""
    assert cold_meta["engine"]["ran"] == "numpy"
    assert "compiled loop 'any' not cached yet" in cold_meta["engine"]["note"]


# ------------------------------------------------------------------ the cache probe

TINY = """\
from numba import njit


@njit(cache=True)
def tiny(x):
    return x + {k}
"""


@pytest.fixture
def tiny(tmp_path, monkeypatch):
    """A one-line cached numba function in a module of its own (compiles in well under a
    second): ``(module, dispatchers, marker folder)``."""
    import importlib

    src = tmp_path / "src"
    src.mkdir()
    (src / "qp_tiny_loop.py").write_text(TINY.format(k=1))
    monkeypatch.syspath_prepend(str(src))
    sys.modules.pop("qp_tiny_loop", None)
    mod = importlib.import_module("qp_tiny_loop")
    yield mod, {"qp_tiny_loop.tiny": mod.tiny}, tmp_path / "markers"
    sys.modules.pop("qp_tiny_loop", None)


def test_probe_reads_numbas_own_index(tiny):
    mod, disp, folder = tiny
    assert not real_cached("tiny", disp, folder)  # no marker
    before = coldstart.signatures(disp)
    assert mod.tiny(2) == 3  # compiled (or loaded) now, and saved by numba
    coldstart.record("tiny", before, disp, folder)
    marker = json.loads((folder / coldstart.MARKER.format("tiny")).read_text())
    assert marker["signatures"] == {"qp_tiny_loop.tiny": ["(int64,)"]}
    assert real_cached("tiny", disp, folder)
    assert not real_cached("other", disp, folder)
    # the index numba would use no longer lists the signature (its sources changed)
    cache_file = mod.tiny._cache._cache_file
    stamp = cache_file._source_stamp
    cache_file._source_stamp = ("changed", 0)
    assert not real_cached("tiny", disp, folder)
    cache_file._source_stamp = stamp
    assert real_cached("tiny", disp, folder)
    # the marker names a signature numba never cached
    path = folder / coldstart.MARKER.format("tiny")
    bad = {"loop": "tiny", "signatures": {"qp_tiny_loop.tiny": ["(int64,)", "(float64,)"]}}
    path.write_text(json.dumps(bad))
    assert not real_cached("tiny", disp, folder)
    # ... or a dispatcher that no longer exists; or it is unreadable
    path.write_text(json.dumps({"loop": "tiny", "signatures": {"gone.tiny": ["(int64,)"]}}))
    assert not real_cached("tiny", disp, folder)
    path.write_text("{not json")
    assert not real_cached("tiny", disp, folder)
    # the cache emptied: the index is gone
    coldstart.record("tiny", {}, disp, folder)
    assert real_cached("tiny", disp, folder)
    os.remove(cache_file._index_path)
    assert not real_cached("tiny", disp, folder)


def test_probe_without_numbas_cache_objects_takes_the_loop_as_cached(tiny):
    """Another numba whose cache objects this does not know: the compiled engine runs,
    as it did before the probe existed."""
    mod, disp, folder = tiny
    before = coldstart.signatures(disp)
    mod.tiny(1)
    coldstart.record("tiny", before, disp, folder)

    class Opaque:
        signatures = mod.tiny.signatures
        _cache = object()

    assert real_cached("tiny", {"qp_tiny_loop.tiny": Opaque()}, folder)


def test_record_adds_only_what_this_run_compiled_or_loaded(tiny):
    mod, disp, folder = tiny
    mod.tiny(1)
    before = coldstart.signatures(disp)
    coldstart.record("tiny", before, disp, folder)  # nothing new: no marker
    assert not (folder / coldstart.MARKER.format("tiny")).exists()
    mod.tiny(1.5)
    coldstart.record("tiny", before, disp, folder)
    marker = json.loads((folder / coldstart.MARKER.format("tiny")).read_text())
    assert marker["signatures"] == {"qp_tiny_loop.tiny": ["(float64,)"]}


def test_the_real_dispatchers_and_their_folder():
    """The compiled engine's cached dispatchers are found, each under the module that
    defines it, and the markers go to numba_core's cache folder."""
    from qpatrol.engines import numba_core

    disp = coldstart.dispatchers()
    assert disp["qpatrol.engines.numba_core.run_block"] is numba_core.run_block
    assert all(d.py_func.__module__ == n.rsplit(".", 1)[0] for n, d in disp.items())
    assert coldstart.cache_folder(disp) == Path(numba_core.run_block._cache.cache_path)


def test_a_loop_found_cached_is_not_read_again(monkeypatch, tmp_path):
    """The engine's own loops: once found cached, a process does not read numba's
    index again (a sweep asks at every point); not found, it reads again (another
    process may be compiling it). The scan for the dispatchers is kept too."""
    reads: list[str] = []
    found = {"any": False}

    def index_lists(loop, disp, folder):
        reads.append(loop)
        return found[loop]

    monkeypatch.setattr(coldstart, "_index_lists", index_lists)
    monkeypatch.setattr(coldstart, "_CACHED", set())
    assert not real_cached("any", folder=tmp_path)
    assert not real_cached("any", folder=tmp_path)
    found["any"] = True
    assert real_cached("any", folder=tmp_path)
    assert real_cached("any", folder=tmp_path)
    assert reads == ["any"] * 3
    assert coldstart.dispatchers() is coldstart.dispatchers()


# ------------------------------------------------------------------ lock and warm-up


def test_a_compiling_process_holds_the_loops_lock(monkeypatch, tmp_path):
    monkeypatch.setattr(coldstart, "cache_folder", lambda disp=None: tmp_path)
    recorded = []
    monkeypatch.setattr(coldstart, "record", lambda loop, before, *a: recorded.append(loop))
    assert coldstart._compiling_for("any") == 0.0
    job = coldstart.Compiling("any")
    assert (tmp_path / coldstart.LOCK.format("any")).exists()
    assert coldstart._compiling_for("any") >= 0.0
    assert coldstart.Compiling("any").lock is None  # held: a second one does not take it
    job.done()
    job.done()
    assert recorded == ["any"]
    assert not (tmp_path / coldstart.LOCK.format("any")).exists()
    # a lock left by a process that is gone is stale
    (tmp_path / coldstart.LOCK.format("any")).write_text("999999999\n")
    assert coldstart._compiling_for("any") == 0.0
    job = coldstart.Compiling("any")
    assert job.lock is not None
    job.release()


def test_the_lock_is_taken_before_numba_made_its_cache_folder(monkeypatch, tmp_path):
    """On an empty NUMBA_CACHE_DIR numba makes the folder when it first saves."""
    folder = tmp_path / "not-yet"
    monkeypatch.setattr(coldstart, "cache_folder", lambda disp=None: folder)
    job = coldstart.Compiling("any")
    assert job.lock == folder / coldstart.LOCK.format("any") and job.lock.exists()
    job.release()


def test_a_live_lock_counts_its_age(monkeypatch, tmp_path):
    monkeypatch.setattr(coldstart, "cache_folder", lambda disp=None: tmp_path)
    lock = tmp_path / coldstart.LOCK.format("any")
    lock.write_text(f"{os.getpid()}\n")
    past = lock.stat().st_mtime - 5
    os.utime(lock, (past, past))
    assert 4.0 < coldstart._compiling_for("any") < 60.0
    past -= coldstart.LOCK_STALE
    os.utime(lock, (past, past))
    assert coldstart._compiling_for("any") == 0.0


def test_warm_in_background_hands_the_config_to_a_detached_process(monkeypatch, tmp_path):
    monkeypatch.setattr(coldstart, "_compiling_for", lambda loop, folder=None: 0.0)
    started = []

    class Popen:
        def __init__(self, argv, **kw):
            started.append((argv, kw))

    monkeypatch.setattr(coldstart.subprocess, "Popen", Popen)
    cfg = PAPER.replace(steps=777)
    assert real_warm_in_background(cfg, "any")
    (argv, kw) = started[0]
    assert argv[:3] == [sys.executable, "-m", "qpatrol.run.warmup"]
    assert kw["start_new_session"] and kw["stdout"] is coldstart.subprocess.DEVNULL
    # the process reads the same config back, and removes the file
    got = []
    monkeypatch.setattr(warmup, "warm", lambda c, loop: got.append((c, loop)) or True)
    monkeypatch.setattr(warmup.os, "nice", lambda n: 0)
    assert warmup.main([argv[3]]) == 0
    assert got == [(cfg, "any")] and not Path(argv[3]).exists()
    # another process is compiling the loop: none started
    monkeypatch.setattr(coldstart, "_compiling_for", lambda loop, folder=None: 3.0)
    assert not real_warm_in_background(cfg, "any")
    assert len(started) == 1


def test_warm_runs_a_few_steps_of_one_run_on_the_compiled_engine(monkeypatch):
    seen = []
    monkeypatch.setattr(warmup, "simulate", lambda cfg: seen.append(cfg))
    monkeypatch.setattr(coldstart, "_compiling_for", lambda loop, folder=None: 0.0)
    monkeypatch.setattr(coldstart, "cached", lambda loop, disp=None, folder=None: False)
    assert warmup.warm(PAPER, "any")
    (mini,) = seen
    assert (mini["runs"], mini["steps"], mini["engine"], mini["threads"]) == (1, 8, "numba", 1)
    assert engines.compiled_loop(mini) == engines.compiled_loop(PAPER)
    monkeypatch.setattr(coldstart, "cached", lambda loop, disp=None, folder=None: True)
    assert not warmup.warm(PAPER, "any")
    assert len(seen) == 1


# ------------------------------------------------------------------ pools and waiting


def test_a_pools_batches_of_a_loop_are_weighed_together(monkeypatch):
    """One batch of a sweep would finish on numpy before the compile, but the sweep's
    batches of the same loop together would not: compile (once, for all of them)."""
    monkeypatch.setattr(coldstart, "cached", lambda loop, disp=None, folder=None: False)
    monkeypatch.setattr(coldstart, "_compiling_for", lambda loop, folder=None: 0.0)
    assert coldstart.cold_note(PAPER, "any") is not None
    work = coldstart.pool_work([(PAPER, "any")] * 40 + [(PAPER, None)])
    assert work == {"any": pytest.approx(40 * coldstart.numpy_seconds(PAPER))}
    assert coldstart.pool_work([(PAPER.replace(engine="numba"), "any")]) == {}
    coldstart.set_pool_work(work)
    try:
        assert coldstart.cold_note(PAPER, "any") is None
        assert coldstart.cold_note(PAPER, "qlearning-team") is not None  # another loop
    finally:
        coldstart.set_pool_work(None)
    assert coldstart.cold_note(PAPER, "any") is not None


def test_while_another_process_compiles_a_short_batch_runs_on_numpy(monkeypatch):
    """Another process is compiling the loop: a batch shorter than the compile's rest
    runs on numpy (no second warm-up), a longer one waits for it (numba)."""
    monkeypatch.setattr(coldstart, "cached", lambda loop, disp=None, folder=None: False)
    monkeypatch.setattr(coldstart, "_compiling_for", lambda loop, folder=None: 2.0)
    est = coldstart.numpy_seconds(PAPER)
    note = coldstart.cold_note(PAPER, "any")
    assert note is not None and "another process compiling it" in note
    assert "background" not in note
    monkeypatch.setattr(coldstart, "COMPILE_SECONDS", {"any": est + 1.0})
    assert coldstart.cold_note(PAPER, "any") is None


def test_a_compiled_run_waits_for_another_process_compiling_its_loop(monkeypatch):
    """Compiling a loop another process is compiling would take longer and cost a core:
    wait until it is done (its lock gone, or the loop cached)."""
    polls = []

    def busy(loop, folder=None):
        polls.append(loop)
        return 5.0 if len(polls) < 4 else 0.0

    monkeypatch.setattr(coldstart, "_compiling_for", busy)
    monkeypatch.setattr(coldstart, "cached", lambda loop, disp=None, folder=None: False)
    coldstart._wait_for_others("any", poll=0.001)
    assert len(polls) == 4
    polls.clear()
    monkeypatch.setattr(coldstart, "cached", lambda loop, disp=None, folder=None: True)
    coldstart._wait_for_others("any", poll=0.001)
    assert len(polls) == 1


def test_the_sweep_pool_tells_its_workers_the_loops_work(monkeypatch, tmp_path):
    from qpatrol.study import sweep
    from qpatrol.study.sweep import Point

    seen = []

    def run_points(pts, m, pdir, meta):
        seen.append(dict(coldstart._pool_work))
        return []

    monkeypatch.setattr(sweep, "_run_points", run_points)
    cfgs = [PAPER, PAPER.replace(policy="random"), PAPER.replace(engine="numpy")]
    tasks = [(0, [(Point(i, {}), c)], None, tmp_path) for i, c in enumerate(cfgs)]
    assert list(sweep._pool(tasks, 1, {})) == []
    want = {"any": coldstart.numpy_seconds(cfgs[0]) + coldstart.numpy_seconds(cfgs[1])}
    assert seen == [want] * 3
    assert coldstart._pool_work == {}  # reset after the pool
    sweep._run_tagged(0, [], None, tmp_path, {}, 1, want)
    assert coldstart._pool_work == want and seen[-1] == want
    coldstart.set_pool_work(None)


def test_a_strategy_that_reads_the_map_every_step_is_estimated_dearer():
    """``Strategy.numpy_cell_us``: 8 ``dta-ssi-part`` robots on facility (10 runs of 5,000
    steps, one robot failing) took 157 s on numpy, estimated 7 s without the strategy's
    own cost; with it the estimate is within 20% of that, and above the compile, so the
    run waits for the compiled engine; the world's step alone is unchanged for others."""
    flat = {"map": "facility", "agents": 8, "runs": 10, "steps": 5000}
    dta = from_flat({**flat, "policy": "dta-ssi-part", "failures.robots": 1, "failures.at": 2000})
    plain = from_flat({**flat, "policy": "random"})
    fixed, per_robot, per = coldstart.NUMPY_US
    assert coldstart.numpy_seconds(plain) == pytest.approx(
        5000 * (fixed + 8 * per_robot + 80 * per) * 1e-6
    )
    assert 0.8 * 157 < coldstart.numpy_seconds(dta) < 1.2 * 157
    assert coldstart.numpy_seconds(dta) > coldstart.compile_seconds("any")
