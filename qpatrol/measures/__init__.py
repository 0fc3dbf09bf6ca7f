"""Patrolling measures, watched from outside the world, one dict per run.

The standard measures of the multi-agent patrolling literature (Machado et al. 2002;
Chevaleyre 2004), all over the same *window*: the team steps ``t > record.warmup``,
and over the *target* cells only (``Map.target``: every cell of a grid, the vertices of
a graph; entering a waypoint of a graph's edge is no visit).

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
* ``max_stall``: the longest stretch, reached in the window, in which a robot made no
  *progress* (its task did not end: ``State.since``, docs/model.md), against
  ``stall_bound`` (:func:`stall_bound`); ``live`` when it stays within the bound and
  every target is visited in the window;
* ``mean_steps_per_episode``: over complete episodes that started in the window;
* the patrolling field's measures (:data:`FIELD_MEASURES`, :func:`field_measures`):
  the intervals' quadratic mean and spread, the spread of the targets' visit
  frequencies, the worst, mean, median and spread of the targets' average intervals,
  complete patrol cycles and interferences (``docs/model.md``).

The work per step does not grow with the map: the sum of last-visit times is kept as
visits happen (``sum_c idle = T t - sum_c last`` over the T targets), the worst
idleness is the largest visit gap (a cell visited at t after l peaked at ``t - 1 - l``,
in the step before), plus the gaps still open at the end, and each visit adds its
interval to the run's and its target's sums and ticks the patrol cycle under way.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from qpatrol.util.arrays import at, flat
from qpatrol.world import GONE, Outcome, Params, State, interference


def entries(out: Outcome, last: np.ndarray, last_sum: np.ndarray, target: np.ndarray | None = None):
    """The visits of one step, robot by robot: ``(k, rows, cells, prev)`` for each robot
    ``k`` that entered a target cell in some runs (``rows`` int ``[B]``, the cells entered
    ``cells`` int ``[B]``, ``prev`` int ``[B]`` their previous visit, 0 for none), after
    recording the visit: ``last`` int ``[R, C]`` (the step of each cell's last visit) set
    to ``out.t`` and ``last_sum`` int ``[R]`` (the sum of ``last`` over cells) kept equal
    to it. ``target``: bool ``[C]``, the cells that count (None: every cell); a move into
    any other cell (a graph's waypoint) is no visit. The one place the measures and the
    timeline (:mod:`qpatrol.measures.timeline`) learn of a visit."""
    t = out.t
    for k in range(out.moved.shape[1]):
        entered = out.moved[:, k]
        if target is not None:
            entered = entered & target[out.pos[:, k]]
        rows = np.flatnonzero(entered)
        if rows.size == 0:
            continue
        c = flat(out.pos)[at(out.pos.shape, rows, k)]
        cell = at(last.shape, rows, c)  # int [B], the cells entered, flat in [R, C]
        prev = flat(last)[cell]
        flat(last)[cell] = t
        last_sum[rows] += t - prev
        yield k, rows, c, prev


class Measures:
    """Accumulators over a batch of runs; call :meth:`observe` after every step.

    Every measure counts the target cells only (``target``; a graph's waypoints are in
    transit): a move into another cell is no visit, but for ``visits``.

    Attributes:
        target: bool ``[C]``, the cells that count; n_targets: their number.
        last: int ``[R, C]``, last visit of each target by any robot (0 = never).
        last_sum: int ``[R]``, sum of ``last`` over targets.
        visits: int ``[R, K, C]``, cells entered by each robot (the whole run, every cell).
        window_visits: int ``[R, K, C]``, targets entered, in the window only.
        idle_total: int ``[R]``, sum over window steps of the summed idleness of targets.
        worst: int ``[R]``, worst idleness of a closed gap in the window.
        measured: int ``[R]``, window steps taken.
        gap_sum, gap_count, gap_max: int ``[R]``, visit intervals ending in the window.
        gap_sq: int ``[R]``, the sum of their squares.
        target_gap_sum, target_gap_count: int ``[R, C]``, the same intervals, by target.
        cycle_start: int ``[R]``, first step of the patrol cycle under way.
        cycle_seen: int ``[R]``, targets visited in it so far.
        cycles: int ``[R]``, patrol cycles completed in the window.
        interferences: int ``[R]``, robot-steps in the window in which a robot asked for
            a move and did not make it.
        max_wait: int ``[R]``, longest wait reached in the window.
        max_stall: int ``[R]``, longest stretch without progress reached in the window.
        wait_total: int ``[R]``, robot-steps spent waiting in the window.
        min_charge: int ``[R]``, lowest battery charge seen.
        attack: int ``[A]``, the attack durations D of the intruder measures
            (``security.attack_steps``; none: the measures are off and the arrays
            below are empty); horizon: the steps a run is configured to take.
        empty_since: int ``[R, C]``, for each target the step at whose end it became
            empty (a departure; 0: empty since the start), or, while robots stand on
            it, minus their number.
        random_missed: int ``[R, A]``, intruder pairs (target, step) that no robot
            caught within D steps, over the closed empty stretches that began before
            the window.
        stretch_count, stretch_sum: int ``[R, A + 1]``, the closed empty stretches that
            began in the window, and the sum of their lengths (their gaps), by the
            bucket of their gap (as ``gaps``); stretch_equal: int ``[R, A]``, those whose
            gap equals the i-th D. A stretch of gap g hides max(0, g + 1 - D) random
            intruders, so these give each D's (:func:`intruder_measures`).
        gaps: int32 ``[R, C, A + 1]``, each target's departures that the observer counts
            for every D (made at least the longest D before the horizon), by the bucket
            of their gap until the next arrival: bucket j holds the gaps longer than the
            j shortest durations and no longer than the next (a departure is missed for
            the i-th D when its bucket is above i).
        tail_departures, tail_missed: int32 ``[R, C, A]``, the departures made within
            the longest D of the horizon, each counted for the durations it is early
            enough for, and those of them missed.
    """

    def __init__(
        self,
        n_runs: int,
        n_agents: int,
        n_cells: int,
        warmup: int,
        target: np.ndarray | None = None,
        attack_steps: tuple[int, ...] | list[int] = (),
        horizon: int = 0,
        start: np.ndarray | None = None,
    ):
        r, k, c = n_runs, n_agents, n_cells
        self.warmup = warmup
        self.n_cells = c
        mask = np.ones(c, dtype=bool) if target is None else np.asarray(target, dtype=bool)
        # in a tuple: not an array attribute, which batches would join or slice as per-run
        self._target = (mask,)
        self.n_targets = int(mask.sum())
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
        self.gap_sq = np.zeros(r, dtype=np.int64)
        self.target_gap_sum = np.zeros((r, c), dtype=np.int64)
        self.target_gap_count = np.zeros((r, c), dtype=np.int64)
        self.cycle_start = np.full(r, warmup + 1, dtype=np.int64)
        self.cycle_seen = np.zeros(r, dtype=np.int64)
        self.cycles = np.zeros(r, dtype=np.int64)
        self.interferences = np.zeros(r, dtype=np.int64)
        self.max_wait = np.zeros(r, dtype=np.int64)
        self.max_stall = np.zeros(r, dtype=np.int64)
        self.wait_total = np.zeros(r, dtype=np.int64)
        self.min_charge = np.full(r, np.iinfo(np.int64).max, dtype=np.int64)
        # the intruder measures (docs/model.md, "Intruders"): who stands where, when
        # each target became empty, and the intruders missed so far, per duration D
        self._attack = (np.asarray(sorted(set(attack_steps)), dtype=np.int64),)
        self.horizon = int(horizon)
        a = self.attack.size
        cc = c if a else 0
        self.empty_since = np.zeros((r, cc), dtype=np.int64)
        self.random_missed = np.zeros((r, a), dtype=np.int64)
        self.stretch_count = np.zeros((r, a + 1 if a else 0), dtype=np.int64)
        self.stretch_sum = np.zeros((r, a + 1 if a else 0), dtype=np.int64)
        self.stretch_equal = np.zeros((r, a), dtype=np.int64)
        self.gaps = np.zeros((r, cc, a + 1 if a else 0), dtype=np.int32)
        self.tail_departures = np.zeros((r, cc, a), dtype=np.int32)
        self.tail_missed = np.zeros((r, cc, a), dtype=np.int32)
        if a:
            if start is None:
                raise ValueError("Measures: the intruder measures need the robots' start cells")
            rows = np.repeat(np.arange(r), np.asarray(start).shape[1])
            np.add.at(self.empty_since, (rows, np.asarray(start).ravel()), -1)

    @property
    def attack(self) -> np.ndarray:
        """int ``[A]``: the attack durations D, ascending (empty: intruder measures off)."""
        return self._attack[0]

    @property
    def target(self) -> np.ndarray:
        """bool ``[C]``: the cells every measure counts."""
        return self._target[0]

    def observe(
        self,
        out: Outcome,
        wait: np.ndarray,
        charge: np.ndarray | None,
        failing: np.ndarray | None = None,
        stall: np.ndarray | None = None,
    ) -> None:
        """Take in one step: visits, intervals, idleness, cycles, waits and charge.

        Args:
            out: the step's outcome.
            wait: int ``[R, K]``, the robots' current waits after the step.
            charge: int ``[R, K]``, the charge after the step (None: battery off).
            failing: bool ``[R, K]``, the robots that left the map at the end of the step
                (:mod:`qpatrol.world.failures`; None: none).
            stall: int ``[R, K]``, each robot's steps without progress after the step
                (``t - since``; 0 for a failed robot); None: not measured.
        """
        t = out.t
        in_window = t > self.warmup
        rows, ks = np.nonzero(out.moved)  # every robot that entered a cell, once
        cells = flat(out.pos)[at(out.pos.shape, rows, ks)]
        flat(self.visits)[at(self.visits.shape, rows, ks, cells)] += 1
        for k, rows, c, prev in entries(out, self.last, self.last_sum, self.target):
            if in_window:
                flat(self.window_visits)[at(self.window_visits.shape, rows, k, c)] += 1
                seen = prev > 0
                gap = np.where(seen, t - prev, 0)
                self.gap_sum[rows] += gap
                self.gap_count[rows] += seen
                self.gap_max[rows] = np.maximum(self.gap_max[rows], gap)
                self.gap_sq[rows] += gap * gap
                cell = at(self.target_gap_sum.shape, rows, c)  # int [B], flat in [R, C]
                flat(self.target_gap_sum)[cell] += gap
                flat(self.target_gap_count)[cell] += seen
                if t - 1 > self.warmup:
                    self.worst[rows] = np.maximum(self.worst[rows], t - 1 - prev)
                # a patrol cycle: every target visited once since the cycle began
                start = self.cycle_start[rows]
                seen_now = self.cycle_seen[rows] + ((t >= start) & (prev < start))
                done = seen_now == self.n_targets
                self.cycles[rows] += done
                self.cycle_start[rows] = np.where(done, t + 1, start)
                self.cycle_seen[rows] = np.where(done, 0, seen_now)
        # the runs that took the step, act (bool [R]), take it in (in place, where=act)
        act = out.active
        if charge is not None:
            np.minimum(self.min_charge, charge.min(axis=1), out=self.min_charge, where=act)
        if in_window:
            idle = self.n_targets * t - self.last_sum
            np.add(self.idle_total, idle, out=self.idle_total, where=act)
            np.add(self.measured, 1, out=self.measured, where=act)
            np.maximum(self.max_wait, wait.max(axis=1), out=self.max_wait, where=act)
            if stall is not None:
                np.maximum(self.max_stall, stall.max(axis=1), out=self.max_stall, where=act)
            waiting = (wait > 0).sum(axis=1)
            np.add(self.wait_total, waiting, out=self.wait_total, where=act)
            blocked = ((out.ask >= 0) & ~out.as_asked).sum(axis=1)
            np.add(self.interferences, blocked, out=self.interferences, where=act)
        self.intruders(out, failing)

    def intruders(self, out: Outcome, failing: np.ndarray | None = None) -> None:
        """Take in the step's arrivals and departures for the intruder measures (off
        without attack durations): a target entered while empty closes an empty stretch
        (:meth:`_close`); a target left empty by the step is a departure at ``out.t``.
        Arrivals are counted before departures, so a cell a robot leaves while another
        enters it stays occupied. A robot ``failing`` (bool ``[R, K]``) at the end of the
        step stands nowhere after it: it leaves the cell it stood on before the step and
        enters none."""
        if not self.attack.size:
            return
        t = out.t
        target = self.target
        moved, gone = out.moved, out.moved
        if failing is not None:
            moved, gone = out.moved & ~failing, out.moved | failing
        n_cells = self.empty_since.shape[1]
        # arrivals, before any departure: robots entering one target together (cells
        # shared with collisions off) as one group; an empty target's stretch closes
        rows, cells, count = _groups(moved, out.pos, target, n_cells)
        if rows.size:
            v = self.empty_since[rows, cells]
            empty = v >= 0
            if empty.any():
                self._close(rows[empty], cells[empty], v[empty], t)
            self.empty_since[rows, cells] = np.where(empty, -count, v - count)
        rows, cells, count = _groups(gone, out.prev_pos, target, n_cells)  # departures
        if rows.size:
            v = self.empty_since[rows, cells] + count
            self.empty_since[rows, cells] = np.where(v == 0, t, v)

    def _close(self, rows: np.ndarray, cells: np.ndarray, e: np.ndarray, b: int) -> None:
        """Target ``cells`` of runs ``rows`` (int ``[B]``, distinct pairs), empty from the
        end of step ``e`` (int ``[B]``) on, are entered in step ``b``
        (:func:`empty_stretch`): a stretch that began in the window (``e > warmup``)
        goes to the bucket of its gap (the random intruders it hid follow from its gap),
        one that began before it adds the random intruders it hid from the window's
        start on; its departure goes to the bucket of its gap (or, near the horizon,
        per duration)."""
        if b <= self.warmup:  # (nothing before the window)
            return
        attack = self.attack
        gap = b - e
        bucket = np.searchsorted(attack, gap, side="left")  # durations below the gap
        inside = e > self.warmup
        # (a run may close several stretches in one step: np.add.at adds each)
        ri, bi = rows[inside], bucket[inside]
        np.add.at(self.stretch_count, (ri, bi), 1)
        np.add.at(self.stretch_sum, (ri, bi), gap[inside])
        equal = inside & (bucket < attack.size)
        equal &= attack[np.minimum(bucket, attack.size - 1)] == gap
        np.add.at(self.stretch_equal, (rows[equal], bucket[equal]), 1)
        rand, counted, missed = empty_stretch(attack, self.warmup, self.horizon, e, b)
        np.add.at(self.random_missed, rows[~inside], rand[~inside])
        every = counted.all(axis=1)  # counted for every D: by the bucket of its gap
        self.gaps[rows[every], cells[every], bucket[every]] += 1
        some = counted.any(axis=1) & ~every  # near the horizon: for the shorter D only
        self.tail_departures[rows[some], cells[some]] += counted[some]
        self.tail_missed[rows[some], cells[some]] += missed[some]

    def worst_idleness(self, steps_done: np.ndarray) -> np.ndarray:
        """int ``[R]``: worst idleness in the window, open gaps at the end included."""
        open_gaps = steps_done - self.of_targets(self.last).min(axis=1)
        return np.where(steps_done > self.warmup, np.maximum(self.worst, open_gaps), self.worst)

    def of_targets(self, a: np.ndarray) -> np.ndarray:
        """``a[..., target]``: an array over cells (last axis) over the targets only
        (``a`` itself when every cell is a target)."""
        return a if self.n_targets == self.n_cells else a[..., self.target]

    def target_averages(self, steps_done: np.ndarray) -> np.ndarray:
        """float ``[R, T]``: each target's average interval over the intervals ending in
        the window; a target with none counts with its idleness at the end,
        ``steps_done - last`` (``steps_done`` if never visited)."""
        total, count = self.of_targets(self.target_gap_sum), self.of_targets(self.target_gap_count)
        open_gap = np.asarray(steps_done)[:, None] - self.of_targets(self.last)
        avg = open_gap.astype(np.float64)
        np.divide(total, count, out=avg, where=count > 0)
        return avg


def division_of_labour(visits: np.ndarray) -> np.ndarray:
    """float ``[R]`` from visit counts int ``[R, K, C]`` (NaN for a run with no visit)."""
    total = visits.sum(axis=1)  # [R, C]
    share = np.full(total.shape, np.nan)
    np.divide(visits.max(axis=1), total, out=share, where=total > 0)
    visited = total > 0
    counts = visited.sum(axis=1)
    sums = np.where(visited, share, 0.0).sum(axis=1)
    return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


def stalls(s: State, t: int) -> np.ndarray:
    """int ``[R, K]``: each robot's stall after step ``t``, the age of its task (``t -
    State.since``; 0 for a failed robot): what :meth:`Measures.observe` takes."""
    return np.where(s.mode != GONE, t - s.since, 0)


def stall_bound(p: Params, planned: int | np.ndarray = 0) -> int | np.ndarray:
    """The longest stretch without progress a live team may show (``max_stall``).

    ``trip`` is the most steps a task takes once it is the oldest: under ``exclusive``
    ``task_moves + 2`` (its aim is at most ``task_moves`` moves away, the diameter but
    for ``hpcc``'s routes, ``Params.task_moves``; it moves one cell
    closer every step but one, and from the step after it is first blocked its robot
    holds the right of way: docs/model.md, "What is proven"); under ``interference`` a
    trip of ``diameter`` moves with stops
    (:func:`qpatrol.world.interference.travel_steps`); under ``none`` ``diameter``.
    Without battery a task waits at most for the K - 1 older tasks: ``K x trip`` (a
    theorem for strategies that keep asking for a shortest way to their aim). With the
    battery a robot may queue behind every other robot of the team, each of which
    travels to a station, charges (``charge_steps``) and clears the station's pocket
    (``2 x depart_len``): ``K x
    (charge_steps + 2 x max depart_len + 2 x trip + 1) + trip``, a yardstick under
    ``exclusive`` and a theorem when robots pass each other (docs/model.md).
    ``planned``: the strategy's own waits, added (per run, int ``[R]``, or one for all:
    :meth:`qpatrol.strategies.base.Strategy.planned_wait`; walk followers wait for
    their spacing).
    """
    if p.avoid_collisions:
        trip = p.task_moves + 2
    else:
        trip = interference.travel_steps(p.task_moves, p)
    if not p.battery:
        return p.n_agents * trip + planned
    turnaround = p.charge_steps + 2 * int(p.depart_len.max()) + 2 * trip + 1
    return p.n_agents * turnaround + trip + planned


def summarize(
    m: Measures,
    episodes: pd.DataFrame,
    run_ids: np.ndarray,
    steps_done: np.ndarray,
    bound: int | np.ndarray,
) -> list[dict[str, Any]]:
    """Per-run measures as plain dicts (JSON-ready), in batch order; ``bound``: the
    ``stall_bound``, one for every run or int ``[R]``."""
    dol = division_of_labour(m.window_visits)
    per_target = m.of_targets(m.window_visits).sum(axis=1)  # [R, T] window visits
    coverage = (per_target > 0).mean(axis=1)
    worst = m.worst_idleness(steps_done)
    field = field_measures(m, per_target, steps_done)
    intruder = intruder_measures(m, steps_done)
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
        avg = (m.idle_total / (m.n_targets * m.measured)).tolist()
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
        m.max_stall.tolist(),
        m.min_charge.tolist(),
    ]
    never = int(np.iinfo(np.int64).max)
    bounds = np.broadcast_to(np.asarray(bound, dtype=np.int64), (n,)).tolist()
    out = []
    for i, row in enumerate(zip(*cols, strict=True)):
        run, steps, done, cut, n_ep, cov, wst, gmax, lab, waits, mwait, stall, charge = row
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
                "max_stall": stall,
                "stall_bound": bounds[i],
                # no robot without progress longer than the bound, every target visited
                "live": bool(stall <= bounds[i] and (not seen or cov == 1.0)),
                "min_charge": None if charge == never else charge,
                **{key: values[i] for key, values in field.items()},
                **{key: values[i] for key, values in intruder.items()},
            }
        )
    return out


def _groups(
    who: np.ndarray, where: np.ndarray, target: np.ndarray, n_cells: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The targets that robots ``who`` (bool ``[R, K]``) stand on ``where`` (int ``[R,
    K]``): each (run, target) once, as ``rows``, ``cells`` and the robots ``count``
    (int ``[B]`` each)."""
    rows, ks = np.nonzero(who)
    cells = where[rows, ks]
    on = target[cells]
    key, count = np.unique(rows[on] * n_cells + cells[on], return_counts=True)
    return key // n_cells, key % n_cells, count


def empty_stretch(
    attack: np.ndarray, warmup: int, horizon: int, e: np.ndarray, b: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What one empty stretch of a target does to the intruder measures, per stretch and
    attack duration D (int ``[..., A]`` each; ``attack`` int ``[A]``): the target is
    empty at the end of steps ``e`` (int ``[...]``; 0: since the start) to ``b - 1``
    and occupied at the end of step ``b`` (``horizon + 1`` for a stretch still open at
    the end). Returns the random intruders it hides (strike at the end of step ``a``,
    with ``warmup <= a <= horizon - D``, all of ``a + 1 .. a + D`` inside the stretch:
    ``max(0, b - D - max(e - 1, warmup))``), whether its departure counts for D (``e >=
    1``, ``warmup <= e <= horizon - D``) and whether that departure was missed (``b - e >
    D``)."""
    e2 = np.asarray(e)[..., None]
    rand = np.maximum(0, b - attack - np.maximum(e2 - 1, warmup))
    counted = (e2 >= 1) & (e2 >= warmup) & (e2 <= horizon - attack)
    return rand, counted, counted & (b - e2 > attack)


def attack_steps(setting: str | list[int], n_targets: int) -> tuple[int, ...]:
    """The attack durations of config key ``security.attack_steps`` on a map of
    ``n_targets`` targets: the list given, or for ``auto`` T/8, T/4, T/2, T and 2T
    rounded up (short attacks, that a team catches only where it stands near, to long
    ones, that outlast a walk of every target)."""
    if setting == "auto":
        t = n_targets
        return tuple(sorted({-(-t // 8), -(-t // 4), -(-t // 2), t, 2 * t}))
    return tuple(sorted(set(setting)))


def attack_names(d: int) -> tuple[str, str, str]:
    """The summary keys of the intruder measures for attacks of ``d`` steps."""
    return f"capture_random_d{d}", f"capture_observer_d{d}", f"capture_observer_cell_d{d}"


def intruder_measures(m: Measures, steps_done: np.ndarray) -> dict[str, list[Any]]:
    """``capture_random``, ``capture_observer`` and ``capture_observer_cell`` for each
    attack duration D of ``m`` (keys :func:`attack_names`), per run (a list ``[R]``;
    None where no intruder fits in the window, or for a run that stopped before its
    horizon); definitions in ``docs/model.md``, "Intruders". The empty stretches still
    open at the end are closed at the horizon + 1; integers are exact, then one float
    division per value."""
    out: dict[str, list[Any]] = {}
    attack = m.attack
    if not attack.size:
        return out
    s, w = m.horizon, m.warmup
    tgt = slice(None) if m.n_targets == m.n_cells else m.target
    # the stretches still open at the end close at the horizon + 1 (added to copies: the
    # accumulators stay as they are, so a checkpointed run goes on from them)
    since = m.empty_since[:, tgt]  # [R, T]
    # (an occupied target as a stretch from the horizon + 1: it adds nothing)
    e_end = np.where(since >= 0, since, s + 1)
    rand, counted, miss = empty_stretch(attack, w, s, e_end, s + 1)  # [R, T, A]
    random_missed = m.random_missed + rand.sum(axis=1)
    # the stretches that began in the window: a gap g hides max(0, g + 1 - D); the
    # buckets above the i-th D hold the gaps longer than it, and equal ones hide 1
    n_a = attack.size
    for i, d in enumerate(attack.tolist()):
        longer = slice(i + 1, n_a + 1)
        random_missed[:, i] += (
            m.stretch_sum[:, longer].sum(axis=1)
            + (1 - d) * m.stretch_count[:, longer].sum(axis=1)
            + m.stretch_equal[:, i]
        )
    gaps = m.gaps[:, tgt].astype(np.int64)  # [R, T, A + 1]
    below = np.cumsum(gaps, axis=2)  # departures with a gap up to each D, and all of them
    departures = below[..., -1:] + m.tail_departures[:, tgt] + counted  # [R, T, A]
    # missed for the i-th D: the buckets above i
    missed = below[..., -1:] - below[..., :-1] + m.tail_missed[:, tgt] + miss
    done = np.asarray(steps_done) == s
    cell_ids = np.flatnonzero(m.target)
    rows_all = np.arange(departures.shape[0])
    for j, d in enumerate(attack.tolist()):
        k_rand, k_obs, k_cell = attack_names(d)
        pairs = m.n_targets * (s - d - w + 1)
        ok = (done & (pairs > 0)).tolist()
        dep = departures[..., j]
        frac = np.full(dep.shape, np.inf)
        np.divide(dep - missed[..., j], dep, out=frac, where=dep > 0)
        worst = np.argmin(frac, axis=1)  # the lowest cell among ties
        value = frac[rows_all, worst]
        has = [o and v != math.inf for o, v in zip(ok, value.tolist(), strict=True)]
        rand_j = ((pairs - random_missed[:, j]) / max(pairs, 1)).tolist()  # (None: not ok)
        out[k_rand] = [x if o else None for x, o in zip(rand_j, ok, strict=True)]
        out[k_obs] = [x if h else None for x, h in zip(value.tolist(), has, strict=True)]
        out[k_cell] = [x if h else None for x, h in zip(cell_ids[worst].tolist(), has, strict=True)]
    return out


#: The patrolling field's measures (:func:`field_measures`), after today's in a summary.
FIELD_MEASURES = (
    "qmi",
    "std_interval",
    "freq_std",
    "worst_avg_idleness",
    "mean_avg_idleness",
    "median_idleness",
    "std_idleness",
    "cycles",
    "interferences",
)


def field_measures(
    m: Measures, per_target: np.ndarray, steps_done: np.ndarray
) -> dict[str, list[Any]]:
    """Each of :data:`FIELD_MEASURES` per run (a list ``[R]``; None where undefined),
    from the accumulators of ``m``, ``per_target`` int ``[R, T]`` (window visits of each
    target) and ``steps_done`` int ``[R]``; definitions in ``docs/model.md``,
    "Patrolling measures". Sums of integers are exact (Python integers), then one
    float division or square root; sums of floats are math.fsum's: the same
    accumulators give the same bits, in any batch."""
    n_t = m.n_targets
    # sums over each run's row alone, by math.fsum, exactly rounded (a float reduction
    # over the axis of a [R, T] array may add in an order that depends on R, and a
    # run's numbers must not depend on its batch); the max, the median (the mean of
    # the two middle values) and elementwise steps take the batch at once
    # (math.fsum reads a row's doubles through a memoryview, without a list of them)
    avg = m.target_averages(steps_done)  # float [R, T]
    mean_avg = [math.fsum(memoryview(a)) / n_t for a in avg]
    worst_avg = avg.max(axis=1).tolist()
    median = np.median(avg, axis=1).tolist()
    deviation = (avg - np.array(mean_avg)[:, None]) ** 2
    spread = [math.sqrt(math.fsum(memoryview(d)) / n_t) for d in deviation]
    visits = per_target.sum(axis=1).tolist()
    visits_sq = (per_target * per_target).sum(axis=1).tolist()
    out: dict[str, list[Any]] = {key: [] for key in FIELD_MEASURES}
    sums = (m.measured, m.gap_count, m.gap_sum, m.gap_sq)
    rows = zip(*(x.tolist() for x in sums), strict=True)
    for i, (seen, n, s1, s2) in enumerate(rows):
        out["qmi"].append(math.sqrt(s2 / n) if n else None)
        out["std_interval"].append(math.sqrt(n * s2 - s1 * s1) / n if n else None)
        # population std of visits / window length over targets: sqrt(T sum v^2 - (sum
        # v)^2) / (T W)
        spread_v = n_t * visits_sq[i] - visits[i] * visits[i]
        out["freq_std"].append(math.sqrt(spread_v) / (n_t * seen) if seen else None)
        out["worst_avg_idleness"].append(worst_avg[i] if seen else None)
        out["mean_avg_idleness"].append(mean_avg[i] if seen else None)
        out["median_idleness"].append(median[i] if seen else None)
        out["std_idleness"].append(spread[i] if seen else None)
    out["cycles"] = m.cycles.tolist()
    out["interferences"] = m.interferences.tolist()
    return out
