"""Idleness over time (qpatrol.measures.timeline): by hand on a ring, and by brute force.

A window w of length n covers team steps ``w n + 1 .. (w + 1) n``; its average
idleness is the mean over those steps t and all cells c of ``t - last visit of c``
(0 if never), its worst idleness the max of the same. The brute force recomputes both
from every robot's cell after every step, with plain loops.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_measures import RING12, positions, random_team, write

from qpatrol.config import from_flat
from qpatrol.measures.timeline import TIMELINE_COLUMNS, Timeline
from qpatrol.run import simulate


def brute_windows(pos: np.ndarray, n_cells: int, window: int) -> list[tuple]:
    """(window, first, last, avg, worst) of one run from its positions ``[T + 1, K]``."""
    steps = pos.shape[0] - 1
    last = [0] * n_cells
    rows, idle, worst, first = [], 0, 0, 1
    for t in range(1, steps + 1):
        for a in range(pos.shape[1]):
            if pos[t, a] != pos[t - 1, a]:
                last[int(pos[t, a])] = t
        values = [t - last[c] for c in range(n_cells)]
        idle += sum(values)
        worst = max(worst, max(values))
        if t % window == 0 or t == steps:
            n = t - first + 1
            rows.append(((t - 1) // window, first, t, idle / (n_cells * n), worst))
            idle, worst, first = 0, 0, t + 1
    return rows


def compare(result, window: int) -> None:
    df = result.timeline
    assert list(df.columns) == TIMELINE_COLUMNS
    for run_id, pos in positions(result).items():
        want = brute_windows(pos, result.map.n_cells, window)
        got = df[df.run == run_id]
        assert len(got) == len(want), run_id
        for row, w in zip(got.itertuples(index=False), want, strict=True):
            assert (row.window, row.first_step, row.last_step) == w[:3]
            assert row.avg_idleness == w[3], (run_id, row.window, "avg_idleness")
            assert row.worst_idleness == w[4], (run_id, row.window, "worst_idleness")


@pytest.mark.parametrize("window", [37, 100])
def test_timeline_equals_a_brute_force_recount(tmp_path, window):
    """4 random robots with batteries; 37 does not divide the 400 steps (a short last
    window), 100 does."""
    result = random_team(tmp_path, **{"record.timeline": window})
    compare(result, window)


def test_timeline_of_runs_that_stop_unevenly(tmp_path):
    result = random_team(tmp_path, episodes=3, steps=3000, **{"record.timeline": 50})
    assert len(set(result.state.steps_done.tolist())) > 1
    compare(result, 50)


def test_a_cyclic_robot_on_a_ring_by_hand(tmp_path):
    """One robot circling the 12-ring: once every cell has been entered, after every step
    the idleness values are 0, 1, ..., 11, so each 12-step window has average 5.5 and
    worst 11. In the first window, after step t the t cells entered have idleness
    0..t-1 and the 12 - t others t (counted from step 0): the sum over t = 1..12 of
    t(t-1)/2 + (12-t)t is 286 + 286 = 572, so the average is 572/144; worst 11 at t = 11
    (the start cell, entered last, at step 12) and 12 - 1 = 11."""
    cfg = from_flat(
        {
            "map": write(tmp_path, RING12),
            "agents": 1,
            "policy": "cyclic",
            "battery.enabled": False,
            "steps": 120,
            "record.timeline": 12,
        }
    )
    df = simulate(cfg).timeline
    assert len(df) == 10
    late = df[df.window >= 2]
    assert (late.avg_idleness == 5.5).all() and (late.worst_idleness == 11).all()
    assert df.avg_idleness.iloc[0] == 572 / 144
    assert df.worst_idleness.iloc[0] == 11


def test_timeline_off_writes_nothing(tmp_path):
    cfg = from_flat({"map": write(tmp_path, RING12), "battery.enabled": False, "steps": 20})
    assert simulate(cfg).timeline is None
    assert Timeline(3, 12, 0).table(np.arange(3), np.full(3, 20)) is None


def test_a_timeline_without_open_gaps_is_caught(tmp_path, monkeypatch):
    """The guard works: forgetting the gaps still open at a window's end fails the recount."""
    monkeypatch.setattr(Timeline, "_close", broken_close)
    result = random_team(tmp_path, **{"record.timeline": 20})
    with pytest.raises(AssertionError, match="worst_idleness"):
        compare(result, 20)


def broken_close(self: Timeline, rows: np.ndarray, t: int) -> None:
    for r in rows.tolist():
        n = int(self.steps[r])
        avg = float(self.idle_sum[r] / (self.n_cells * n))
        self.rows.append((r, (t - 1) // self.window, t - n + 1, t, avg, int(self.worst[r])))
    self.idle_sum[rows] = 0
    self.worst[rows] = 0
    self.steps[rows] = 0
