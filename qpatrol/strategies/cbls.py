"""``cbls`` (Portugal and Rocha 2016, Concurrent Bayesian Learning Strategy): each robot
learns, by reward and punishment of its decisions, which neighbouring target to take.

A neighbour-goal follower (:mod:`qpatrol.strategies.goals`). Robot k keeps a
*histogram* ``h[k, c, d] in [0.5, 2]`` (1 at first) over the arcs of the target graph
(target c, port d), and, on its group map (the team's with communication on, its own
without), for every target the number of visits ``n``, the mean idleness ``a`` found at
the visits and the step ``s`` of the last visit (visits: robots entering a target).

*Choice* at target c, step t. The candidates are the ports the goal followers allow
whose far target v no other robot has as its goal (with communication on; every allowed
port when all are), n of them. With ``I(v) = t - s(v)`` and the current mean idleness
``m(v) = (a(v) n(v) + I(v)) / (n(v) + 1)``, the prior of v is ``m(v)`` if v has one
target neighbour, else ``0.75 m(v) + 0.25 M(v)``, M(v) the greatest m over v's target
neighbours no other robot intends (0 when all candidates were intended; ``m(v)`` alone
when M(v) <= 0.001); priors are divided by their sum (1 / n each when the sum is at most
0.001). The posterior is prior x ``h[k, c, d]`` (patrolling_sim divides h by its sum over
all arcs, a common factor left out); the greatest wins, ties to the fewest moves, then
the j-th tied port, ``j = floor(u x ties)``. The decision's entropy is
``H = -sum p ln p / ln n`` (p the posteriors divided by their sum, 0 ln 0 = 0), at most 1.

*Learning.* When the robot next chooses at another target, the ports of its last
decision (n > 1) are judged by the idleness ``I`` of their far targets now: those of
greatest I are rewarded (+1), those of least I (among them the target just reached)
punished (-1, over a reward); each judged arc's h moves by ``sign x (1 - H)`` and is
clipped to [0.5, 2] (patrolling_sim's ``update_likelihood_new``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from qpatrol.strategies import goals

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.measures.records import Recorder
    from qpatrol.world import Observation, Outcome, Params

#: ``math.log`` element by element (the C library's, as the compiled engine's).
_LOG = np.frompyfunc(math.log, 1, 1)

#: The weight of a candidate's own mean idleness in its look-ahead prior.
W_FIRST = 0.75
H_MIN, H_MAX = 0.5, 2.0


class Strategy(goals.GoalFollower):
    """Attributes (``G = K`` group slots, slot 0 the team's with communication on):
    hist: float ``[R, K, C, D]``, each robot's histogram over arcs.
    count: int ``[R, G, C]``, visits; avg: float ``[R, G, C]``, mean idleness at visits;
    seen: int ``[R, G, C]``, the step of the last visit (0: never).
    dec_cell: int ``[R, K]``, the target of the last decision (-1: none); dec_ports: bool
    ``[R, K, D]`` its candidates; dec_ent: float ``[R, K]`` its normalised entropy.
    """

    name = "cbls"
    numpy_cell_us = 0.13  # (base.Strategy.numpy_cell_us)
    learns = True

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        n_runs, n_agents = self.n_runs, self.n_agents
        n_cells, n_ports = self.tnbr.shape
        self.hist = np.ones((n_runs, n_agents, n_cells, n_ports))
        self.count = np.zeros((n_runs, n_agents, n_cells), dtype=np.int64)
        self.avg = np.zeros((n_runs, n_agents, n_cells))
        self.seen = np.zeros((n_runs, n_agents, n_cells), dtype=np.int64)
        self.dec_cell = np.full((n_runs, n_agents), -1, dtype=np.int64)
        self.dec_ports = np.zeros((n_runs, n_agents, n_ports), dtype=bool)
        self.dec_ent = np.zeros((n_runs, n_agents))
        self.degree = (self.tnbr >= 0).sum(axis=1)

    def mean_idleness(self, g: int, rows: np.ndarray, v: np.ndarray, t: int) -> np.ndarray:
        """float, the shape of ``v``: the current mean idleness of targets v."""
        rr = rows.reshape(rows.shape + (1,) * (v.ndim - 1))
        n = self.count[rr, g, v].astype(np.float64)
        idle = (t - self.seen[rr, g, v]).astype(np.float64)
        return (self.avg[rr, g, v] * n + idle) / (n + 1.0)

    def judge(self, g: int, k: int, rows: np.ndarray, t: int) -> None:
        """Reward and punish the arcs of robot k's last decision in runs ``rows``."""
        c0 = self.dec_cell[rows, k]
        poss = self.dec_ports[rows, k]
        ok = (c0 >= 0) & (poss.sum(axis=1) > 1)
        rows, c0, poss = rows[ok], c0[ok], poss[ok]
        if not rows.size:
            return
        v = np.maximum(self.tnbr[c0], 0)
        idle = (t - self.seen[rows[:, None], g, v]).astype(np.float64)
        top = np.where(poss, idle, 0.0).max(axis=1, keepdims=True)
        low = np.where(poss, idle, np.inf).min(axis=1, keepdims=True)
        sign = np.where(idle == top, 1.0, 0.0)
        sign = np.where(idle == low, -1.0, sign)
        h = self.hist[rows[:, None], k, c0[:, None], np.arange(v.shape[1])[None, :]]
        h = h + sign * (1.0 - self.dec_ent[rows, k])[:, None]
        h = np.where(h < H_MIN, H_MIN, np.where(h > H_MAX, H_MAX, h))
        rr, dd = np.nonzero(poss)
        self.hist[rows[rr], k, c0[rr], dd] = h[rr, dd]

    def choose(
        self,
        obs: Observation,
        k: int,
        rows: np.ndarray,
        mask: np.ndarray,
        closed: np.ndarray,
        u: np.ndarray,
    ) -> np.ndarray:
        s, t = obs.state, obs.t
        g = 0 if obs.params.communication else k
        c = s.pos[rows, k]
        on = self.is_target[c]
        out = np.full(rows.size, -1, dtype=np.int64)
        if (~on).any():  # off a target: the goal followers' nearest target
            b = np.flatnonzero(~on)
            out[b] = super().choose(obs, k, rows[b], mask[b], closed[b], u[b])
        b = np.flatnonzero(on)
        if not b.size:
            return out
        rows, c, mask, closed, u = rows[b], c[b], mask[b], closed[b], u[b]
        self.judge(g, k, rows[c != self.dec_cell[rows, k]], t)
        far = self.tnbr[c]  # [B, D]
        cand = far >= 0
        allowed = cand & mask & ~closed
        allowed = np.where(allowed.any(axis=1, keepdims=True), allowed, cand & ~closed)
        allowed = np.where(allowed.any(axis=1, keepdims=True), allowed, cand)
        if obs.params.communication and self.n_agents > 1:
            others = np.delete(self.goal[rows], k, axis=1)  # [B, K - 1]

            def intended(x: np.ndarray) -> np.ndarray:
                return (x[..., None] == others.reshape(others.shape[:1] + (1,) * (x.ndim - 1)
                        + others.shape[1:])).any(axis=-1) & (x >= 0)  # fmt: skip
        else:

            def intended(x: np.ndarray) -> np.ndarray:
                return np.zeros(x.shape, dtype=bool)

        poss = allowed & ~intended(far)
        occupied = ~poss.any(axis=1)
        poss = np.where(occupied[:, None], allowed, poss)
        n = poss.sum(axis=1)
        v = np.maximum(far, 0)
        mv = self.mean_idleness(g, rows, v, t)  # [B, D]
        second = self.tnbr[v]  # [B, D, D]
        ms = self.mean_idleness(g, rows, np.maximum(second, 0), t)
        ok2 = (second >= 0) & ~occupied[:, None, None] & ~intended(second)
        top = np.zeros(far.shape)
        for e in range(second.shape[2]):  # the greatest, strictly, from 0.0
            top = np.where(ok2[:, :, e] & (ms[:, :, e] > top), ms[:, :, e], top)
        look = (self.degree[v] != 1) & (top > 0.001)
        prior = np.where(look, W_FIRST * mv + (1.0 - W_FIRST) * top, mv)
        denom = np.zeros(rows.size)
        for d in range(far.shape[1]):
            denom = np.where(poss[:, d], denom + prior[:, d], denom)
        flat = denom <= 0.001
        prior = np.where(
            flat[:, None],
            1.0 / np.maximum(n, 1)[:, None],
            prior / np.where(flat, 1.0, denom)[:, None],
        )
        post = prior * self.hist[rows[:, None], k, c[:, None], np.arange(far.shape[1])[None, :]]
        masked = np.where(poss, post, -np.inf)
        best = poss & (masked == masked.max(axis=1, keepdims=True))
        cost = np.where(best, self.tcost[c], np.iinfo(np.int64).max)
        best &= cost == cost.min(axis=1, keepdims=True)
        d = goals.pick_nth(best, u)
        # the decision's entropy
        total = np.zeros(rows.size)
        for e in range(far.shape[1]):
            total = np.where(poss[:, e], total + post[:, e], total)
        ent = np.zeros(rows.size)
        for e in range(far.shape[1]):
            pe = post[:, e] / total
            use = poss[:, e] & (pe > 0.0)
            lg = _LOG(np.where(use, pe, 1.0)).astype(np.float64)
            ent = np.where(use, ent + pe * lg, ent)
        lnn = _LOG(np.maximum(n, 2).astype(np.float64)).astype(np.float64)
        ent = np.where(n > 1, np.minimum(-ent / lnn, 1.0), self.dec_ent[rows, k])
        self.dec_cell[rows, k] = c
        self.dec_ports[rows, k] = poss
        self.dec_ent[rows, k] = ent
        out[b] = far[np.arange(rows.size), d]
        return out

    def learn(self, out: Outcome, rec: Recorder | None = None) -> None:
        """Robots that entered a target count the visit on their group map, in robot
        order: ``n += 1``, ``a += (I - a) / n`` as ``(a (n - 1) + I) / n``, ``s = t``."""
        comm = self.params.communication
        for k in range(self.n_agents):
            rr = np.flatnonzero(out.moved[:, k] & self.is_target[out.pos[:, k]])
            if not rr.size:
                continue
            g = 0 if comm else k
            v = out.pos[rr, k]
            idle = (out.t - self.seen[rr, g, v]).astype(np.float64)
            n = self.count[rr, g, v] + 1
            self.count[rr, g, v] = n
            self.avg[rr, g, v] = (
                self.avg[rr, g, v] * (n - 1).astype(np.float64) + idle
            ) / n.astype(np.float64)
            self.seen[rr, g, v] = out.t
