"""``hpcc`` (patrolling_sim's Heuristic Pathfinder Conscientious Cognitive agent): a goal
anywhere, by normalised idleness and nearness, reached along a route that prefers idle
targets.

A goal follower (:mod:`qpatrol.strategies.goals`: goals chosen at targets, held pockets
avoided, insisting) with a *route*. On its goal (or without one) a robot on target c
scores every target x but c (outside another robot's held pocket) by

    U(x) = hpcc.distance_weight x (L_max - L(c, x)) / L_max
         + hpcc.idleness_weight x I(x) / I_max

(the idleness term 0 when ``I_max`` is 0), ``L`` moves on shortest paths, ``I`` the
idleness by the robot's own record of the cells it entered and the goals it handed on
(as ``cc``: patrolling_sim's
cognitive agents exchange nothing, so communication changes nothing), the maxima over
every target of the map; the greatest wins, ties to the j-th
tied target in cell order, ``j = floor(u x ties)``. Its route to the goal is the
cheapest path over the arcs between targets (a port of a target and the target at its
far end) with the costs

    cost(v, d) = hpcc.idleness_weight x (I_max - I(w)) / I_max
               + hpcc.distance_weight x (len(v, d) - len_min) / (len_max - len_min)

(w the arc's far target, ``len`` its moves, the extremes over every arc of the map; a
term 0 when its denominator is), found by patrolling_sim's Dijkstra: targets settled in
order of cost, the lowest cell first on a tie, arcs relaxed in port order, a target's
path replaced only by a strictly cheaper one. The robot keeps its route and follows it,
target by target, to the goal, where it chooses again.

Each decision at a target c: a robot on its route (c one of its targets but the goal)
asks for the route's port out of c, and insists on it when it is blocked (-1 when it
leads deeper into another robot's held pocket); its *hop* becomes the target at that
port's far end. A robot off its route (pushed off it) heads for its hop, the route's
target it was making for, by :meth:`goals.GoalFollower.travel`, and follows the route
again from the first of its targets it stands on. A robot that plans off a target (no
map of today asks one to) has no route and heads for its goal.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.strategies import base, goals
from qpatrol.world import battery

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.measures.records import Recorder
    from qpatrol.world import Observation, Outcome, Params


class Strategy(goals.GoalFollower):
    """Attributes:
    weight: float64 ``[2]``, the weights of the idleness and distance terms.
    span: float64 ``[C, D]``, each arc's length normalised to [0, 1] over the map's arcs
        (0 where no arc, or every arc is as long).
    hop: int ``[R, K]``, the target of its route each robot makes for (-1: none).
    route: int ``[R, K, C]``, the port by which each robot leaves each target of its
        route (-1 off the route, and on the goal).
    memory: int ``[R, K, C]``, the step at which robot k last entered cell c (0: never),
        or handed it on as its goal.
    """

    name = "hpcc"
    numpy_cell_us = 0.63  # (base.Strategy.numpy_cell_us)
    neighbour_goals = False

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.weight = np.array(
            [float(cfg["hpcc.idleness_weight"]), float(cfg["hpcc.distance_weight"])]
        )
        arcs = self.tnbr >= 0
        lo, hi = arc_extremes(self.tcost)
        span = np.zeros(self.tcost.shape)
        if hi > lo:
            span = np.where(arcs, (self.tcost - lo).astype(np.float64) / np.float64(hi - lo), 0.0)
        self.span = span
        self.hop = np.full((self.n_runs, self.n_agents), -1, dtype=np.int64)
        self.route = np.full((self.n_runs, self.n_agents, p.n_cells), -1, dtype=np.int64)
        self.memory = np.zeros((self.n_runs, self.n_agents, p.n_cells), dtype=np.int64)

    def idleness(self, obs: Observation, k: int, rows: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """int, the shape of ``cells``: ``t`` minus robot k's own last visit."""
        return obs.t - self.memory[rows.reshape(rows.shape + (1,) * (cells.ndim - 1)), k, cells]

    def aims(self, obs: Observation) -> np.ndarray:
        """Each robot's goal (not the next target of its route: a task of one hop would
        end at every move, and two robots whose routes cross would push each other back
        and forth, each holding the right of way for one step)."""
        return self.goal.copy()

    def exchange(self, swapped: np.ndarray) -> None:
        """Robots that exchanged tasks exchange goals, hops and routes."""
        self.goal = base.partners(self.goal, swapped)
        self.hop = base.partners(self.hop, swapped)
        self.route = base.partners(self.route, swapped)

    def learn(self, out: Outcome, rec: Recorder | None = None) -> None:
        goals.remember(self.memory, self.goal, out)

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        s, p = obs.state, obs.params
        n_runs, n_agents = s.pos.shape
        rows = np.arange(n_runs)
        ports = p.neighbors[s.pos]  # [R, K, D]
        mask = base.prefer_open(obs)
        closed = (
            battery.closed_cells(s, p, ports) if p.battery else np.zeros(mask.shape, dtype=bool)
        )
        ask = np.full((n_runs, n_agents), -1, dtype=np.int64)
        # a robot that failed announces no goal (qpatrol.world.failures)
        self.goal[s.mode == battery.GONE] = -1
        for k in range(n_agents):
            ch = obs.choosing[:, k]
            c = s.pos[:, k]
            g = self.goal[:, k]
            if p.battery:
                g = np.where(ch & self.held_by_other(s, p, rows, k, g), -1, g)
            need = ch & ((g < 0) | (g == c))
            if need.any():
                b = rows[need]
                g[need] = self.plan(obs, k, b, u[b, k, 1])
            self.goal[:, k] = g
            port = self.route[rows, k, c]
            on = ch & (g >= 0) & (port >= 0)
            d = np.maximum(port, 0)
            self.hop[on, k] = self.tnbr[c[on], d[on]]
            follow = np.where(closed[rows, k, d], -1, port)
            off = self.travel(c, self.hop[:, k], ports[:, k], mask[:, k], closed[:, k])
            ask[:, k] = np.where(ch, np.where(on, follow, off), -1)
        return ask

    def utility(self, obs: Observation, k: int, rows: np.ndarray, c: np.ndarray) -> np.ndarray:
        """float64 ``[B, C]``: the utility of every cell as robot k's goal from cells ``c``."""
        n_cells = self.is_target.size
        cells = np.broadcast_to(np.arange(n_cells), (rows.size, n_cells))
        idle = self.idleness(obs, k, rows, cells)
        i_max = np.where(self.is_target, idle, 0).max(axis=1)[:, None]
        moves = self.dist[c]
        l_max = np.where(self.is_target, moves, 0).max(axis=1)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            near = np.where(
                l_max > 0, (l_max - moves).astype(np.float64) / l_max.astype(np.float64), 0.0
            )
            share = np.where(i_max > 0, idle.astype(np.float64) / i_max.astype(np.float64), 0.0)
        return self.weight[1] * near + self.weight[0] * share

    def plan(self, obs: Observation, k: int, rows: np.ndarray, u: np.ndarray) -> np.ndarray:
        """int ``[B]``: robot k's new goal in runs ``rows`` (-1: no candidate), its route
        and its hop set; ``u`` ``[B]``: its tie-break uniforms."""
        c, _, cand = self.any_target(obs, k, rows)
        score = np.where(cand, self.utility(obs, k, rows, c), -np.inf)
        best = cand & (score == score.max(axis=1, keepdims=True))
        has = cand.any(axis=1)
        best[~has, 0] = True  # (no candidate: a placeholder, replaced by -1 below)
        g = np.where(has, goals.pick_nth(best, u), -1)
        self.route[rows, k] = -1
        self.hop[rows, k] = np.where(has & ~self.is_target[c], g, -1)
        ok = has & self.is_target[c]
        if ok.any():
            self.pathfind(obs, k, rows[ok], c[ok], g[ok])
        return g

    def arc_costs(self, obs: Observation, k: int, rows: np.ndarray) -> np.ndarray:
        """float64 ``[B, C, D]``: the pathfinder's cost of each arc for robot k."""
        n_cells = self.is_target.size
        cells = np.broadcast_to(np.arange(n_cells), (rows.size, n_cells))
        idle = self.idleness(obs, k, rows, cells)
        i_max = np.where(self.is_target, idle, 0).max(axis=1)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            stale = np.where(
                i_max > 0, (i_max - idle).astype(np.float64) / i_max.astype(np.float64), 0.0
            )
        far = stale[:, np.maximum(self.tnbr, 0)]  # [B, C, D]
        return self.weight[0] * far + self.weight[1] * self.span[None]

    def pathfind(
        self, obs: Observation, k: int, rows: np.ndarray, c: np.ndarray, g: np.ndarray
    ) -> None:
        """Robot k's route from targets ``c`` to goals ``g`` (``[B]``) in runs ``rows``:
        patrolling_sim's Dijkstra on :meth:`arc_costs`, stopped when the goal is settled."""
        n_rows, n_cells = rows.size, self.is_target.size
        arc = self.arc_costs(obs, k, rows)
        at = np.arange(n_rows)
        cost = np.full((n_rows, n_cells), np.inf)
        cost[at, c] = 0.0
        seen = np.zeros((n_rows, n_cells), dtype=bool)
        pred = np.full((n_rows, n_cells), -1, dtype=np.int64)
        via = np.full((n_rows, n_cells), -1, dtype=np.int64)
        cur = c.copy()
        live = np.ones(n_rows, dtype=bool)
        while True:
            live &= cur != g
            b = np.flatnonzero(live)
            if not b.size:
                break
            v = cur[b]
            seen[b, v] = True
            for d in range(self.tnbr.shape[1]):
                w = self.tnbr[v, d]
                ww = np.maximum(w, 0)
                new = cost[b, v] + arc[b, v, d]
                ok = (w >= 0) & ~seen[b, ww] & (new < cost[b, ww])
                bb, wo = b[ok], ww[ok]
                cost[bb, wo] = new[ok]
                pred[bb, wo] = v[ok]
                via[bb, wo] = d
            left = np.where(seen[b], np.inf, cost[b])
            nxt = np.argmin(left, axis=1)
            live[b[left[np.arange(b.size), nxt] == np.inf]] = False  # (cut off: no route)
            cur[b] = nxt
        for i in np.flatnonzero(cur == g).tolist():
            r, x = int(rows[i]), int(g[i])
            while x != c[i]:
                self.route[r, k, pred[i, x]] = via[i, x]
                x = int(pred[i, x])


def arc_extremes(tcost: np.ndarray) -> tuple[int, int]:
    """``(least, greatest)`` moves of the arcs between targets (``tcost`` of
    :func:`goals.target_neighbours`; ``(0, 0)`` without an arc)."""
    lengths = tcost[tcost >= 0]
    if not lengths.size:
        return 0, 0
    return int(lengths.min()), int(lengths.max())
