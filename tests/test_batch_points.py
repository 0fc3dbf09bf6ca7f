"""Sweep points sharing batches (qpatrol.run.batching): the same files as one point at a time."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from covering import pairs

import qpatrol.run.batching
from qpatrol.config import from_mapping
from qpatrol.run import batching
from qpatrol.study import sweep
from qpatrol.study.sweep import grid_points, listed_points, points_for, run_sweep

TINY = """\
; name: tiny
#######
#0...1#
#.#.#.#
#.....#
#######
"""
#: A bigger map, with room for four robots (avoiding collisions).
HALL = """\
; name: hall
###########
#0.......1#
#.#.#.#.#.#
#.........#
#.#.#.#.#.#
#2.......3#
###########
"""

#: Sweeps over the per-run values: the learner's, the reward's, and both with the seed.
SWEEPS = {
    "gamma": [{"learning.gamma": g} for g in (0.1, 0.5, 0.9)],
    "reward": [
        {"reward.incremental_value": 0.5},
        {"reward.idle_horizon": 7.0, "reward.lambda": 2.0},
        {"reward.lambda": 0.0, "reward.incremental_value": 0.0},
    ],
    "explore": [
        {"learning.epsilon": 0.0, "learning.multiplier": 10},
        {"learning.epsilon": 0.2, "learning.multiplier": 1000},
        {"learning.epsilon": 0.05, "learning.q_init.north": 0.5, "seed": 11},
    ],
}


@pytest.fixture
def maps(tmp_path: Path) -> dict[int, Path]:
    (tmp_path / "tiny.txt").write_text(TINY)
    (tmp_path / "hall.txt").write_text(HALL)
    return {1: tmp_path / "tiny.txt", 4: tmp_path / "hall.txt"}


def make_base(map_path: Path, agents: int, engine: str = "numpy", record: bool = True, **extra):
    tree = {
        "map": str(map_path),
        "agents": agents,
        "runs": 2,
        "seed": 7,
        "steps": 240,
        "battery": False,
        "engine": engine,
        "record": {"transitions": record, "timeline": 40 if record else 0, "trajectory": 5},
    }
    tree.update(extra)
    return from_mapping(tree)


def assert_same_sweeps(a: Path, b: Path) -> None:
    """Every file of every point folder and results.csv byte-identical; meta.json up to
    its times."""
    assert (a / "results.csv").read_bytes() == (b / "results.csv").read_bytes()
    files_a = sorted(p.relative_to(a) for p in (a / "points").rglob("*"))
    assert files_a == sorted(p.relative_to(b) for p in (b / "points").rglob("*"))
    assert files_a
    for rel in files_a:
        fa, fb = a / rel, b / rel
        if fa.is_dir():
            continue
        if fa.name == "meta.json":
            ma, mb = json.loads(fa.read_text()), json.loads(fb.read_text())
            for m in (ma, mb):
                m.pop("started"), m.pop("ended")
            assert ma == mb, rel
        else:
            assert fa.read_bytes() == fb.read_bytes(), rel


class Count:
    """Wraps a function and counts its calls (and the rows of a batch's seeds)."""

    def __init__(self, fn):
        self.fn, self.calls, self.rows = fn, 0, []

    def __call__(self, *args, **kwargs):
        self.calls += 1
        if len(args) > 1 and isinstance(args[1], list):
            self.rows.append(len(args[1]))
        return self.fn(*args, **kwargs)


#: (kind, agents, engine, record): each sweep kind with two rows whose other settings
#: are each other's opposite; every pair of values of any two columns occurs.
BATCHED = pairs(
    [tuple(SWEEPS), (1, 4), ("numpy", "numba"), (True, False)],
    [
        ("gamma", 1, "numpy", True),
        ("gamma", 4, "numba", False),
        ("reward", 1, "numba", False),
        ("reward", 4, "numpy", True),
        ("explore", 4, "numpy", False),
        ("explore", 1, "numba", True),
    ],
)


@pytest.mark.parametrize("kind, agents, engine, record", BATCHED)
def test_batched_sweep_gives_the_same_files(
    maps, tmp_path, monkeypatch, engine, kind, agents, record
):
    if engine == "numba":
        pytest.importorskip("numba")
    base = make_base(maps[agents], agents, engine, record)
    pts = listed_points(SWEEPS[kind])
    count = Count(qpatrol.run.batching.simulate_rows)
    monkeypatch.setattr(qpatrol.run.batching, "simulate_rows", count)
    r1 = run_sweep(base, pts, tmp_path / "batched", meta={})
    assert count.calls == 1 and count.rows == [6]  # one batch: 3 points x 2 runs
    r2 = run_sweep(base, pts, tmp_path / "alone", meta={}, batch_points=False)
    assert count.calls == 1
    assert r1.ok and r2.ok and r1.done == r2.done == [p.id for p in pts]
    assert_same_sweeps(tmp_path / "batched", tmp_path / "alone")
    # the values really differ between the points (a batch that gave every row point
    # 0's values would give equal summaries)
    summaries = {(tmp_path / "batched" / "points" / p.id / "summary.json").read_text() for p in pts}
    assert len(summaries) == 3


def test_rows_use_their_own_point_values(maps):
    """Row by row, a mixed batch equals each point's own batch (gamma differs)."""
    from qpatrol.maps import get_map
    from qpatrol.run import simulate

    base = make_base(maps[4], 4, record=False)
    cfgs = [base.replace(**{"learning.gamma": g}) for g in (0.2, 0.8)]
    got = {}
    batching.run_group(
        [(i, i, c) for i, c in enumerate(cfgs)],
        get_map(base["map"]),
        lambda p, r: got.setdefault(p, r),
    )
    for i, c in enumerate(cfgs):
        own = simulate(c, point=i)
        assert np.array_equal(got[i].strategy.q, own.strategy.q)
        assert got[i].summary == own.summary
        assert list(got[i].run_ids) == [0, 1]
    assert not np.array_equal(got[0].strategy.q, got[1].strategy.q)


def test_memory_limit_splits_a_group_into_batches(maps, tmp_path, monkeypatch):
    """Batches of at most limits.batch_runs rows, cutting points in two: same files."""
    base = make_base(maps[1], 1, runs=3)
    pts = points_for("learning.gamma", [0.1, 0.5, 0.9])
    count = Count(qpatrol.run.batching.simulate_rows)
    monkeypatch.setattr(qpatrol.run.batching, "simulate_rows", count)
    monkeypatch.setattr(qpatrol.run.batching.limits, "batch_runs", lambda cfg, m: 4)
    run_sweep(base, pts, tmp_path / "batched", meta={})
    assert count.rows == [4, 4, 1]
    run_sweep(base, pts, tmp_path / "alone", meta={}, batch_points=False)
    assert_same_sweeps(tmp_path / "batched", tmp_path / "alone")


def test_points_differing_in_other_keys_are_not_grouped(maps, tmp_path, monkeypatch):
    count = Count(qpatrol.run.batching.simulate_rows)
    monkeypatch.setattr(qpatrol.run.batching, "simulate_rows", count)
    base = make_base(maps[4], 2, record=False, steps=60)
    # agents x gamma: one batch per team size
    pts = grid_points({"agents": [1, 2], "learning.gamma": [0.1, 0.9]})
    run_sweep(base, pts, tmp_path / "agents", meta={})
    assert count.calls == 2 and count.rows == [4, 4]
    # maps: never in one batch
    count.calls, count.rows = 0, []
    shutil.copy(maps[4], tmp_path / "hall2.txt")
    pts = listed_points(
        [
            {"map": str(maps[4]), "learning.gamma": 0.1},
            {"map": str(tmp_path / "hall2.txt"), "learning.gamma": 0.5},
        ]
    )
    run_sweep(base, pts, tmp_path / "maps", meta={})
    assert count.calls == 0  # two groups of one point: each runs alone (run.simulate)
    # policies: a strategy that does not name its per-run arrays is never grouped
    pts = points_for("policy", ["qlearning", "random"])
    assert [len(g) for g in batching.groups([base.replace(**p.overrides) for p in pts])] == [
        1,
        1,
    ]
    random = base.replace(policy="random")
    assert batching.groups([random, random.replace(seed=3)]) == [[0], [1]]
    # qlearning-idleness: its own qidle.* keys are not per-run
    qidle = base.replace(policy="qlearning-idleness")
    assert batching.groups([qidle, qidle.replace(**{"qidle.gamma": 0.5})]) == [[0], [1]]
    assert batching.groups([qidle, qidle.replace(seed=5)]) == [[0, 1]]


def test_two_workers_get_two_tasks_of_a_group(maps):
    """jobs=2 with one group of 9 points: cut by points until no task of several points
    costs more than half of the whole (9 -> 5 + 4 -> 3 + 2 + 4)."""
    base = make_base(maps[1], 1)
    pts = points_for("learning.gamma", [round(0.1 * i, 1) for i in range(1, 10)])
    items = [(None, p, base.replace(**p.overrides), None, Path(".")) for p in pts]
    assert [len(t[1]) for t in sweep._tasks(items, 1, True)] == [9]
    two = sweep._tasks(items, 2, True)
    assert [len(t[1]) for t in two] == [3, 2, 4]
    assert [p for t in two for p, _ in t[1]] == pts
    assert [len(t[1]) for t in sweep._tasks(items, 4, True)] == [2, 1, 2, 2, 2]
    assert [len(t[1]) for t in sweep._tasks(items, 2, False)] == [1] * 9
    # a cheap group beside a costly point is not cut: it is below its fair share
    assert batching.tasks([[0, 1, 2], [3]], 2, [1.0, 1.0, 1.0, 10.0]) == [[0, 1, 2], [3]]


def test_a_pool_starts_on_different_compiled_loops(maps):
    """The first task of each compiled loop goes first (each worker then compiles a
    different one at once); the others keep their order, and numpy tasks stay where
    they were among them."""
    base = make_base(maps[1], 1, engine="numba", record=False)
    any_ = base.replace(**{"battery.enabled": True})
    team = base.replace(agents=4, **{"battery.enabled": False})
    solo = base.replace(agents=1, **{"battery.enabled": False})
    numpy = base.replace(engine="numpy")
    cfgs = [any_, any_.replace(seed=2), numpy, team, any_.replace(seed=3), solo, team]
    tasks = [(i, [(None, c)], None, Path(".")) for i, c in enumerate(cfgs)]
    assert [sweep.compiled_loop(c) for c in cfgs] == [
        "any",
        "any",
        None,
        "qlearning-team",
        "any",
        "qlearning-solo",
        "qlearning-team",
    ]
    assert [t[0] for t in sweep._distinct_loops_first(tasks)] == [0, 3, 5, 1, 2, 4, 6]


def test_two_workers_batched_sweep_is_identical(maps, tmp_path):
    base = make_base(maps[1], 1)
    pts = points_for("learning.gamma", [0.1, 0.3, 0.5, 0.7, 0.9])
    calls = []
    r = run_sweep(
        base, pts, tmp_path / "j2", jobs=2, meta={}, progress=lambda d, t: calls.append(d)
    )
    assert r.ok and calls[-1] == 10 and calls == sorted(calls)
    run_sweep(base, pts, tmp_path / "j1", meta={}, batch_points=False)
    assert_same_sweeps(tmp_path / "j2", tmp_path / "j1")


def test_resume_runs_only_the_missing_points_of_a_group(maps, tmp_path, monkeypatch):
    base = make_base(maps[1], 1)
    pts = points_for("learning.gamma", [0.1, 0.3, 0.5, 0.7])
    out = tmp_path / "s"
    run_sweep(base, pts, out, meta={})
    first = (out / "results.csv").read_bytes()
    for p in (pts[1], pts[3]):
        shutil.rmtree(out / "points" / p.id)
    count = Count(qpatrol.run.batching.simulate_rows)
    monkeypatch.setattr(qpatrol.run.batching, "simulate_rows", count)
    r = run_sweep(base, pts, out, meta={})
    assert r.done == [pts[1].id, pts[3].id] and r.skipped == [pts[0].id, pts[2].id]
    assert count.rows == [4]  # the two missing points' runs, in one batch
    assert (out / "results.csv").read_bytes() == first
    run_sweep(base, pts, tmp_path / "alone", meta={}, batch_points=False)
    assert_same_sweeps(out, tmp_path / "alone")


def test_a_failing_batch_fails_each_of_its_points(maps, tmp_path, monkeypatch):
    base = make_base(maps[1], 1)
    pts = points_for("learning.gamma", [0.1, 0.5, 0.9])
    out = tmp_path / "f"

    def boom(*a, **k):
        raise RuntimeError("boom in a shared batch")

    monkeypatch.setattr(qpatrol.run.batching, "simulate_rows", boom)
    r = run_sweep(base, pts, out, meta={})
    assert r.failed == [p.id for p in pts] and not r.done
    for p in pts:
        info = json.loads((out / "points" / f"{p.id}.failed.json").read_text())
        assert info["message"] == "boom in a shared batch" and info["id"] == p.id
    assert not list((out / "points").glob(".*progress.tmp"))
    monkeypatch.undo()
    r = run_sweep(base, pts, out, meta={})
    assert r.ok and r.done == [p.id for p in pts]
    assert not list((out / "points").glob("*.failed.json"))
    run_sweep(base, pts, tmp_path / "alone", meta={}, batch_points=False)
    assert_same_sweeps(out, tmp_path / "alone")


def test_every_point_of_a_group_reports_progress(maps):
    from qpatrol.maps import get_map

    base = make_base(maps[1], 1, runs=3)
    cfgs = [base.replace(**{"learning.gamma": g}) for g in (0.1, 0.5)]
    seen: dict[int, list[float]] = {0: [], 1: []}
    written = []
    batching.run_group(
        [(i, i, c) for i, c in enumerate(cfgs)],
        get_map(base["map"]),
        lambda p, r: written.append(p),
        lambda p, done, total: seen[p].append(done / total),
    )
    assert written == [0, 1]
    for p in (0, 1):
        assert seen[p] and seen[p] == sorted(seen[p]) and seen[p][-1] == 1.0


def test_cli_no_batch_points(maps, tmp_path, monkeypatch):
    from qpatrol import cli

    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"map: {maps[1]}\nruns: 2\nsteps: 100\nbattery: false\n")
    count = Count(qpatrol.run.batching.simulate_rows)
    monkeypatch.setattr(qpatrol.run.batching, "simulate_rows", count)
    for flag, out in (([], "a"), (["--no-batch-points"], "b")):
        args = ["sweep", "learning.gamma", "--values", "0.1,0.9", str(cfg), "--out"]
        with pytest.raises(SystemExit) as e:
            cli.main([*args, str(tmp_path / out), "-q", *flag])
        assert e.value.code in (0, None)
    assert count.calls == 1
    assert (tmp_path / "a" / "results.csv").read_bytes() == (
        tmp_path / "b" / "results.csv"
    ).read_bytes()


@pytest.mark.parametrize("engine", ["numpy", "numba"])
def test_qlearning_idleness_points_share_batches(maps, tmp_path, monkeypatch, engine):
    if engine == "numba":
        pytest.importorskip("numba")
    base = make_base(maps[4], 4, engine, policy="qlearning-idleness")
    pts = listed_points([{"seed": 1}, {"seed": 2, "reward.lambda": 3.0}, {"learning.gamma": 0.2}])
    count = Count(qpatrol.run.batching.simulate_rows)
    monkeypatch.setattr(qpatrol.run.batching, "simulate_rows", count)
    run_sweep(base, pts, tmp_path / "batched", meta={})
    assert count.rows == [6]
    run_sweep(base, pts, tmp_path / "alone", meta={}, batch_points=False)
    assert_same_sweeps(tmp_path / "batched", tmp_path / "alone")
