"""The compiled engine's threads share out a batch's runs and change no number.

Each lane of runs (:func:`qpatrol.engines.threads.lanes`) is advanced by its own thread
with its own working arrays and output buffers; every file of the run folder must be
the one a single thread writes, byte for byte, whatever the number of threads, the
compiled loop (the lone robot's and the team's Q-learning loops, the Q-learning loop
with Q-update records, the general loop with the battery), the recorders, and runs
that meet their episode quota at different steps.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from qpatrol.config import ConfigError, from_flat
from qpatrol.engines import threads
from qpatrol.run import simulate, write_run
from qpatrol.world import limits

META = {"started": "-", "ended": "-"}
BASE = {"map": "map_b", "seed": 11, "steps": 900, "engine": "numba"}


@pytest.fixture
def lanes_seen(monkeypatch) -> list[tuple[int, int, int, str]]:
    """Every lane the compiled loop ran during the test: ``(lane, first row, end row,
    thread name)``; lanes are cut for calls of any size (MIN_LANE_WORK 1)."""
    pytest.importorskip("numba")
    from qpatrol.engines import numba_core

    monkeypatch.setattr(threads, "MIN_LANE_WORK", 1)
    seen: list[tuple[int, int, int, str]] = []
    real = numba_core.Loop._lane

    def spy(self, lane, n, lo, hi):
        seen.append((lane, lo, hi, threading.current_thread().name))
        return real(self, lane, n, lo, hi)

    monkeypatch.setattr(numba_core.Loop, "_lane", spy)
    return seen


def written(result, path: Path) -> dict[str, bytes]:
    """Every file of ``result``'s run folder, written to ``path``: name -> bytes."""
    out = write_run(result, path, meta=META)
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())}


def folder_bytes(flat: dict, path: Path) -> dict[str, bytes]:
    return written(simulate(from_flat(flat)), path)


CASES = {
    "lone kernel, trajectory": {"runs": 7, "agents": 1, "record.trajectory": 5},
    "team kernel, epsilon": {"runs": 5, "agents": 3, "learning.epsilon": 0.2},
    "battery and recorders (general loop)": {
        "runs": 4,
        "agents": 3,
        "battery.enabled": True,
        "battery.capacity": 60,
        "record.watch": [3, 10],
        "record.timeline": 50,
        "record.warmup": 30,
    },
    "every Q-update recorded": {"runs": 3, "agents": 2, "record.transitions": True},
    "episode quotas met at different steps": {
        "runs": 6,
        "agents": 2,
        "episodes": 3,
        "max_episode_steps": 70,
    },
    "conscientious": {"runs": 5, "agents": 2, "policy": "conscientious"},
    "qlearning-idleness with the battery": {
        "runs": 5,
        "agents": 3,
        "policy": "qlearning-idleness",
        "battery.enabled": True,
        "battery.capacity": 60,
    },
}


@pytest.mark.parametrize("case", list(CASES))
def test_threads_write_the_same_files(tmp_path, lanes_seen, case):
    flat = {**BASE, **CASES[case]}
    one = folder_bytes({**flat, "threads": 1}, tmp_path / "one")
    assert {lane for lane, *_ in lanes_seen} == {0}
    for n in (2, 3):
        lanes_seen.clear()
        assert folder_bytes({**flat, "threads": n}, tmp_path / f"t{n}") == one, (case, n)
        # n lanes, each in a thread of the pool, covering the rows in order
        assert {lane for lane, *_ in lanes_seen} == set(range(n))
        assert all(name.startswith("qpatrol-lane") for *_, name in lanes_seen)
        first_call = sorted({(lane, lo, hi) for lane, lo, hi, _ in lanes_seen})[:n]
        assert [lo for _, lo, _ in first_call] == [flat["runs"] * i // n for i in range(n)]


@pytest.mark.parametrize("timeline", [50, 0])
def test_threads_of_large_batches(tmp_path, lanes_seen, ring_map, timeline):
    """A large batch is cut into one lane of consecutive runs per thread, each lane
    advanced in one call per block, its runs one after the other (the general loop,
    here for the timeline, and the Q-learning loop alike)."""
    flat = {**BASE, "map": str(ring_map), "runs": 150, "agents": 1, "steps": 600}
    flat["battery.enabled"] = False
    flat["record.timeline"] = timeline
    one = folder_bytes({**flat, "threads": 1}, tmp_path / "one")
    lanes_seen.clear()
    assert folder_bytes({**flat, "threads": 2}, tmp_path / "two") == one
    per_lane = {lane: {(lo, hi) for l2, lo, hi, _ in lanes_seen if l2 == lane} for lane in (0, 1)}
    assert per_lane == {0: {(0, 75)}, 1: {(75, 150)}}


def test_checkpointed_runs_in_threads(tmp_path, lanes_seen, stop_and_resume):
    """`qpatrol train` keeps a checkpointer: its blocks are cut into lanes too, and a
    run stopped and resumed with two threads ends as one thread's uninterrupted run."""
    flat = {**BASE, "runs": 4, "agents": 2, "steps": 1500}
    whole = simulate(from_flat({**flat, "threads": 1}))
    lanes_seen.clear()
    resumed = stop_and_resume(from_flat({**flat, "threads": 2}), tmp_path / "cp", 700)
    assert {lane for lane, *_ in lanes_seen} == {0, 1}
    a, b = written(whole, tmp_path / "a"), written(resumed, tmp_path / "b")
    a.pop("meta.json"), b.pop("meta.json")
    assert a == b


def test_lanes_cut_the_runs_in_order():
    big = threads.MIN_LANE_WORK
    assert threads.lanes(5, 2, big) == [(0, 2), (2, 5)]
    assert threads.lanes(5, 3, big) == [(0, 1), (1, 3), (3, 5)]
    assert threads.lanes(8, 4, big) == [(0, 2), (2, 4), (4, 6), (6, 8)]
    assert threads.lanes(2, 8, big) == [(0, 1), (1, 2)]  # at most one lane per run
    assert threads.lanes(1, 4, big) == [(0, 1)]
    assert threads.lanes(8, 1, big) == [(0, 8)]
    assert threads.lanes(8, 2, big - 1) == [(0, 8)]  # too little work to hand over


def test_threads_resolve_to_this_process_share(monkeypatch):
    monkeypatch.setattr(limits, "cores", lambda: 8)
    monkeypatch.setattr(threads, "_share", None)
    assert threads.resolve(0) == 8  # a process of its own: every core
    assert threads.resolve(3) == 3  # asked for
    assert threads.share_of(2) == 4 and threads.share_of(3) == 2 and threads.share_of(16) == 1
    threads.set_share(threads.share_of(4))  # a worker of a pool of 4
    assert threads.resolve(0) == 2 and threads.resolve(5) == 5
    threads.set_share(None)
    assert threads.resolve(0) == 8


def test_pool_workers_share_the_cores(monkeypatch, tmp_path):
    """A sweep's workers get their share of the cores (two jobs on two cores: one
    thread each); the share is set in the worker before its points run."""
    from qpatrol.study import sweep

    monkeypatch.setattr(threads, "_share", None)
    got = []
    monkeypatch.setattr(sweep, "_run_points", lambda *a: got.append(threads.resolve(0)) or [])
    assert sweep._run_tagged("t", [], None, tmp_path, {}, 1) == ("t", [])
    assert got == [1]


def test_threads_is_an_execution_key():
    a = from_flat({"runs": 3})
    b = from_flat({"runs": 3, "threads": 2})
    assert a.digest() == b.digest() and a.to_yaml() == b.to_yaml()
    for bad in (-1, 1.5, "two"):
        with pytest.raises(ConfigError, match=r"^threads: got .*; allowed"):
            from_flat({"threads": bad})


def test_lane_buffers_hold_their_own_runs(monkeypatch, lanes_seen):
    """Lanes other than the first get row buffers for their own runs, not the batch's
    (a third of them here), and working arrays of their own."""
    from qpatrol.engines import numba_core

    loops = []
    real = numba_core.Loop.run
    monkeypatch.setattr(
        numba_core.Loop, "run", lambda self, *a, **k: loops.append(self) or real(self, *a, **k)
    )
    flat = {**BASE, "runs": 9, "agents": 2, "threads": 3, "record.transitions": True}
    simulate(from_flat(flat))
    loop = loops[0]
    first = loop.args
    for lane in (1, 2):
        runs, args = loop._lanes[lane]
        assert runs == 3
        for name in ("ep_buf", "up_int", "up_float"):
            mine, whole = getattr(args[loop.out_at], name), getattr(first[loop.out_at], name)
            assert mine.shape[0] * 3 == whole.shape[0] > 0
        assert all(a is not b for a, b in zip(args[-1], first[-1], strict=True))


def test_lanes_only_for_calls_worth_a_hand_over(monkeypatch, tmp_path):
    """At the default threshold a batch's calls of thousands of agent-steps are cut
    into lanes, and a checkpointer's calls of one team step are not."""
    pytest.importorskip("numba")
    from qpatrol.engines import numba_core
    from qpatrol.run import checkpoint as ck

    lanes = []
    real = numba_core.Loop._lane
    monkeypatch.setattr(
        numba_core.Loop, "_lane", lambda self, i, *a: lanes.append(i) or real(self, i, *a)
    )
    flat = {**BASE, "runs": 4, "agents": 2, "steps": 3000, "threads": 2}
    simulate(from_flat(flat))  # one call of 4 x 2 x 3,000 agent-steps
    assert sorted(lanes) == [0, 1]

    class EveryStep(ck.Checkpointer):
        every_step = True

    lanes.clear()
    simulate(from_flat({**flat, "steps": 50}), checkpoint=EveryStep(tmp_path / "cp", every=0))
    assert lanes == [0] * 50


POLICIES = ("qlearning", "qlearning-idleness", "random", "conscientious",
            "shared-conscientious", "evap", "cyclic", "partition", "hcr", "cc", "gbs",
            "sebs", "dta-greedy", "dta-ssi", "dta-ssi-part", "cbls",
            "learned-tour", "hpcc", "gravitational")  # fmt: skip


@pytest.mark.parametrize("battery", [False, True])
@pytest.mark.parametrize("policy", POLICIES)
def test_lanes_share_nothing_they_write(monkeypatch, policy, battery):
    """The contract lanes rest on, checked without relying on a race to show: the
    compiled loop writes only per-run arrays (cut by run for each lane) and each lane's
    own ones, never an array the lanes share (the world's constants, the strategy's
    constants, or a placeholder of one row). Writing the robots' rewards of
    ``qlearning-idleness`` into one shared row, as it once did, fails here."""
    pytest.importorskip("numba")
    from qpatrol.engines import COMPILED_POLICIES, numba_core

    assert set(POLICIES) == set(COMPILED_POLICIES)
    shared = []
    init = numba_core.Loop.__init__

    def spy(self, *args, **kwargs):
        init(self, *args, **kwargs)
        for f, name in enumerate(self.pack._fields):
            if f not in self.pack_per_run:
                shared.append((name, self.pack[f], self.pack[f].copy()))
        out = self.args[self.out_at]  # each lane's own: its output rows, working arrays
        own = {id(getattr(out, b)) for b in ("ep_buf", "up_int", "up_float", "tl_buf")}
        for j, a in enumerate(self.args[:-1]):  # the world's constants (map, battery, ...)
            if a is self.pack:
                continue
            named = a._asdict().items() if isinstance(a, tuple) else [(f"argument {j}", a)]
            for name, x in named:
                if isinstance(x, np.ndarray) and id(x) not in self._per_run | own:
                    shared.append((name, x, x.copy()))

    monkeypatch.setattr(numba_core.Loop, "__init__", spy)
    flat = {**BASE, "runs": 3, "agents": 3, "policy": policy, "battery.enabled": battery}
    simulate(from_flat({**flat, "battery.capacity": 60, "threads": 1}))
    assert shared
    for name, after, before in shared:
        assert np.array_equal(after, before), (policy, name)
