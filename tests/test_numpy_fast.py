"""The numpy engine's fast steps write the general step's files to the bit.

Every config runs twice on the numpy engine, with the fast steps
(:mod:`qpatrol.engines.numpy_solo`, :mod:`qpatrol.engines.numpy_team`) and without
(:data:`qpatrol.engines.numpy_loop.FAST` off: :func:`qpatrol.run.advance` on every
step), and every file of the run folder is compared byte for byte. The configs are
chosen so that the fast steps run (checked) and also hand steps to the general step
(episode quotas, robots that cannot move, collisions).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from qpatrol.config import from_flat
from qpatrol.engines import numpy_loop
from qpatrol.run import simulate, write_run

META = {"started": "-", "ended": "-"}


def both_ways(flat: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[str, int]:
    """Run ``flat`` with and without the fast steps and compare every file; ``(kind,
    steps)``: the fast step's class and how many team steps it took (of all runs)."""
    cfg = from_flat({"engine": "numpy", **flat})
    made = []
    real = numpy_loop.fast_step

    def spy(*args):
        made.append(real(*args))
        return made[-1]

    monkeypatch.setattr(numpy_loop, "fast_step", spy)
    folders = {}
    for fast in (True, False):
        monkeypatch.setattr(numpy_loop, "FAST", fast)
        folders[fast] = write_run(simulate(cfg), tmp_path / str(fast), replace=True, meta=META)
    a, b = folders[True], folders[False]
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), (flat, name)
    assert made[-1] is None  # the second run had no fast step
    return type(made[0]).__name__, made[0].taken


BASE = {"runs": 3, "seed": 5, "steps": 300, "max_episode_steps": 60, "battery.enabled": False}


@pytest.mark.parametrize(
    "extra",
    [
        {},
        {"record.trajectory": 7, "record.warmup": 40},
        {"learning.epsilon": 0.3, "learning.state_space": "cell"},
        {"team.avoid_collisions": False, "episodes": 3, "max_episode_steps": None},
        {"learning.gamma": 0.9, "learning.multiplier": 100.0, "reward.lambda": 0.5},
    ],
)
def test_solo(rooms_map, tmp_path, monkeypatch, extra):
    flat = {**BASE, "map": str(rooms_map), "agents": 1, **extra}
    kind, taken = both_ways(flat, tmp_path, monkeypatch)
    assert kind == "Solo" and taken > 100


@pytest.mark.parametrize("agents", [1, 2, 4, 8])
@pytest.mark.parametrize("communication", [True, False])
@pytest.mark.parametrize("avoid", [True, False])
def test_team(rooms_map, tmp_path, monkeypatch, agents, communication, avoid):
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": agents,
        "team.communication": communication,
        "team.avoid_collisions": avoid,
        "record.trajectory": 5,
    }
    kind, taken = both_ways(flat, tmp_path, monkeypatch)
    print(kind, taken)
    assert kind == ("Solo" if agents == 1 else "Team") and taken > 100
