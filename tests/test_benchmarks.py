"""The benchmark scripts run: benchmarks/train_speed.py times the API and `qpatrol train`
on one config."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

PATH = Path(__file__).parents[1] / "benchmarks" / "train_speed.py"


def test_train_speed_times_both_paths_on_the_same_config():
    """benchmarks/train_speed.py runs the Python API and `qpatrol train` on one config,
    each writing a run folder, and gives their seconds."""
    spec = importlib.util.spec_from_file_location("train_speed", PATH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    small = ["map=map_b", "runs=2", "agents=1", "steps=60", "battery.enabled=off"]
    for path in ("api", "train"):
        assert module.one(path, "paper", small) > 0
    with pytest.raises(SystemExit):  # a bad config fails, it is not timed
        module.one("train", "paper", [*small, "agents=0"])
    pytest.importorskip("numba")
    from qpatrol import run

    times = module.loop_costs("paper", [*small, "engine=numba"], 1)
    assert set(times) == {"api", "one-call", "train"}
    assert all(len(t) == 1 and t[0] > 0 for t in times.values())
    assert run.COMPILED_CALL_SECONDS == 1.0 and run.COMPILED_RUN_STEPS == 4096  # restored
