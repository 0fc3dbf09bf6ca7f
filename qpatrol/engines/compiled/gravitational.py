"""``gravitational`` compiled: robots pulled by the masses of idle targets.

The numpy twin is :mod:`qpatrol.strategies.gravitational`, operation for operation:
goals of robots that left patrolling dropped, then robot by robot in robot order the
masses of the targets (growth of the group map's idleness, 0 at the goals it knows of),
the force on each port (the propagation's pulls ``mass x (1 / L^e)``, combined target by
target in cell order: a running sum or maximum from 0), the open port of greatest force
(``greatest``, ties by ``u[k, 1]``) and its far target as the new goal. ``pow`` only in
the geometric growth, by ``math.pow`` (the C library's, as the twin's); the table of
``1 / L^e`` is the twin's own.

Pack: ``ipar = [growth, combination, propagation]`` (the twin's codes); ``fpar = [1 +
growth rate, 1 / 0^e = 1, 1 / 1^e, 1 / 2^e, ...]``; ``robot_i`` int64 ``[R, K, 1]`` each
robot's goal (copied, and back by :func:`unpack`); ``table_i`` int64 ``[C, D + 1]`` =
each port's length to its far target | the cell's index among the targets (-1);
``row_i`` int64 ``[T]`` the targets; ``dist`` int64 ``[C, T]`` moves to each target;
``cell_f`` float64 ``[R, 1, T]`` scratch, the run's masses (written and read within one
choice).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from qpatrol.engines.compiled.choice import greatest
from qpatrol.engines.compiled.pack import Pack, dummy_pack

ARITHMETIC, GEOMETRIC = 0, 1  # (growth; else none)
MAX = 1  # (combination; else sum)
EDGE, NODE, NODE_NO_DISTANCE, MIXED = 0, 1, 2, 3
PATROL = 0  # battery.PATROL


def pack(strategy) -> Pack:
    """The strategy's tables, parameters and goals."""
    n_cells = strategy.dist.shape[0]
    index = np.full(n_cells, -1, dtype=np.int64)
    index[strategy.targets] = np.arange(strategy.targets.size)
    return dummy_pack(
        ipar=np.array(
            [strategy.growth, strategy.combination, strategy.propagation], dtype=np.int64
        ),
        fpar=np.concatenate([[strategy.ratio], strategy.inv]).astype(np.float64),
        robot_i=np.ascontiguousarray(strategy.goal[..., None], dtype=np.int64),
        table_i=np.ascontiguousarray(
            np.concatenate([strategy.tcost, index[:, None]], axis=1), dtype=np.int64
        ),
        row_i=strategy.targets.astype(np.int64),
        dist=np.ascontiguousarray(strategy.dist, dtype=np.int64),
        cell_f=np.zeros((strategy.n_runs, 1, strategy.targets.size)),
    )


def unpack(p: Pack, strategy) -> None:
    """Copy the goals back."""
    strategy.goal = p.robot_i[..., 0].copy()


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _mass(growth, ratio, idle):
    """The mass of a target of idleness ``idle`` (``growth_of``)."""
    if growth == ARITHMETIC:
        return np.float64(idle)
    if growth == GEOMETRIC:
        if idle == 0:
            return 0.0
        return math.pow(ratio, np.float64(idle - 1))
    return 1.0


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _add(acc, value, combination):
    """``acc`` combined with one more pull."""
    if combination == MAX:
        return max(acc, value)
    return acc + value


@njit(cache=True, nogil=True, _nrt=False)
def _forces(x, nbrs, far, propagation, combination, fpar, table, targets, dist, mass, score):
    """``score`` float64 ``[D]``: the force on each port of target x (``forces``)."""
    n_ports = nbrs.shape[1]
    for d in range(n_ports):
        score[d] = 0.0
    if propagation == EDGE:
        for i in range(targets.shape[0]):
            dx = dist[x, i]
            if dx <= 0:
                continue
            pull = mass[i] * fpar[1 + dx]
            for d in range(n_ports):  # the lowest port that starts a shortest path
                n = nbrs[x, d]
                if n >= 0 and dist[n, i] == dx - 1:
                    score[d] = _add(score[d], pull, combination)
                    break
        return
    for d in range(n_ports):
        y = far[x, d]
        if y < 0:
            continue
        length = table[x, d]
        acc = 0.0
        for i in range(targets.shape[0]):
            dy = dist[y, i]
            if dy < 0:
                continue
            if propagation == MIXED:
                if targets[i] == x:
                    continue
                acc = _add(acc, mass[i] * fpar[1 + length + dy], combination)
            else:
                acc = _add(acc, mass[i] * fpar[1 + dy], combination)
        if propagation == NODE:
            acc = acc / np.float64(max(length, 1))
        score[d] = acc


@njit(cache=True, nogil=True, _nrt=False)
def act(r, t, ur, p, s, w, ipar, fpar, goal, table, targets, dist, masses):
    """``w.ask[k]`` for each robot of run ``r`` at step ``t``: robot by robot, the open
    port of greatest force; -1 for robots not choosing."""
    growth, combination, propagation = ipar[0], ipar[1], ipar[2]
    pos, open_mask, choosing, ask = s.pos, w.open_mask, w.choosing, w.ask
    n_agents = choosing.shape[0]
    n_ports = p.nbrs.shape[1]
    for k in range(n_agents):  # a robot that leaves patrolling announces no goal
        if s.mode[r, k] != PATROL:
            goal[r, k, 0] = -1
    mass = masses[r, 0]
    for k in range(n_agents):
        if not choosing[k]:
            ask[k] = -1
            continue
        x = pos[r, k]
        grp = 0 if p.communication else k
        for i in range(targets.shape[0]):
            mass[i] = _mass(growth, fpar[0], t - s.last[r, grp, targets[i]])
        for j in range(n_agents):
            if p.communication or j == k:
                g = goal[r, j, 0]
                if g >= 0:
                    mass[table[g, n_ports]] = 0.0
        score = w.score[k]
        _forces(x, p.nbrs, p.far, propagation, combination, fpar, table, targets, dist, mass, score)
        d = greatest(score, open_mask, k, False, ur[k, 1])
        ask[k] = d
        goal[r, k, 0] = p.far[x, d] if d >= 0 else -1
