"""SimPatrol's recount of the interval measures (qpatrol/measures/field.py), by hand."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qpatrol.measures.field import (
    simpatrol_intervals,
    simpatrol_measures,
    trajectory_visits,
    visit_times,
)

# a 3-vertex line 0 - 1 - 2, one robot entering 1, 2, 1, 0, 1, 2, 1, 0 at steps 1..8
LINE = np.array([[1], [2], [1], [0], [1], [2], [1], [0]])


def test_visit_times_of_the_line() -> None:
    v = visit_times(LINE, 3)
    assert [t.tolist() for t in v] == [[4, 8], [1, 3, 5, 7], [2, 6]]


def test_intervals_of_the_line_by_hand() -> None:
    v = visit_times(LINE, 3)
    # from the window's start (1) to the first visit, between visits, and to end + 1
    assert simpatrol_intervals(v[0], 1, 8) == [3, 4, 1]
    assert simpatrol_intervals(v[1], 1, 8) == [0, 2, 2, 2, 2]
    assert simpatrol_intervals(v[2], 1, 8) == [1, 4, 3]
    # a window that drops the early visits: [4, 8]
    assert simpatrol_intervals(v[1], 4, 8) == [1, 2, 2]
    # never visited in the window: one interval, the window's length
    assert simpatrol_intervals([], 3, 7) == [5]


def test_measures_of_the_line_by_hand() -> None:
    m = simpatrol_measures(visit_times(LINE, 3), 1, 8)
    # intervals 3 4 1 | 0 2 2 2 2 | 1 4 3: 11 of them, sum 24, sum of squares 68
    assert m["intervals"] == 11
    assert m["qmi"] == math.sqrt(68 / 11)
    assert m["mean_interval"] == 24 / 11
    assert m["max_interval"] == 4
    assert m["std_interval"] == math.sqrt(11 * 68 - 24 * 24) / 11
    # sum of (i*i - i) / 2 per vertex: 9, 4, 9, over 8 window steps, mean over 3
    assert m["avg_idleness"] == (9 / 8 + 4 / 8 + 9 / 8) / 3


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(0, 30), max_size=12), st.integers(0, 10), st.integers(0, 20))
def test_intervals_cover_the_window(times: list[int], start: int, extra: int) -> None:
    # the intervals of a vertex always add up to the window's length
    end = start + extra
    iv = simpatrol_intervals(times, start, end)
    assert sum(iv) == end - start + 1
    assert len(iv) == sum(start <= t <= end for t in times) + 1
    assert all(i >= 0 for i in iv)


def test_example_quick_table() -> None:
    # examples/simplepatrol_map_a.py in its quick mode: one row per strategy and team
    import importlib.util
    from pathlib import Path

    path = Path(__file__).parent.parent / "examples" / "simplepatrol_map_a.py"
    spec = importlib.util.spec_from_file_location("simplepatrol_map_a", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    rows = mod.main(["--quick", "--engine", "numpy"])
    assert len(rows) == len(mod.STRATEGIES) * len(mod.TEAMS)
    assert [(r["strategy"], r["robots"]) for r in rows] == [
        (s, k) for s in mod.STRATEGIES for k in mod.TEAMS
    ]
    for r in rows:
        assert r["qmi"] > 0 and r["field_qmi"] > 0
        # the field's maximum interval is at least the shortest possible, 1
        assert r["field_max_interval"] >= 1


@pytest.mark.parametrize("policy", ["conscientious", "shared-conscientious"])
def test_trajectory_visits_are_qpatrol_visits(policy: str) -> None:
    # qpatrol's own QMI, recounted from the visits read off the trajectory, to the bit:
    # the recount sees the same visits the loop counted (simultaneous entries included)
    from qpatrol.config import load_config
    from qpatrol.run import simulate

    steps, warmup = 400, 150
    cfg = load_config(
        "field",
        [
            "map=ps_example",
            "agents=5",
            f"policy={policy}",
            "team.avoid_collisions=off",
            f"steps={steps}",
            f"record.warmup={warmup}",
            "runs=2",
            f"record.trajectory={steps}",
            "engine=numpy",
        ],
    )
    res = simulate(cfg)
    for (_, run), s in zip(res.trajectory.groupby("run"), res.summary, strict=True):
        cells = run["cell"].to_numpy().reshape(-1, 5)  # steps 1..steps
        cells = np.vstack([res.map.starts[:5][None, :], cells])  # step 0: the starts
        times = trajectory_visits(cells, res.map.target, 1)
        iv = [b - a for t in times for a, b in zip(t[:-1], t[1:], strict=True) if b > warmup]
        assert math.sqrt(sum(i * i for i in iv) / len(iv)) == s["qmi"]


def test_trajectory_visits_by_hand() -> None:
    # cells 0 1 2 3, cell 2 a waypoint (no target); robot 0 stays, then moves; robot 1
    # enters cell 1 at step 2 with robot 0 (two visits) and passes the waypoint
    target = np.array([True, True, False, True])
    cells = np.array([[0, 3], [0, 2], [1, 1], [1, 2], [0, 3]])  # steps 0..4
    v = trajectory_visits(cells, target, 1)
    # targets: cell 0 -> 0, cell 1 -> 1, cell 3 -> 2
    assert [t.tolist() for t in v] == [[4], [2, 2], [4]]
