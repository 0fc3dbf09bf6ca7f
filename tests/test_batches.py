"""A config computed in batches under ``memory.limit_gib`` writes the files of one batch.

Each run draws from its own ``SeedSequence(seed, spawn_key=(point, r))``, so splitting
the runs into consecutive batches must not change any number: every file of the run
folder (episodes, summary, visits.npz, q_table.npz, the recorders' CSVs) is compared
byte for byte with the single-batch result.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from qpatrol.config import ConfigError, from_flat
from qpatrol.maps import get_map
from qpatrol.run import simulate, write_run
from qpatrol.strategies import NAMES
from qpatrol.world import limits

META = {"started": "-", "ended": "-"}
RUNS = 5


def tiny_limit(flat: dict, per_batch: int) -> float:
    """``memory.limit_gib`` that makes batches of ``per_batch`` runs of ``flat``."""
    cfg = from_flat(flat)
    m = get_map(cfg["map"])
    need = limits.batch_bytes(cfg, m) + per_batch * limits.bytes_per_run(cfg, m)
    return (need + 1) / 2**30


def same_files(flat: dict, tmp_path: Path, per_batch: int = 2) -> None:
    one = from_flat({**flat, "runs": RUNS})
    split = from_flat({**flat, "runs": RUNS, "memory.limit_gib": tiny_limit(flat, per_batch)})
    assert limits.batch_runs(one, get_map(one["map"])) >= RUNS
    assert limits.batch_runs(split, get_map(split["map"])) == per_batch
    seen = []
    whole = simulate(one)
    parts = simulate(split, progress=lambda done, total: seen.append((done, total)))
    assert parts.run_ids.tolist() == list(range(RUNS))
    assert seen[-1] == (one["steps"], one["steps"])
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)
    a = write_run(whole, tmp_path / "one", meta=META)
    b = write_run(parts, tmp_path / "split", meta=META)
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for name in names:
        if name != "meta.json":  # meta.json: the engine (auto) may differ by batch size
            assert (a / name).read_bytes() == (b / name).read_bytes(), (flat, name)


RECORD = {
    "seed": 7,
    "steps": 400,
    "max_episode_steps": 90,
    "record.trajectory": 6,
    "record.timeline": 50,
    "record.warmup": 30,
}


@pytest.mark.parametrize("engine", ["numpy", "numba"])
@pytest.mark.parametrize("battery", [False, True])
@pytest.mark.parametrize("agents", [1, 3])
def test_qlearning_in_three_batches(tmp_path, engine, battery, agents):
    if engine == "numba":
        pytest.importorskip("numba")
    flat = {
        **RECORD,
        "map": "map_b",
        "agents": agents,
        "engine": engine,
        "battery.enabled": battery,
        "battery.capacity": 60,
    }
    same_files(flat, tmp_path)


def test_recorders_and_episode_quota_in_batches(tmp_path):
    flat = {
        **RECORD,
        "map": "map_b",
        "agents": 2,
        "record.transitions": True,
        "record.watch": [3, 10],
        "episodes": 2,
        "max_episode_steps": 40,
    }
    same_files(flat, tmp_path, per_batch=1)


@pytest.mark.parametrize("policy", [n for n in NAMES if n != "qlearning"])
def test_every_strategy_in_batches(tmp_path, policy):
    # 200 steps: two episodes of each run end (max_episode_steps 90), four timeline
    # windows close, the measures count after the warmup
    flat = {**RECORD, "steps": 200, "map": "map_b", "agents": 2, "policy": policy}
    same_files(flat, tmp_path)


def test_limit_is_an_execution_key():
    a = from_flat({"runs": 3})
    b = from_flat({"runs": 3, "memory.limit_gib": 0.5})
    assert a.digest() == b.digest() and a.to_yaml() == b.to_yaml()
    with pytest.raises(ConfigError, match="memory.limit_gib"):
        from_flat({"memory.limit_gib": 0})


@pytest.mark.parametrize("agents", [1, 4])
@pytest.mark.parametrize("battery", [False, True])
def test_bench_reports_the_estimate(agents, battery):
    """``qpatrol bench`` reports :func:`qpatrol.world.limits.bytes_per_run`, which covers the
    per-run arrays actually allocated."""
    from qpatrol.run.bench import bench, workload

    cfg = workload(3, agents, 200, "numpy", extra={"battery.enabled": battery})
    b = bench(cfg)
    assert b["bytes_per_run"] == limits.bytes_per_run(cfg, get_map("map_a"))
    assert b["array_bytes_per_run"] <= b["bytes_per_run"] < 1.5 * b["array_bytes_per_run"]
    assert b["batch_runs"] == 3


def test_sweep_points_in_batches(tmp_path):
    """A sweep whose points are split into batches writes the same folders and
    ``results.csv`` (the limit is not part of the config: same point folders)."""
    from qpatrol.study.sweep import points_for, run_sweep

    flat = {**RECORD, "map": "map_b", "agents": 2, "runs": RUNS}
    points = points_for("learning.gamma", [0.1, 0.5])
    run_sweep(from_flat(flat), points, tmp_path / "one")
    limit = tiny_limit(flat, 2)
    run_sweep(from_flat({**flat, "memory.limit_gib": limit}), points, tmp_path / "split")
    a, b = tmp_path / "one", tmp_path / "split"
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for f in files:
        if f.name not in ("meta.json", "sweep.json"):
            assert (a / f).read_bytes() == (b / f).read_bytes(), f
