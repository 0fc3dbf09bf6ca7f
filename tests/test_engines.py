"""The compiled engine writes the numpy engine's files to the bit, on every config.

Configs the compiled engine covers (qlearning, without transition/watch recorders) run
through both loops;
the rest must fall back to the numpy engine and say so. Every file of the run folder
is compared byte for byte; in ``meta.json`` only ``loop_engine``/``loop_engine_note``
(which loop ran) may differ.
"""

from __future__ import annotations

import json
from pathlib import Path

import mazes
import pytest

from qpatrol import engines
from qpatrol.config import ConfigError, from_flat
from qpatrol.run import simulate, write_run
from qpatrol.strategies import NAMES

pytest.importorskip("numba")

META = {"started": "-", "ended": "-"}
ENGINE_FIELDS = ("loop_engine", "loop_engine_note")


def both(flat: dict, tmp_path: Path) -> tuple[str, str]:
    """Run ``flat`` on both engines, compare every file; ``(engine, note)`` of numba's."""
    folders = {}
    ran = {}
    for engine in ("numpy", "numba"):
        result = simulate(from_flat({**flat, "engine": engine}))
        ran[engine] = (result.engine, result.engine_note)
        folders[engine] = write_run(result, tmp_path / engine, replace=True, meta=META)
    a, b = folders["numpy"], folders["numba"]
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for name in names:
        if name == "meta.json":
            ma, mb = (json.loads((f / name).read_text()) for f in (a, b))
            for key in ENGINE_FIELDS:
                ma.pop(key, None), mb.pop(key, None)
            assert ma == mb
        else:
            assert (a / name).read_bytes() == (b / name).read_bytes(), (flat, name)
    assert ran["numpy"] == ("numpy", "")
    return ran["numba"]


BASE = {"runs": 2, "seed": 11, "steps": 160, "max_episode_steps": 60, "record.trajectory": 5}


@pytest.mark.parametrize("agents", [1, 2, 4, 8])
@pytest.mark.parametrize("communication", [True, False])
@pytest.mark.parametrize("avoid", [True, False])
@pytest.mark.parametrize("battery", [True, False])
def test_compiled_qlearning_teams(rooms_map, tmp_path, agents, communication, avoid, battery):
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": agents,
        "battery.enabled": battery,
        "battery.capacity": 30,
        "battery.charge_steps": 4,
        "team.communication": communication,
        "team.avoid_collisions": avoid,
        "steps": 300,
    }
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("agents", [3, 6])
def test_compiled_battery_on_dead_end_stations(tmp_path, seed, agents):
    """Station pockets, queues, homing yields and pushes: random tree-like mazes."""
    path = tmp_path / "maze.txt"
    path.write_text(mazes.random_maze(5, 6, seed, loops=0.1 * seed, stations=2))
    flat = {
        **BASE,
        "map": str(path),
        "agents": agents,
        "battery.capacity": 90,
        "battery.charge_steps": 3 * (seed - 1),
        "battery.initial_charge": "full" if seed == 1 else "staggered",
        "steps": 900,
        "max_episode_steps": 300,
    }
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize(
    "extra",
    [
        {"learning.epsilon": 0.3, "learning.state_space": "cell", "record.warmup": 20},
        {"episodes": 2, "max_episode_steps": None, "steps": 900, "agents": 3},
        {"learning.gamma": 0.9, "learning.multiplier": 100.0, "reward.lambda": 0.5},
    ],
)
def test_compiled_qlearning_settings(tmp_path, extra):
    flat = {**BASE, "map": "map_b", "agents": 2, "battery.enabled": False, **extra}
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize("policy", NAMES)
@pytest.mark.parametrize("battery", [True, False])
def test_every_strategy_and_battery(rooms_map, tmp_path, policy, battery):
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": 2,
        "policy": policy,
        "battery.enabled": battery,
        "battery.capacity": 40,
        "battery.charge_steps": 5,
        "steps": 120,
    }
    engine, note = both(flat, tmp_path)
    if policy == "qlearning":
        assert (engine, note) == ("numba", "")
    else:
        assert engine == "numpy" and note.startswith("fallback from numba")


@pytest.mark.parametrize(
    "record",
    [
        {"record.watch": [3, 4, 17]},
        {"record.transitions": True, "learning.state_space": "cell"},
        {"record.transitions": True, "record.watch": [5], "agents": 4},
    ],
)
@pytest.mark.parametrize("battery", [True, False])
def test_recorders(rooms_map, tmp_path, record, battery):
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": 2,
        "battery.enabled": battery,
        "battery.capacity": 30,
        "steps": 300,
        **record,
    }
    assert both(flat, tmp_path) == ("numba", "")


def test_engine_choice(monkeypatch):
    cfg = from_flat({"battery.enabled": False, "engine": "numpy", "runs": 16})
    assert engines.choose(cfg) == ("numpy", "")
    assert engines.choose(cfg.replace(engine="auto")) == ("numba", "")
    small = cfg.replace(engine="auto", runs=1, steps=1000)
    assert engines.choose(small)[0] == "numpy" and "small batch" in engines.choose(small)[1]
    assert engines.choose(small.replace(engine="numba")) == ("numba", "")
    monkeypatch.setattr(engines, "numba_installed", lambda: False)
    assert engines.choose(cfg.replace(engine="auto")) == ("numpy", "numba not installed")
    with pytest.raises(ConfigError, match="engine: numba is not installed"):
        engines.choose(cfg.replace(engine="numba"))


def test_engine_is_not_part_of_the_experiment():
    a = from_flat({"engine": "numpy"})
    b = from_flat({"engine": "numba"})
    assert a.digest() == b.digest() and a.to_yaml() == b.to_yaml()
    assert "engine" not in a.to_yaml()


@pytest.mark.parametrize("agents", [1, 4])
@pytest.mark.parametrize("battery", [True, False])
@pytest.mark.parametrize("window", [7, 50])
def test_compiled_timeline(rooms_map, tmp_path, agents, battery, window):
    """``record.timeline`` (idleness in windows), including a short last window (7 does
    not divide 300) and runs that stop early on an episode quota."""
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": agents,
        "battery.enabled": battery,
        "battery.capacity": 30,
        "battery.charge_steps": 4,
        "steps": 300,
        "record.timeline": window,
    }
    assert both(flat, tmp_path) == ("numba", "")
    assert (tmp_path / "numba" / "timeline.csv").is_file()
    assert both({**flat, "episodes": 2}, tmp_path) == ("numba", "")


@pytest.mark.parametrize("battery", [True, False])
@pytest.mark.parametrize("timeline", [0, 50])
def test_compiled_groups_of_runs(rooms_map, tmp_path, monkeypatch, battery, timeline):
    """Large batches go through the compiled loop a group of runs at a time (uniforms
    drawn per group, output rows renumbered): shrunk limits force groups of 2 runs out
    of 5 (the last group of 1) and blocks of 64 steps, with a short last block and runs
    stopped early by an episode quota; every file equals the numpy engine's."""
    from qpatrol import run

    monkeypatch.setattr(run, "COMPILED_BLOCK", 256)
    monkeypatch.setattr(run, "COMPILED_GROUP_STEPS", 64)
    calls = []
    draw = run.Streams.draw
    monkeypatch.setattr(
        run.Streams,
        "draw",
        lambda s, n, lo, hi, out: calls.append((lo, hi)) or draw(s, n, lo, hi, out),
    )
    flat = {
        **BASE,
        "map": str(rooms_map),
        "runs": 5,
        "agents": 2,
        "steps": 300,
        "episodes": 3,
        "max_episode_steps": 40,
        "battery.enabled": battery,
        "battery.capacity": 30,
        "record.timeline": timeline,
    }
    assert both(flat, tmp_path) == ("numba", "")
    assert calls[:3] == [(0, 2), (2, 4), (4, 5)]
