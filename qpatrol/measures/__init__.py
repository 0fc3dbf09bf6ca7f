"""Patrolling measures, watched from outside the world, one dict per run.

The standard measures of the multi-agent patrolling literature (Machado et al. 2002;
Chevaleyre 2004), all over the same *window*: the team steps ``t > record.warmup``.

* idleness of cell c after team step t: ``t - last visit of c by any robot`` (every
  cell counts as visited at step 0);
* ``avg_idleness``: mean over cells and window steps; ``worst_idleness``: the max;
* ``mean_interval`` / ``max_interval``: between two successive visits of a cell, for
  visits made in the window (the first visit of a cell has no interval);
* ``coverage``: share of cells visited in the window;
* ``division_of_labour``: for each cell visited in the window, the share of its window
  visits made by its most frequent visitor, averaged over those cells (1/K: none, 1: a
  full partition);
* ``max_wait``: the longest stretch of consecutive team steps, reached in the window,
  in which a robot could not make the move its strategy or its battery asked for
  (waiting for a station included);
* ``mean_steps_per_episode``: over complete episodes that started in the window.

The work per step does not grow with the map: the sum of last-visit times is kept as
visits happen (``sum_c idle = C t - sum_c last``), and the worst idleness is the
largest visit gap (a cell visited at t after l peaked at ``t - 1 - l``, in the step
before), plus the gaps still open at the end.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from qpatrol.world import Outcome, Params


def entries(out: Outcome, last: np.ndarray, last_sum: np.ndarray):
    """The visits of one step, robot by robot: ``(k, rows, cells, prev)`` for each robot
    ``k`` that entered a cell in some runs (``rows`` int ``[B]``, the cells entered
    ``cells`` int ``[B]``, ``prev`` int ``[B]`` their previous visit, 0 for none), after
    recording the visit: ``last`` int ``[R, C]`` (the step of each cell's last visit) set
    to ``out.t`` and ``last_sum`` int ``[R]`` (the sum of ``last`` over cells) kept equal
    to it. The one place the measures and the timeline (:mod:`qpatrol.measures.timeline`)
    learn of a visit."""
    t = out.t
    for k in range(out.moved.shape[1]):
        rows = np.flatnonzero(out.moved[:, k])
        if rows.size == 0:
            continue
        c = out.pos[rows, k]
        prev = last[rows, c]
        last[rows, c] = t
        last_sum[rows] += t - prev
        yield k, rows, c, prev


class Measures:
    """Accumulators over a batch of runs; call :meth:`observe` after every step.

    Attributes:
        last: int ``[R, C]``, last visit of each cell by any robot (0 = never).
        last_sum: int ``[R]``, sum of ``last`` over cells.
        visits: int ``[R, K, C]``, cells entered by each robot (the whole run).
        window_visits: int ``[R, K, C]``, the same, in the window only.
        idle_total: int ``[R]``, sum over window steps of the summed idleness of cells.
        worst: int ``[R]``, worst idleness of a closed gap in the window.
        measured: int ``[R]``, window steps taken.
        gap_sum, gap_count, gap_max: int ``[R]``, visit intervals ending in the window.
        max_wait: int ``[R]``, longest wait reached in the window.
        wait_total: int ``[R]``, robot-steps spent waiting in the window.
        min_charge: int ``[R]``, lowest battery charge seen.
    """

    def __init__(self, n_runs: int, n_agents: int, n_cells: int, warmup: int):
        r, k, c = n_runs, n_agents, n_cells
        self.warmup = warmup
        self.n_cells = c
        self.last = np.zeros((r, c), dtype=np.int64)
        self.last_sum = np.zeros(r, dtype=np.int64)
        self.visits = np.zeros((r, k, c), dtype=np.int64)
        self.window_visits = np.zeros((r, k, c), dtype=np.int64)
        self.idle_total = np.zeros(r, dtype=np.int64)
        self.worst = np.zeros(r, dtype=np.int64)
        self.measured = np.zeros(r, dtype=np.int64)
        self.gap_sum = np.zeros(r, dtype=np.int64)
        self.gap_count = np.zeros(r, dtype=np.int64)
        self.gap_max = np.zeros(r, dtype=np.int64)
        self.max_wait = np.zeros(r, dtype=np.int64)
        self.wait_total = np.zeros(r, dtype=np.int64)
        self.min_charge = np.full(r, np.iinfo(np.int64).max, dtype=np.int64)

    def observe(self, out: Outcome, wait: np.ndarray, charge: np.ndarray | None) -> None:
        """Take in one step: visits, intervals, idleness, waits and charge.

        Args:
            out: the step's outcome.
            wait: int ``[R, K]``, the robots' current waits after the step.
            charge: int ``[R, K]``, the charge after the step (None: battery off).
        """
        t = out.t
        in_window = t > self.warmup
        for k, rows, c, prev in entries(out, self.last, self.last_sum):
            self.visits[rows, k, c] += 1
            if in_window:
                self.window_visits[rows, k, c] += 1
                seen = prev > 0
                gap = np.where(seen, t - prev, 0)
                self.gap_sum[rows] += gap
                self.gap_count[rows] += seen
                self.gap_max[rows] = np.maximum(self.gap_max[rows], gap)
                if t - 1 > self.warmup:
                    self.worst[rows] = np.maximum(self.worst[rows], t - 1 - prev)
        act = out.active
        if charge is not None:
            self.min_charge[act] = np.minimum(self.min_charge[act], charge[act].min(axis=1))
        if in_window:
            self.idle_total[act] += self.n_cells * t - self.last_sum[act]
            self.measured[act] += 1
            self.max_wait[act] = np.maximum(self.max_wait[act], wait[act].max(axis=1))
            self.wait_total[act] += (wait[act] > 0).sum(axis=1)

    def worst_idleness(self, steps_done: np.ndarray) -> np.ndarray:
        """int ``[R]``: worst idleness in the window, open gaps at the end included."""
        open_gaps = steps_done - self.last.min(axis=1)
        return np.where(steps_done > self.warmup, np.maximum(self.worst, open_gaps), self.worst)


def division_of_labour(visits: np.ndarray) -> np.ndarray:
    """float ``[R]`` from visit counts int ``[R, K, C]`` (NaN for a run with no visit)."""
    total = visits.sum(axis=1)  # [R, C]
    share = np.full(total.shape, np.nan)
    np.divide(visits.max(axis=1), total, out=share, where=total > 0)
    visited = total > 0
    counts = visited.sum(axis=1)
    sums = np.where(visited, share, 0.0).sum(axis=1)
    return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


def wait_bound(p: Params) -> int:
    """The longest wait a live team may show: a fair station queue, then a crossing.

    With the battery on, a robot may queue behind every other robot of the team, each of
    which travels to a station (at most ``diameter`` moves), charges (``charge_steps``)
    and clears the station's pocket (``2 x depart_len``); then it crosses the map. So
    ``K x (charge_steps + 2 x max depart_len + diameter) + diameter``; without battery
    ``diameter`` (a robot blocked longer than a crossing is stuck). A yardstick, not a
    theorem: the trip home is not proven to take at most ``diameter`` steps, and on
    some maps no rule can bound a station wait (``docs/model.md``, "What is proven").
    """
    if not p.battery:
        return p.diameter
    turnaround = p.charge_steps + 2 * int(p.depart_len.max()) + p.diameter
    return p.n_agents * turnaround + p.diameter


def summarize(
    m: Measures,
    episodes: pd.DataFrame,
    run_ids: np.ndarray,
    steps_done: np.ndarray,
    bound: int,
) -> list[dict[str, Any]]:
    """Per-run measures as plain dicts (JSON-ready), in batch order."""
    dol = division_of_labour(m.window_visits)
    coverage = (m.window_visits.sum(axis=1) > 0).mean(axis=1)
    worst = m.worst_idleness(steps_done)
    ids = np.asarray(run_ids)
    n = ids.size
    # episodes per batch row, without a DataFrame filter per run (O(runs x episodes))
    order = np.argsort(ids, kind="stable")
    ep_run = episodes["run"].to_numpy()
    row = (
        order[np.searchsorted(ids, ep_run, sorter=order)]
        if ep_run.size
        else np.zeros(0, dtype=np.int64)
    )
    complete = episodes["complete"].to_numpy() == 1
    counted = complete & (episodes["start_step"].to_numpy() > m.warmup)
    n_complete = np.bincount(row[complete], minlength=n)
    n_truncated = np.bincount(row[~complete], minlength=n)
    n_done = np.bincount(row[counted], minlength=n)
    # exact: integer step counts summed as float64 are exact below 2**53, as in pandas
    done_steps = np.bincount(
        row[counted], weights=episodes["steps"].to_numpy()[counted].astype(np.float64), minlength=n
    )
    # the per-run numbers as Python lists (one conversion per measure, not per run);
    # each quotient is the float64 division it was when written per run
    with np.errstate(divide="ignore", invalid="ignore"):
        per_episode = (done_steps / n_done).tolist()
        avg = (m.idle_total / (m.n_cells * m.measured)).tolist()
        interval = (m.gap_sum / m.gap_count).tolist()
    measured = m.measured.tolist()
    gaps = m.gap_count.tolist()
    cols = [
        ids.tolist(),
        np.asarray(steps_done).tolist(),
        n_complete.tolist(),
        n_truncated.tolist(),
        n_done.tolist(),
        coverage.tolist(),
        worst.tolist(),
        m.gap_max.tolist(),
        dol.tolist(),
        m.wait_total.tolist(),
        m.max_wait.tolist(),
        m.min_charge.tolist(),
    ]
    never = int(np.iinfo(np.int64).max)
    out = []
    for i, (run, steps, done, cut, n_ep, cov, wst, gmax, lab, waits, mwait, charge) in enumerate(
        zip(*cols, strict=True)
    ):
        seen, n_gaps = measured[i], gaps[i]
        out.append(
            {
                "run": int(run),
                "steps": int(steps),
                "episodes_completed": done,
                "episodes_truncated": cut,
                "mean_steps_per_episode": per_episode[i] if n_ep else None,
                "coverage": cov if seen else None,
                "avg_idleness": avg[i] if seen else None,
                "worst_idleness": wst if seen else None,
                "mean_interval": interval[i] if n_gaps else None,
                "max_interval": gmax if n_gaps else None,
                "division_of_labour": None if lab != lab else lab,  # NaN: no visit
                "waits": waits,
                "max_wait": mwait,
                "wait_bound": int(bound),
                "live": bool(mwait <= bound),
                "min_charge": None if charge == never else charge,
            }
        )
    return out
