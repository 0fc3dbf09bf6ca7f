"""``cbls`` compiled: each robot learns, by reward and punishment of its decisions, which
neighbouring target to take.

The numpy twin is :class:`qpatrol.strategies.cbls.Strategy`, operation for operation:
per robot in robot order, drop a goal in another robot's held pocket; on a target, judge
the last decision (if made at another target) and choose (sums in port order, ties by
fewest moves then ``u[k, 1]``); off a target, the nearest target; then travel as
:mod:`~qpatrol.engines.compiled.goals`. ``learn``: visits counted in robot order.

Pack: ``robot_i`` int64 ``[R, K, 3]`` each robot's goal, last decision's target and its
candidate ports (bits); ``q`` float64 ``[R, K, C, 1, D]`` the histograms; ``cell_i``
int64 ``[R, 2 K, C]`` visits (slots 0..K-1) and last visits (K..2K-1); ``cell_f``
float64 ``[R, K, C]`` mean idleness at visits; ``row_f`` float64 ``[R, K + 2 D]`` each
robot's last entropy, then scratch (priors, posteriors); ``table_i`` int64 ``[C, 2 D]``
= ``tnbr | tcost``; ``row_i`` int64 ``[C]`` the targets' target degree, -1 off targets;
``dist`` int64 ``[C, C]``. All but the constants are copied and copied back.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from qpatrol.engines.compiled import goals
from qpatrol.engines.compiled.pack import Pack, dummy_pack
from qpatrol.engines.compiled.stations import closed

BIG = np.iinfo(np.int64).max
W_FIRST = 0.75
H_MIN, H_MAX = 0.5, 2.0


def pack(strategy) -> Pack:
    """The strategy's tables and learned state (copies)."""
    n_agents = strategy.n_agents
    n_ports = strategy.tnbr.shape[1]
    bits = (strategy.dec_ports.astype(np.int64) << np.arange(n_ports)).sum(axis=2)
    robot = np.stack([strategy.goal, strategy.dec_cell, bits], axis=2)
    row_f = np.zeros((strategy.n_runs, n_agents + 2 * n_ports))
    row_f[:, :n_agents] = strategy.dec_ent
    degree = np.where(strategy.is_target, strategy.degree, -1)
    return dummy_pack(
        robot_i=np.ascontiguousarray(robot, dtype=np.int64),
        q=np.ascontiguousarray(strategy.hist[:, :, :, None, :], dtype=np.float64),
        cell_i=np.ascontiguousarray(
            np.concatenate([strategy.count, strategy.seen], axis=1), dtype=np.int64
        ),
        cell_f=np.ascontiguousarray(strategy.avg, dtype=np.float64),
        row_f=row_f,
        table_i=np.ascontiguousarray(
            np.concatenate([strategy.tnbr, strategy.tcost], axis=1), dtype=np.int64
        ),
        row_i=degree.astype(np.int64),
        dist=np.ascontiguousarray(strategy.dist, dtype=np.int64),
    )


def unpack(p: Pack, strategy) -> None:
    """Copy the goals, decisions, histograms and visit tables back."""
    n_agents = strategy.n_agents
    n_ports = strategy.tnbr.shape[1]
    strategy.goal = p.robot_i[..., 0].copy()
    strategy.dec_cell = p.robot_i[..., 1].copy()
    strategy.dec_ports = (p.robot_i[..., 2:3] >> np.arange(n_ports)) & 1 == 1
    strategy.dec_ent = p.row_f[:, :n_agents].copy()
    strategy.hist = p.q[:, :, :, 0, :].copy()
    strategy.count = p.cell_i[:, :n_agents].copy()
    strategy.seen = p.cell_i[:, n_agents:].copy()
    strategy.avg = p.cell_f.copy()


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _intended(r, k, x, robot, exchange):
    """Another robot has target x as its goal (with communication on)."""
    if not exchange or x < 0:
        return False
    for j in range(robot.shape[1]):
        if j != k and robot[r, j, 0] == x:
            return True
    return False


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _mean_idleness(r, g, v, t, visits, avg):
    """The current mean idleness of target v on group map g."""
    n_agents = avg.shape[1]
    n = np.float64(visits[r, g, v])
    idle = np.float64(t - visits[r, n_agents + g, v])
    return (avg[r, g, v] * n + idle) / (n + 1.0)


@njit(cache=True, nogil=True, _nrt=False)
def _judge(r, k, g, t, robot, hist, visits, table, ent_row):
    """Reward and punish the arcs of robot k's last decision."""
    c0 = robot[r, k, 1]
    if c0 < 0:
        return
    bits = robot[r, k, 2]
    n_ports = table.shape[1] // 2
    n_agents = hist.shape[1]
    n = 0
    top = 0.0
    low = np.inf
    for d in range(n_ports):
        if bits >> d & 1:
            n += 1
            idle = np.float64(t - visits[r, n_agents + g, table[c0, d]])
            if idle > top:
                top = idle
            if idle < low:
                low = idle
    if n <= 1:
        return
    step = 1.0 - ent_row[k]
    for d in range(n_ports):
        if bits >> d & 1:
            idle = np.float64(t - visits[r, n_agents + g, table[c0, d]])
            sign = 0.0
            if idle == top:
                sign = 1.0
            if idle == low:
                sign = -1.0
            h = hist[r, k, c0, 0, d] + sign * step
            if h < H_MIN:
                h = H_MIN
            elif h > H_MAX:
                h = H_MAX
            hist[r, k, c0, 0, d] = h


@njit(cache=True, nogil=True, _nrt=False)
def _choose(r, k, t, uu, c, battery, p, s, open_mask, robot, hist, visits, avg, table, degree,
            scratch):  # fmt: skip
    """Robot k's new goal from target c (``scratch`` float64 ``[K + 2 D]``, the run's
    row: entropies, then priors and posteriors)."""
    nbrs = p.nbrs
    n_ports = nbrs.shape[1]
    n_agents = robot.shape[1]
    g = 0 if p.communication else k
    exchange = p.communication and n_agents > 1
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
    poss = 0
    for d in range(n_ports):
        if allowed >> d & 1 and not _intended(r, k, table[c, d], robot, exchange):
            poss |= 1 << d
    occupied = poss == 0
    if occupied:
        poss = allowed
    n = 0
    denom = 0.0
    for d in range(n_ports):
        if not poss >> d & 1:
            continue
        n += 1
        v = table[c, d]
        mv = _mean_idleness(r, g, v, t, visits, avg)
        top = 0.0
        for e in range(n_ports):
            w = table[v, e]
            if w < 0 or occupied or _intended(r, k, w, robot, exchange):
                continue
            mw = _mean_idleness(r, g, w, t, visits, avg)
            if mw > top:
                top = mw
        if degree[v] != 1 and top > 0.001:
            prior = W_FIRST * mv + (1.0 - W_FIRST) * top
        else:
            prior = mv
        scratch[n_agents + d] = prior
        denom = denom + prior
    best = -np.inf
    for d in range(n_ports):
        if not poss >> d & 1:
            continue
        if denom <= 0.001:
            prior = 1.0 / np.float64(n)
        else:
            prior = scratch[n_agents + d] / denom
        post = prior * hist[r, k, c, 0, d]
        scratch[n_agents + n_ports + d] = post
        if post > best:
            best = post
    least = BIG
    count = 0
    for d in range(n_ports):
        if poss >> d & 1 and scratch[n_agents + n_ports + d] == best:
            cost = table[c, n_ports + d]
            if cost < least:
                least = cost
                count = 1
            elif cost == least:
                count += 1
    j = min(np.int64(uu * count), count - 1)
    pick = -1
    for d in range(n_ports):
        if poss >> d & 1 and scratch[n_agents + n_ports + d] == best:
            if table[c, n_ports + d] == least:
                if j == 0:
                    pick = d
                    break
                j -= 1
    total = 0.0
    for d in range(n_ports):
        if poss >> d & 1:
            total = total + scratch[n_agents + n_ports + d]
    if n > 1:
        ent = 0.0
        for d in range(n_ports):
            if poss >> d & 1:
                pe = scratch[n_agents + n_ports + d] / total
                if pe > 0.0:
                    ent = ent + pe * math.log(pe)
        x = -ent / math.log(np.float64(n))
        scratch[k] = x if x < 1.0 else 1.0
    robot[r, k, 1] = c
    robot[r, k, 2] = poss
    if pick < 0:
        return -1
    return table[c, pick]


@njit(cache=True, nogil=True, _nrt=False)
def _nearest_target(r, k, c, pocket_of, reserved, degree, dist):
    """The nearest target (``degree >= 0``) outside other robots' held pockets (lowest
    cell on a tie): :func:`qpatrol.engines.compiled.goals._nearest_target`."""
    best = -1
    best_d = BIG
    for x in range(degree.shape[0]):
        if degree[x] >= 0 and not goals._held_by_other(r, k, x, pocket_of, reserved):
            if dist[c, x] < best_d:
                best_d = dist[c, x]
                best = x
    return best


@njit(cache=True, nogil=True, _nrt=False)
def act(r, t, ur, battery, p, s, w, robot, hist, visits, avg, scratch, table, degree, dist):
    """``w.ask[k]`` for each robot of run ``r`` at step ``t``: goals chosen robot by
    robot, then the move towards the goal; -1 for robots not choosing."""
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
        if degree[c] >= 0:
            if c != robot[r, k, 1]:
                _judge(r, k, 0 if p.communication else k, t, robot, hist, visits, table,
                       scratch[r])  # fmt: skip
            g = _choose(r, k, t, ur[k, 1], c, battery, p, s, open_mask, robot, hist, visits,
                        avg, table, degree, scratch[r])  # fmt: skip
        elif g < 0 or g == c:
            g = _nearest_target(r, k, c, p.pocket_of, s.reserved, degree, dist)
        robot[r, k, 0] = g
        ask[k] = goals._travel(r, k, c, g, battery, p, s, open_mask, dist)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def learn(r, t, communication, pos, moved, degree, visits, avg):
    """Robots that entered a target count the visit on their group map, in robot order."""
    n_agents = avg.shape[1]
    for k in range(moved.shape[0]):
        if not moved[k]:
            continue
        v = pos[r, k]
        if degree[v] < 0:
            continue
        g = 0 if communication else k
        idle = np.float64(t - visits[r, n_agents + g, v])
        n = visits[r, g, v] + 1
        visits[r, g, v] = n
        avg[r, g, v] = (avg[r, g, v] * np.float64(n - 1) + idle) / np.float64(n)
        visits[r, n_agents + g, v] = t
