"""The field's recount of the interval measures: SimPatrol's ``MetricsReport``.

SimPatrol (Sampaio's ``tools.metrics.MetricsReport``) measures a closed window of
turns ``[start, end]`` and, for each vertex, counts as intervals: the time from the
window's start to the vertex's first visit in it, the time between its consecutive
visits in it, and the open gap from its last visit to ``end + 1`` (a vertex never
visited in the window has the one interval ``end + 1 - start``). Visits before the
window are ignored. Its average idleness of a vertex is the sum over its intervals
``i`` of ``(i*i - i) / 2`` divided by the window's length ``end - start + 1``; its
maximum instantaneous idleness is the largest interval. Definitions and how they
differ from qpatrol's own: ``docs/model.md``, "Patrolling measures".
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def simpatrol_intervals(times: Sequence[int] | np.ndarray, start: int, end: int) -> list[int]:
    """One vertex's intervals as SimPatrol's MetricsReport counts them.

    ``times``: int ``[V]``, the steps at which the vertex was visited (any order,
    repeats kept; those outside ``[start, end]`` are dropped); ``start``, ``end``: the
    closed window. Returns the intervals in time order (``V_in + 1`` of them, ``V_in``
    the visits in the window)."""
    if end < start:
        raise ValueError(f"end ({end}) must be at least start ({start})")
    inside = sorted(int(t) for t in times if start <= int(t) <= end)
    out, last = [], start
    for t in inside:
        out.append(t - last)
        last = t
    out.append(end + 1 - last)
    return out


def simpatrol_measures(
    visits: Sequence[Sequence[int]] | Sequence[np.ndarray], start: int, end: int
) -> dict[str, float]:
    """SimPatrol's interval and idleness measures over the window ``[start, end]``.

    ``visits``: for each of the T vertices, the steps at which it was visited (int
    ``[V_c]``). Returns ``qmi`` (quadratic mean of all intervals), ``mean_interval``,
    ``max_interval`` (= SimPatrol's maximum instantaneous idleness), ``std_interval``
    (population), ``avg_idleness`` (the mean over vertices of each vertex's
    ``sum (i*i - i) / 2 / (end - start + 1)``) and ``intervals`` (their number).
    Integer sums are exact; then one division or square root each."""
    per = [simpatrol_intervals(t, start, end) for t in visits]
    flat = [i for row in per for i in row]
    n, s1, s2 = len(flat), sum(flat), sum(i * i for i in flat)
    length = end - start + 1
    # (i*i - i) is even: the sums are exact integers
    node_idle = [sum((i * i - i) // 2 for i in row) / length for row in per]
    return {
        "qmi": math.sqrt(s2 / n),
        "mean_interval": s1 / n,
        "max_interval": float(max(flat)),
        "std_interval": math.sqrt(n * s2 - s1 * s1) / n,
        "avg_idleness": math.fsum(node_idle) / len(per),
        "intervals": float(n),
    }


def visit_times(positions: np.ndarray, n_targets: int, first_step: int = 1) -> list[np.ndarray]:
    """Each target's visit steps from a trace of positions.

    ``positions``: int ``[S, K]``, the target (or -1: none, in transit) each of K robots
    entered at steps ``first_step .. first_step + S - 1``; returns T int arrays of the
    steps at which each target was entered (one entry per robot entering it)."""
    steps, robots = np.nonzero(positions >= 0)
    cells = positions[steps, robots]
    return [np.sort(steps[cells == c]) + first_step for c in range(n_targets)]


def trajectory_visits(cells: np.ndarray, target: np.ndarray, first_step: int) -> list[np.ndarray]:
    """Each target's visit steps from a run's trajectory (``record.trajectory``).

    ``cells``: int ``[S + 1, K]``, every robot's cell at steps ``first_step - 1 ..
    first_step + S - 1``; ``target``: bool ``[C]``, the map's targets. A robot visits a
    target at step t when its cell at t is a target and differs from its cell at t - 1
    (qpatrol's visits: two robots entering a target at one step are two visits). Returns
    T int arrays, by target number (the order of the targets among the cells)."""
    index = np.cumsum(target) - 1  # cell -> target number
    entered = (cells[1:] != cells[:-1]) & target[cells[1:]]
    pos = np.where(entered, index[cells[1:]], -1)
    return visit_times(pos, int(target.sum()), first_step)
