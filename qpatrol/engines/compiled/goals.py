"""``hcr``, ``cc``, ``gbs`` and ``sebs`` compiled: robots that choose a goal target and
travel to it.

The numpy twin is :class:`qpatrol.strategies.goals.GoalFollower` with its four strategies
(:mod:`~qpatrol.strategies.hcr`, :mod:`~qpatrol.strategies.cc`,
:mod:`~qpatrol.strategies.gbs`, :mod:`~qpatrol.strategies.sebs`), operation for
operation: per robot in robot order, drop a goal in another robot's held pocket, choose
a goal where needed (scores in float64 in the twin's order, ties by ``u[k, 1]``), then
ask for the lowest open port on a shortest path, else insist on the lowest such port not
deeper into a held pocket. Every loop over ports runs to ``D = nbrs.shape[1]``.

Pack: ``ipar = [kind (HCR, CC, GBS, SEBS), neighbour goals (0/1)]``; ``fpar = [g1,
ln(1/g1)/g2, g2, edge_min, factor_0 .. factor_K]`` (``sebs``'s intention factors);
``robot_i`` int64 ``[R, K, 1]`` each robot's goal (copied, and back by :func:`unpack`);
``cell_i`` (``cc``) the strategy's ``memory`` int64 ``[R, K, C]`` (its own array);
``table_i`` int64 ``[C, 2 D]`` = ``tnbr | tcost``; ``row_i`` int64 ``[C]`` the targets
(0/1); ``dist`` int64 ``[C, C]``; ``row_f`` float64 ``[R, D]`` scratch, each run's
candidates' scores (written and read within one choice).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from qpatrol.engines.compiled.pack import Pack, dummy_pack
from qpatrol.engines.compiled.stations import closed

HCR, CC, GBS, SEBS = 0, 1, 2, 3
GONE = 4  # battery.GONE
KINDS = {"hcr": HCR, "cc": CC, "gbs": GBS, "sebs": SEBS}
BIG = np.iinfo(np.int64).max


def pack(strategy) -> Pack:
    """The strategy's tables, parameters and goals (and ``cc``'s own ``memory``)."""
    kind = KINDS[strategy.name]
    fpar = [0.0, 0.0, 0.0, 0.0]
    if kind in (GBS, SEBS):
        fpar = [strategy.g1, strategy.coef, strategy.g2, strategy.edge_min]
    factor = strategy.factor if kind == SEBS else np.ones(strategy.n_agents + 1)
    fields = {
        "ipar": np.array([kind, int(strategy.neighbour_goals)], dtype=np.int64),
        "fpar": np.concatenate([np.array(fpar), factor]).astype(np.float64),
        "robot_i": np.ascontiguousarray(strategy.goal[..., None], dtype=np.int64),
        "table_i": np.ascontiguousarray(
            np.concatenate([strategy.tnbr, strategy.tcost], axis=1), dtype=np.int64
        ),
        "row_i": strategy.is_target.astype(np.int64),
        "dist": np.ascontiguousarray(strategy.dist, dtype=np.int64),
        "row_f": np.zeros((strategy.n_runs, strategy.tnbr.shape[1])),
    }
    if kind == CC:
        fields["cell_i"] = strategy.memory
    return dummy_pack(**fields)


def unpack(p: Pack, strategy) -> None:
    """Copy the goals back (``cc``'s ``memory`` is the strategy's own array)."""
    strategy.goal = p.robot_i[..., 0].copy()


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def forget_gone(r, mode, goal):
    """A robot of run r that failed (``mode`` GONE) announces no goal: ``goal[r, k, 0]``
    (int ``[R, K, X]``) -1 (:class:`qpatrol.strategies.goals.GoalFollower`)."""
    for k in range(goal.shape[1]):
        if mode[r, k] == GONE:
            goal[r, k, 0] = -1


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _held_by_other(r, k, cell, pocket_of, reserved):
    """Cell lies in the pocket of a station a robot other than k holds (run r)."""
    if cell < 0:
        return False
    h = pocket_of[cell]
    if h < 0:
        return False
    holder = reserved[r, h]
    return holder >= 0 and holder != k


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _score(kind, d, r, k, t, c, i_max, c_max, communication, last, goal, table, fpar):
    """The score of port d's far target for robot k on target c (greater is better)."""
    n_ports = table.shape[1] // 2
    far = table[c, d]
    cost = table[c, n_ports + d]
    idle = t - last[r, 0 if communication else k, far]
    if kind == HCR:
        near = np.float64(c_max - cost) / np.float64(c_max)
        if i_max == 0:
            return near + 0.0
        return near + np.float64(idle) / np.float64(i_max)
    weight = max(np.float64(cost), fpar[3])
    gain = np.float64(idle) / weight
    pp = 1.0
    if gain < fpar[2]:
        pp = fpar[0] * math.exp(fpar[1] * gain)
    if kind == SEBS and communication:
        count = 0
        for j in range(goal.shape[1]):
            if j != k and goal[r, j, 0] == far:
                count += 1
        pp = pp * fpar[4 + count]
    return pp


@njit(cache=True, nogil=True, _nrt=False)
def _choose_neighbour(kind, r, k, t, uu, c, battery, p, s, open_mask, goal, table, fpar, score):
    """Robot k's new goal from target c: the far target of its best candidate port
    (``score`` float64 ``[D]``: scratch, the run's own row)."""
    nbrs = p.nbrs
    n_ports = nbrs.shape[1]
    # the candidate ports: open and not closed, else not closed, else all (bits)
    cand = 0
    a1 = 0
    a2 = 0
    for d in range(n_ports):
        if table[c, d] < 0:
            continue
        cand |= 1 << d
        if not closed(r, k, c, nbrs[c, d], battery, p.pocket_of, p.pocket_depth, s.reserved):
            a2 |= 1 << d
            if open_mask[k, d]:
                a1 |= 1 << d
    allowed = a1 if a1 != 0 else (a2 if a2 != 0 else cand)
    last = s.last
    i_max = 0
    c_max = 0
    for d in range(n_ports):
        if allowed >> d & 1:
            i_max = max(i_max, t - last[r, 0 if p.communication else k, table[c, d]])
            c_max = max(c_max, table[c, n_ports + d])
    best = -np.inf
    count = 0
    for d in range(n_ports):
        if allowed >> d & 1:
            sc = _score(kind, d, r, k, t, c, i_max, c_max, p.communication, last, goal, table, fpar)
            score[d] = sc
            if sc > best:
                best = sc
                count = 1
            elif sc == best:
                count += 1
    j = min(np.int64(uu * count), count - 1)
    for d in range(n_ports):
        if allowed >> d & 1 and score[d] == best:
            if j == 0:
                return table[c, d]
            j -= 1
    return -1


@njit(cache=True, nogil=True, _nrt=False)
def _nearest_target(r, k, c, pocket_of, reserved, is_target, dist):
    """The nearest target outside other robots' held pockets (lowest cell on a tie)."""
    best = -1
    best_d = BIG
    for x in range(is_target.shape[0]):
        if is_target[x] and not _held_by_other(r, k, x, pocket_of, reserved):
            if dist[c, x] < best_d:
                best_d = dist[c, x]
                best = x
    return best


@njit(cache=True, nogil=True, _nrt=False)
def _choose_oldest(r, k, uu, c, battery, pocket_of, reserved, is_target, memory):
    """``cc``: the target other than c of oldest ``memory[r, k]``, the j-th tied one."""
    oldest = BIG
    count = 0
    for x in range(is_target.shape[0]):
        if not is_target[x] or x == c:
            continue
        if battery and _held_by_other(r, k, x, pocket_of, reserved):
            continue
        v = memory[r, k, x]
        if v < oldest:
            oldest = v
            count = 1
        elif v == oldest:
            count += 1
    if count == 0:
        return -1
    j = min(np.int64(uu * count), count - 1)
    for x in range(is_target.shape[0]):
        if not is_target[x] or x == c:
            continue
        if battery and _held_by_other(r, k, x, pocket_of, reserved):
            continue
        if memory[r, k, x] == oldest:
            if j == 0:
                return x
            j -= 1
    return -1


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _travel(r, k, c, g, battery, p, s, open_mask, dist):
    """The lowest open port on a shortest path from c to g, else the lowest such port
    not deeper into another robot's held pocket; -1 on g or without a goal."""
    if g < 0 or g == c:
        return -1
    nbrs = p.nbrs
    here = dist[c, g]
    first = -1
    for d in range(nbrs.shape[1]):
        nb = nbrs[c, d]
        if nb < 0 or dist[nb, g] != here - 1:
            continue
        if closed(r, k, c, nb, battery, p.pocket_of, p.pocket_depth, s.reserved):
            continue
        if open_mask[k, d]:
            return d
        if first < 0:
            first = d
    return first


@njit(cache=True, nogil=True, _nrt=False)
def act(r, t, ur, battery, p, s, w, ipar, fpar, goal, table, is_target, dist, memory, scratch):
    """``w.ask[k]`` for each robot of run ``r`` at step ``t``: goals chosen robot by
    robot, then the move towards the goal; -1 for robots not choosing."""
    kind = ipar[0]
    neighbour = ipar[1] != 0
    pos, open_mask, choosing, ask = s.pos, w.open_mask, w.choosing, w.ask
    forget_gone(r, s.mode, goal)
    for k in range(choosing.shape[0]):
        if not choosing[k]:
            ask[k] = -1
            continue
        c = pos[r, k]
        g = goal[r, k, 0]
        if battery and _held_by_other(r, k, g, p.pocket_of, s.reserved):
            g = -1
        need = g < 0 or g == c or (neighbour and is_target[c] != 0)
        if need:
            if kind == CC:
                g = _choose_oldest(
                    r, k, ur[k, 1], c, battery, p.pocket_of, s.reserved, is_target, memory
                )
            elif is_target[c] != 0:
                g = _choose_neighbour(
                    kind, r, k, t, ur[k, 1], c, battery, p, s, open_mask, goal, table, fpar,
                    scratch[r],
                )  # fmt: skip
            else:
                g = _nearest_target(r, k, c, p.pocket_of, s.reserved, is_target, dist)
        goal[r, k, 0] = g
        ask[k] = _travel(r, k, c, g, battery, p, s, open_mask, dist)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def learn(r, t, ipar, pos, moved, swapped, goal, memory):
    """``cc``: each robot that entered a cell at step ``t`` remembers it, and one that
    handed its goal on (``swapped`` ``[K]``, the partner; its goal ``goal[r, j, 0]``
    now) counts that goal as served."""
    if ipar[0] != CC:
        return
    for k in range(moved.shape[0]):
        if moved[k]:
            memory[r, k, pos[r, k]] = t
    for k in range(moved.shape[0]):
        if swapped[k] >= 0 and goal[r, swapped[k], 0] >= 0:
            memory[r, k, goal[r, swapped[k], 0]] = t
