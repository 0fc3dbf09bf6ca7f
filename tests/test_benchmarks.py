"""The numpy floor benchmark (benchmarks/numpy_floor.py) runs, and its variants compare
like with like: its two table layouts take the same walks."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

PATH = Path(__file__).parents[1] / "benchmarks" / "numpy_floor.py"


@pytest.fixture(scope="module")
def floor():
    spec = importlib.util.spec_from_file_location("numpy_floor", PATH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_floor_step_explores_the_map_like_the_engine(floor):
    """Its timing means something only if its robots spread over the map as the
    engine's do (its tables' cache misses come from there): the mean number of cells
    visited per run after 600 steps agrees within 10 % (77 against 75 at 400 steps,
    183 against 183 at 2,000 when measured, out of map_a's 185)."""
    us, cells = floor.floor_step_us(64, 600, shared=False)
    engine_us, engine_cells = floor.engine_step_us(64, 600)
    assert us > 0 and engine_us > 0
    assert 50 < engine_cells < 185
    assert abs(cells - engine_cells) < 0.1 * engine_cells, (cells, engine_cells)


def test_the_floor_layouts_take_the_same_walks(floor):
    assert (
        floor.floor_step_us(8, 300, shared=False)[1]
        == floor.floor_step_us(8, 300, shared=False, one_line=True)[1]
    )
    assert floor.floor_step_us(8, 50, shared=True)[1] > 1


def test_train_speed_times_both_paths_on_the_same_config():
    """benchmarks/train_speed.py runs the Python API and `qpatrol train` on one config,
    each writing a run folder, and gives their seconds."""
    spec = importlib.util.spec_from_file_location("train_speed", PATH.parent / "train_speed.py")
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
    assert run.COMPILED_CALL_SECONDS == 1.0 and run.COMPILED_GROUP_STEPS == 4096  # restored
