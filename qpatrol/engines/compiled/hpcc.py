"""``hpcc`` compiled: a goal anywhere by normalised idleness and nearness, reached along
a route that prefers idle targets.

The numpy twin is :class:`qpatrol.strategies.hpcc.Strategy`, operation for operation:
per robot in robot order, drop a goal in another robot's held pocket; on its goal (or
without one) choose a goal (utilities in float64 in the twin's order, ties by
``u[k, 1]``) and its route (the twin's Dijkstra: arc costs in float64 in its order,
targets settled by cost then cell, arcs relaxed in port order, strict improvements
only); then follow the route's port (insisting; -1 deeper into a held pocket), or, off
the route, travel to the hop as :mod:`~qpatrol.engines.compiled.goals`. Each robot's
idleness is its own record of the cells it entered (:func:`learn`).

Pack: ``ipar = [least, greatest arc length]``; ``fpar = [idleness weight, distance
weight]``; ``robot_i`` int64 ``[R, K, 2]`` each robot's goal and hop (copied, and back
by :func:`unpack`); ``cell_i`` int64 ``[R, 2 K + 1, C]`` each robot's route (copied, and
back), then a scratch row (each target's predecessor on the cheapest path found, as
``cell x D + port``), then each robot's memory (the step it last entered each cell;
copied, and back); ``cell_f`` float64 ``[R, 2, C]`` scratch (the candidates'
utilities, the pathfinder's costs); ``cell_b`` bool ``[R, 1, C]`` scratch (the settled
targets); ``table_i`` int64 ``[C, 2 D]`` = ``tnbr | tcost``; ``row_i`` int64 ``[C]``
the targets (0/1); ``dist`` int64 ``[C, C]``. The scratch rows are written and read
within one decision.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from qpatrol.engines.compiled import goals
from qpatrol.engines.compiled.pack import Pack, dummy_pack
from qpatrol.engines.compiled.stations import closed


def pack(strategy) -> Pack:
    """The strategy's weights, tables, goals, hops and routes (copies)."""
    from qpatrol.strategies.hpcc import arc_extremes

    n_runs, n_agents, n_cells = strategy.route.shape
    cells = np.zeros((n_runs, 2 * n_agents + 1, n_cells), dtype=np.int64)
    cells[:, :n_agents] = strategy.route
    cells[:, n_agents + 1 :] = strategy.memory
    return dummy_pack(
        ipar=np.array(arc_extremes(strategy.tcost), dtype=np.int64),
        fpar=strategy.weight.astype(np.float64),
        robot_i=np.ascontiguousarray(np.stack([strategy.goal, strategy.hop], axis=2)),
        cell_i=cells,
        cell_f=np.zeros((n_runs, 2, n_cells)),
        cell_b=np.zeros((n_runs, 1, n_cells), dtype=bool),
        table_i=np.ascontiguousarray(
            np.concatenate([strategy.tnbr, strategy.tcost], axis=1), dtype=np.int64
        ),
        row_i=strategy.is_target.astype(np.int64),
        dist=np.ascontiguousarray(strategy.dist, dtype=np.int64),
    )


def unpack(p: Pack, strategy) -> None:
    """Copy the goals, hops, routes and memories back."""
    n_agents = strategy.route.shape[1]
    strategy.goal = p.robot_i[..., 0].copy()
    strategy.hop = p.robot_i[..., 1].copy()
    strategy.route = p.cell_i[:, :n_agents].copy()
    strategy.memory = p.cell_i[:, n_agents + 1 :].copy()


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _last(r, k, x, route):
    """The step at which robot k of run r last entered cell x (its memory, the rows
    after the routes and the scratch row of ``route``)."""
    return route[r, (route.shape[1] - 1) // 2 + 1 + k, x]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def learn(r, t, pos, moved, swapped, robot_i, route):
    """Each robot of run r that entered a cell at step t remembers it, and one that
    handed its goal on (``swapped`` ``[K]``, the partner; its goal ``robot_i[r, j, 0]``
    now) counts that goal as served."""
    n_agents = moved.shape[0]
    for k in range(n_agents):
        if moved[k]:
            route[r, (route.shape[1] - 1) // 2 + 1 + k, pos[r, k]] = t
    for k in range(n_agents):
        if swapped[k] >= 0 and robot_i[r, swapped[k], 0] >= 0:
            route[r, (route.shape[1] - 1) // 2 + 1 + k, robot_i[r, swapped[k], 0]] = t


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _maxima(r, k, t, c, route, is_target, dist):
    """``(I_max, L_max)``: the greatest idleness by robot k's own record and the greatest
    moves from c, over every target (0 at least)."""
    i_max = 0
    l_max = 0
    for x in range(is_target.shape[0]):
        if is_target[x]:
            i_max = max(i_max, t - _last(r, k, x, route))
            l_max = max(l_max, dist[c, x])
    return i_max, l_max


@njit(cache=True, nogil=True, _nrt=False)
def _choose(r, k, t, uu, c, battery, p, s, route, is_target, dist, fpar, score):
    """Robot k's new goal from cell c (``score`` float64 ``[C]``: scratch, the run's own
    row); -1 without a candidate."""
    i_max, l_max = _maxima(r, k, t, c, route, is_target, dist)
    best = -np.inf
    n_cand = 0
    for x in range(is_target.shape[0]):
        if not is_target[x] or x == c:
            continue
        if battery and goals._held_by_other(r, k, x, p.pocket_of, s.reserved):
            continue
        idle = t - _last(r, k, x, route)
        near = 0.0
        if l_max > 0:
            near = np.float64(l_max - dist[c, x]) / np.float64(l_max)
        share = 0.0
        if i_max > 0:
            share = np.float64(idle) / np.float64(i_max)
        sc = fpar[1] * near + fpar[0] * share
        score[x] = sc
        n_cand += 1
        if sc > best:
            best = sc
    if n_cand == 0:
        return -1
    count = 0
    for x in range(is_target.shape[0]):
        if not is_target[x] or x == c:
            continue
        if battery and goals._held_by_other(r, k, x, p.pocket_of, s.reserved):
            continue
        if score[x] == best:
            count += 1
    j = min(np.int64(uu * count), count - 1)
    for x in range(is_target.shape[0]):
        if not is_target[x] or x == c:
            continue
        if battery and goals._held_by_other(r, k, x, p.pocket_of, s.reserved):
            continue
        if score[x] == best:
            if j == 0:
                return x
            j -= 1
    return -1


@njit(cache=True, nogil=True, _nrt=False)
def _pathfind(r, k, t, c, g, p, s, ipar, fpar, table, is_target, dist, route, cost, seen):
    """Robot k's route from target c to g into ``route[r, k]`` (cleared before), the
    pathfinder's scratch ``cost`` float64 ``[C]``, ``seen`` bool ``[C]`` and the
    predecessors in ``route[r, K]``."""
    n_cells = is_target.shape[0]
    n_ports = table.shape[1] // 2
    n_agents = (route.shape[1] - 1) // 2
    i_max, _ = _maxima(r, k, t, c, route, is_target, dist)
    lo, hi = ipar[0], ipar[1]
    for x in range(n_cells):
        cost[x] = np.inf
        seen[x] = False
    cost[c] = 0.0
    cur = c
    while cur != g:
        seen[cur] = True
        for d in range(n_ports):
            w = table[cur, d]
            if w < 0 or seen[w]:
                continue
            stale = 0.0
            if i_max > 0:
                idle = t - _last(r, k, w, route)
                stale = np.float64(i_max - idle) / np.float64(i_max)
            span = 0.0
            if hi > lo:
                span = np.float64(table[cur, n_ports + d] - lo) / np.float64(hi - lo)
            new = cost[cur] + (fpar[0] * stale + fpar[1] * span)
            if new < cost[w]:
                cost[w] = new
                route[r, n_agents, w] = cur * n_ports + d
        nxt = -1
        least = np.inf
        for x in range(n_cells):
            if not seen[x] and cost[x] < least:
                least = cost[x]
                nxt = x
        if nxt < 0:  # (cut off: no route)
            return
        cur = nxt
    x = g
    while x != c:
        code = route[r, n_agents, x]
        x = code // n_ports
        route[r, k, x] = code % n_ports


@njit(cache=True, nogil=True, _nrt=False)
def _plan(r, k, t, uu, c, battery, p, s, ipar, fpar, robot, route, table, is_target, dist, sf, sb):
    """Robot k's new goal from cell c (returned; -1 without a candidate), its route
    (cleared, then set from a target) and its hop."""
    g = _choose(r, k, t, uu, c, battery, p, s, route, is_target, dist, fpar, sf[r, 0])
    for x in range(is_target.shape[0]):
        route[r, k, x] = -1
    robot[r, k, 1] = g if g >= 0 and not is_target[c] else -1
    if g >= 0 and is_target[c]:
        _pathfind(
            r, k, t, c, g, p, s, ipar, fpar, table, is_target, dist, route, sf[r, 1], sb[r, 0]
        )
    return g


@njit(cache=True, nogil=True, _nrt=False)
def act(r, t, ur, battery, p, s, w, ipar, fpar, robot, route, table, is_target, dist, sf, sb):
    """``w.ask[k]`` for each robot of run ``r`` at step ``t``: goals and routes planned
    robot by robot, then the route's port, or the move towards the hop; -1 for robots
    not choosing."""
    nbrs = p.nbrs
    pos, open_mask, choosing, ask = s.pos, w.open_mask, w.choosing, w.ask
    goals.forget_gone(r, s.mode, robot)
    for k in range(choosing.shape[0]):
        if not choosing[k]:
            ask[k] = -1
            continue
        c = pos[r, k]
        g = robot[r, k, 0]
        if battery and goals._held_by_other(r, k, g, p.pocket_of, s.reserved):
            g = -1
        if g < 0 or g == c:
            g = _plan(
                r, k, t, ur[k, 1], c, battery, p, s, ipar, fpar, robot, route, table, is_target,
                dist, sf, sb,
            )  # fmt: skip
        robot[r, k, 0] = g
        port = route[r, k, c]
        if g >= 0 and port >= 0:
            robot[r, k, 1] = table[c, port]
            if closed(r, k, c, nbrs[c, port], battery, p.pocket_of, p.pocket_depth, s.reserved):
                ask[k] = -1
            else:
                ask[k] = port
        else:
            ask[k] = goals._travel(r, k, c, robot[r, k, 1], battery, p, s, open_mask, dist)
