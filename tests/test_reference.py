"""The plain-Python reference loop learns the core's Q-table from the same uniforms,
and ``qpatrol bench`` reports both."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from qpatrol import world
from qpatrol.cli import app
from qpatrol.config import from_flat
from qpatrol.maps import DIRECTIONS
from qpatrol.run import reference, simulate
from qpatrol.world.rng import Streams, run_seeds


@pytest.mark.parametrize(
    "extra",
    [
        {"agents": 1},
        {"agents": 1, "learning.epsilon": 0.2, "learning.gamma": 0.7},
        {"agents": 3, "team.avoid_collisions": False, "team.communication": False},
        {"agents": 2, "team.avoid_collisions": False, "learning.state_space": "cell"},
    ],
)
def test_reference_loop_gives_the_cores_q_table(rooms_map, extra):
    flat = {
        "map": str(rooms_map),
        "steps": 700,
        "seed": 2,
        "battery.enabled": False,
        "max_episode_steps": 90,
        "engine": "numpy",
        **extra,
    }
    cfg = from_flat(flat)
    core = simulate(cfg)
    k = cfg["agents"]
    streams = Streams(run_seeds(cfg["seed"], 1), k)
    starts = world.place_agents(core.params, core.map, streams.generators[0]).tolist()
    q_init = [cfg[f"learning.q_init.{d}"] * cfg["learning.multiplier"] for d in DIRECTIONS]
    ref = reference.run(
        core.params,
        starts,
        streams.take(cfg["steps"])[0],
        q_init,
        cfg["learning.gamma"],
        cfg["learning.epsilon"],
        cfg["learning.state_space"] == "cell_heading",
    )
    q, n = ref.arrays(core.params.n_cells, k, q_init)
    assert n.sum() > 0
    np.testing.assert_array_equal(n, core.strategy.n[0])
    assert np.array_equal(q, core.strategy.q[0])  # to the bit
    assert ref.pos == core.state.pos[0].tolist()


def test_bench_command_json():
    res = CliRunner().invoke(app, ["bench", "--runs", "2", "--steps", "300", "--json"])
    assert res.exit_code == 0, res.output
    b = json.loads(res.stdout)
    for key in ("agent_steps_per_s", "reference_agent_steps_per_s", "ratio", "engine"):
        assert key in b
    assert b["agent_steps"] == 600 and b["bytes_per_run"] > 0 and b["ratio"] > 0
    assert b["threads"] == 1  # a small batch: numpy, one thread
    # end to end as `qpatrol train` runs it (timed apart: no order between the two times
    # of so small a workload on a shared machine)
    assert b["train_seconds"] > 0 and b["seconds"] > 0 and b["loop"] == "general"
    assert b["train_agent_steps_per_s"] == pytest.approx(600 / b["train_seconds"])
    assert b["train_overhead"] == pytest.approx(b["train_seconds"] / b["seconds"] - 1)


def test_bench_times_train_through_trains_own_path(monkeypatch):
    """The bench's train timing goes through :func:`qpatrol.run.train` (what `qpatrol
    train` calls) with train's checkpointer, and writes a run folder."""
    from qpatrol import run
    from qpatrol.run import bench

    seen = []
    real = run.train

    def spy(cfg, out, checkpoint, *args, **kwargs):
        result = real(cfg, out, checkpoint, *args, **kwargs)
        seen.append((type(checkpoint).__name__, sorted(p.name for p in out.iterdir())))
        assert checkpoint.every == 60 and not checkpoint.folder.exists()
        return result

    monkeypatch.setattr(run, "train", spy)
    b = bench.bench(bench.workload(1, 2, 300, engine="numpy"))
    assert seen and seen[0][0] == "Checkpointer" and "summary.json" in seen[0][1]
    assert b["train_seconds"] > 0


def test_bench_reports_the_threads_that_ran():
    pytest.importorskip("numba")
    args = ["bench", "--runs", "3", "--steps", "400", "--engine", "numba", "--json"]
    for asked, ran in (("1", 1), ("2", 2), ("8", 3)):  # at most one thread per run
        res = CliRunner().invoke(app, [*args, "--threads", asked])
        assert res.exit_code == 0, res.output
        assert json.loads(res.stdout)["threads"] == ran
    res = CliRunner().invoke(app, [*args[:-1], "--threads", "2"])
    assert "engine numba, 2 threads" in res.stdout
    res = CliRunner().invoke(app, [*args, "--threads", "-1"])
    assert res.exit_code == 2 and "threads: got -1" in res.stderr


def test_bench_command_text_and_errors():
    res = CliRunner().invoke(app, ["bench", "--steps", "200", "--engine", "numpy"])
    assert res.exit_code == 0 and "ratio" in res.stdout and "engine numpy" in res.stdout
    res = CliRunner().invoke(app, ["bench", "--engine", "fast"])
    assert res.exit_code == 2 and "engine: got 'fast'" in res.stderr


def test_bench_warms_up_the_engine_it_times(monkeypatch):
    """Under ``engine: auto`` a workload large enough for the compiled engine is warmed
    up on it (the warm-up's few steps alone would take numpy, and loading the compiled
    loop would then fall inside the timing)."""
    pytest.importorskip("numba")
    from qpatrol.run import bench

    seen = []
    real = bench.simulate
    monkeypatch.setattr(
        bench, "simulate", lambda cfg, **kw: seen.append(cfg["engine"]) or real(cfg, **kw)
    )
    bench.time_core(bench.workload(2, 2, 6000, engine="auto"))
    assert seen == ["numba", "auto"]
    seen.clear()
    bench.time_core(bench.workload(1, 1, 300, engine="auto"))  # small: numpy throughout
    assert seen == ["numpy", "auto"]


def test_bench_default_steps_take_about_a_second(monkeypatch):
    """Without --steps a workload is about 20 M agent-steps compiled, 1 M on numpy,
    within bounds (a run of 50,000 steps took 4 ms, mostly setting it up)."""
    from qpatrol import engines
    from qpatrol.run import bench

    assert bench.default_steps(1, 1, "numba") == 20_000_000
    assert bench.default_steps(16, 4, "numba") == 312_500
    assert bench.default_steps(2048, 1, "numba") == 9_765
    assert bench.default_steps(100_000, 8, "numba") == 1_000
    assert bench.default_steps(1, 1, "numpy") == 20_000
    assert bench.default_steps(2048, 1, "numpy") == 488
    assert bench.default_steps(4096, 4, "numpy") == 400
    monkeypatch.setattr(engines, "numba_installed", lambda: False)
    assert bench.default_steps(2048, 1, "auto") == 488  # auto without numba: numpy
    seen = []
    monkeypatch.setattr(bench, "default_steps", lambda r, k, e: seen.append((r, k, e)) or 300)
    res = CliRunner().invoke(app, ["bench", "--runs", "2", "--engine", "numpy", "--json"])
    assert res.exit_code == 0, res.output
    assert seen == [(2, 1, "numpy")] and json.loads(res.stdout)["steps"] == 300


def test_bench_times_the_reference_before_and_after_the_core(monkeypatch):
    """The reference loop brackets the core: its rate is that of both timings together,
    the drift is the change between them, and a large drift is reported."""
    from qpatrol.run import bench

    calls = []
    ref_seconds = iter([1.0, 3.0])  # 100 agent-steps in 1 s, then in 3 s
    monkeypatch.setattr(
        bench, "time_reference", lambda cfg: calls.append("ref") or (next(ref_seconds), 100)
    )
    real_core = bench.time_core
    monkeypatch.setattr(bench, "time_core", lambda cfg: calls.append("core") or real_core(cfg))
    b = bench.bench(bench.workload(1, 1, 50, engine="numpy"))
    assert calls == ["ref", "core", "ref"]
    assert b["reference_agent_steps_per_s"] == 50.0  # 200 agent-steps in 4 s
    assert b["ratio"] == b["agent_steps_per_s"] / 50.0
    assert b["reference_drift"] == pytest.approx(1.0 / 3.0 - 1.0)
    text = bench.report(b)
    assert "before and after: -67%" in text and "warning" in text and "uncertain" in text
    assert "warning" not in bench.report({**b, "reference_drift": 0.05})


def test_bench_times_both_loops_with_the_garbage_collector_off(monkeypatch):
    """As timeit does: a full collection's cost depends on the process, not on the loop
    timed. Both timings run with gc disabled; gc is back on afterwards, and a caller's
    disabled gc stays disabled."""
    import gc

    from qpatrol.run import bench

    seen = []
    real_ref, real_sim = bench.reference.run, bench.simulate
    monkeypatch.setattr(
        bench.reference,
        "run",
        lambda *a, **k: seen.append(("ref", gc.isenabled())) or real_ref(*a, **k),
    )
    monkeypatch.setattr(
        bench,
        "simulate",
        lambda *a, **k: seen.append(("core", gc.isenabled())) or real_sim(*a, **k),
    )
    assert gc.isenabled()
    b = bench.bench(bench.workload(1, 1, 50, engine="numpy"))
    # the warm-up's simulate runs with gc on; the timed one and both references with it off
    assert seen == [("ref", False), ("core", True), ("core", False), ("ref", False)]
    assert gc.isenabled() and b["gc_during_timings"] is False
    assert "both timed with gc off" in bench.report(b)
    gc.disable()
    try:
        with bench.no_gc():
            pass
        assert not gc.isenabled()
    finally:
        gc.enable()
