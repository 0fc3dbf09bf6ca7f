"""SimPatrol's recount of the interval measures (qpatrol/measures/field.py), by hand."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from qpatrol.measures.field import simpatrol_intervals, simpatrol_measures, visit_times

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
