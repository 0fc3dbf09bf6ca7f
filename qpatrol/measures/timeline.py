"""Idleness over time: average and worst idleness in consecutive windows of a run.

A recorder that watches from outside the world, like :mod:`qpatrol.measures`, but
instead of one number per run it keeps one row per window of ``record.timeline`` team
steps, from step 1 on (no warm-up), so that learning shows as a curve:

* ``avg_idleness`` of a window: mean over its steps t and over target cells c of
  ``t - last visit of c`` (every cell counts as visited at step 0);
* ``worst_idleness``: the largest idleness any target reached at a step of the window.

Targets as in :mod:`qpatrol.measures`: every cell of a grid, a graph's vertices.

The work per step does not grow with the map. The idleness sum is kept from the sum of
last visits (``sum_c idle = C t - sum_c last``). A cell visited at t after l peaked at
``t - 1 - l`` in step t - 1, which is counted when t - 1 lies in the window; the gaps
still open at a window's end are taken once per window (O(C) every ``window`` steps).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from qpatrol.measures import entries
from qpatrol.world import Outcome

TIMELINE_COLUMNS = ["run", "window", "first_step", "last_step", "avg_idleness", "worst_idleness"]


class Timeline:
    """Windowed idleness of a batch of runs; call :meth:`observe` after every step.

    Args:
        n_runs, n_cells: the batch's runs R and the map's cells C.
        window: steps per window (0: off, nothing is kept).
        target: bool ``[C]``, the cells that count (None: every cell), as in
            :class:`qpatrol.measures.Measures`.

    Attributes:
        last: int ``[R, C]``, last visit of each cell by any robot (0 = never).
        last_sum: int ``[R]``, sum of ``last`` over cells.
        idle_sum: int ``[R]``, summed idleness of the current window so far.
        worst: int ``[R]``, worst idleness of the current window so far.
        steps: int ``[R]``, steps of the current window taken.
        rows: finished windows, ``(run row, window, first, last, avg, worst)``.
    """

    def __init__(self, n_runs: int, n_cells: int, window: int, target: np.ndarray | None = None):
        self.window = window
        self.n_cells = n_cells
        mask = np.ones(n_cells, dtype=bool) if target is None else np.asarray(target, dtype=bool)
        self._target = (mask,)  # a tuple: not a per-run array (batches join and slice those)
        self.n_targets = int(mask.sum())
        if not window:
            return
        self.last = np.zeros((n_runs, n_cells), dtype=np.int64)
        self.last_sum = np.zeros(n_runs, dtype=np.int64)
        self.idle_sum = np.zeros(n_runs, dtype=np.int64)
        self.worst = np.zeros(n_runs, dtype=np.int64)
        self.steps = np.zeros(n_runs, dtype=np.int64)
        self.rows: list[tuple[int, int, int, int, float, int]] = []

    @property
    def target(self) -> np.ndarray:
        """bool ``[C]``: the cells that count."""
        return self._target[0]

    def observe(self, out: Outcome) -> None:
        """Take in one step of the runs still active."""
        if not self.window:
            return
        t = out.t
        start = ((t - 1) // self.window) * self.window + 1  # first step of t's window
        for _, rows, _, prev in entries(out, self.last, self.last_sum, self.target):
            if t - 1 >= start:
                self.worst[rows] = np.maximum(self.worst[rows], t - 1 - prev)
        act = out.active
        self.idle_sum[act] += self.n_targets * t - self.last_sum[act]
        self.steps[act] += 1
        if t % self.window == 0:
            self._close(np.flatnonzero(act), t)

    def _close(self, rows: np.ndarray, t: int) -> None:
        """End the window at step t for ``rows``: open gaps, then one row each."""
        if rows.size == 0:
            return
        open_gap = t - self.last[rows][:, self.target].min(axis=1)
        worst = np.maximum(self.worst[rows], open_gap)
        for i, r in enumerate(rows.tolist()):
            self.rows.append(self._row(r, t, int(self.steps[r]), self.idle_sum[r], worst[i]))
        self.idle_sum[rows] = 0
        self.worst[rows] = 0
        self.steps[rows] = 0

    def _row(self, r: int, t: int, n: int, idle: np.int64, worst: int) -> tuple:
        """A finished window of run row ``r``: ``n`` steps ending at ``t``, summed
        idleness ``idle`` (int64), worst idleness ``worst``."""
        avg = float(np.int64(idle) / (self.n_targets * n))
        return (r, (t - 1) // self.window, t - n + 1, t, avg, int(worst))

    def add_rows(self, rows: np.ndarray) -> None:
        """Windows closed by the compiled engine: int ``[W, 6]`` (run row, window, first,
        last, idleness sum, worst), turned into rows as :meth:`_close` makes them."""
        for r, _, first, last, idle, worst in rows.tolist():
            self.rows.append(self._row(r, last, last - first + 1, idle, worst))

    def table(self, run_ids: np.ndarray, steps_done: np.ndarray) -> pd.DataFrame | None:
        """``timeline.csv``: one row per run and window (a last, shorter window included).

        Columns: run, window (0, 1, ...), first_step, last_step, avg_idleness,
        worst_idleness. None when off.
        """
        if not self.window:
            return None
        rows = list(self.rows)
        for r in np.flatnonzero(self.steps > 0).tolist():  # a window cut short by the end
            t = int(steps_done[r])
            worst = max(int(self.worst[r]), int(t - self.last[r, self.target].min()))
            rows.append(self._row(r, t, int(self.steps[r]), self.idle_sum[r], worst))
        df = pd.DataFrame(rows, columns=["row", *TIMELINE_COLUMNS[1:]])
        df.insert(0, "run", np.asarray(run_ids)[df["row"].to_numpy(dtype=np.int64)])
        df = df.drop(columns="row").sort_values(["run", "window"], kind="stable")
        return df.reset_index(drop=True)
