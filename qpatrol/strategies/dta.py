"""Dynamic task assignment (Farinelli, Iocchi, Nardi et al. 2017): ``dta-greedy``,
``dta-ssi`` and ``dta-ssi-part``, goal followers whose goal may be any target.

A robot chooses a goal when it has none or stands on it (:mod:`qpatrol.strategies.goals`
for travel and held pockets). Its candidates are the targets other than its own cell,
outside another robot's held pocket (battery on). Each candidate ``x`` has a utility
``U(x) = dta.theta_idleness x I(x) + theta_navigation x L(c, x)``
(``+ dta.greedy_origin x L(o, x)`` for ``dta-greedy``),
``I`` the idleness of x on the robot's group map (the team's shared map with
communication on), ``L`` moves along shortest paths, ``c`` the robot's cell, ``o`` the
cell it started on, in float64 in that order. The
robot takes the *allowed* candidate of greatest utility (every candidate when none is
allowed), ties to the j-th tied target in cell order, ``j = floor(u x ties)``:

- ``dta-greedy`` (patrolling_sim's ``DTAGreedy_Agent``): with communication on, a target
  another robot has as its goal is not allowed (the goals are exchanged; robots decide in
  robot order, so the goals chosen before in the same step count).
- ``dta-ssi`` (``DTASSI_Agent``, a sequential single-item auction held at once within
  the step): with communication on, a candidate is allowed when the robot wins its
  auction: every robot bids its path cost to it, 0 when it is that robot's goal, else
  ``L(c, x)`` for the auctioneer (it stands on its reached goal) and, for another robot
  j at ``p_j`` with goal ``g_j``, the insertion of x after its goal,
  ``L(p_j, g_j) + L(g_j, x)`` (``L(p_j, x)`` without one). The auctioneer wins when no
  other robot bids less (it keeps ties). Going down the candidates by utility and
  taking the first one won is the same as taking the best won one.

- ``dta-ssi-part`` (``DTASSIPart_Agent``): :class:`PartSSI`, auctions whose bids come
  from each robot's region (its won targets and their center).

With communication off every candidate is allowed: each robot is alone.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.strategies import goals
from qpatrol.world.battery import GONE

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.world import Observation, Params


class DTA(goals.GoalFollower):
    """``theta``: float ``[3]``, the utility's weights (idleness, navigation, origin);
    ``origin``: int ``[R, K]``, each robot's start cell."""

    neighbour_goals = False
    keeps_plans = True

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.origin = np.array(start_cells, dtype=np.int64)
        self.theta = np.array(self.weights(cfg), dtype=np.float64)

    def weights(self, cfg: Config) -> tuple[float, float, float]:
        """The utility's weights: idleness, navigation, distance from the origin."""
        raise NotImplementedError

    def utility(self, obs: Observation, k: int, rows: np.ndarray, c: np.ndarray) -> np.ndarray:
        """float64 ``[B, C]``: the utility of every cell as robot k's goal (on cells ``c``)."""
        n_cells = self.is_target.size
        cells = np.broadcast_to(np.arange(n_cells), (rows.size, n_cells))
        idle = self.idleness(obs, k, rows, cells).astype(np.float64)
        u = self.theta[0] * idle + self.theta[1] * self.dist[c].astype(np.float64)
        if self.theta[2] != 0.0:
            u = u + self.theta[2] * self.dist[self.origin[rows, k]].astype(np.float64)
        return u

    def allowed(self, obs: Observation, k: int, rows: np.ndarray, c: np.ndarray) -> np.ndarray:
        """bool ``[B, C]``: the cells robot k may take (with communication on)."""
        raise NotImplementedError

    def choose(
        self,
        obs: Observation,
        k: int,
        rows: np.ndarray,
        mask: np.ndarray,
        closed: np.ndarray,
        u: np.ndarray,
    ) -> np.ndarray:
        c, cells, cand = self.any_target(obs, k, rows)
        ok = cand
        if obs.params.communication and self.n_agents > 1:
            ok = cand & self.allowed(obs, k, rows, c)
            ok = np.where(ok.any(axis=1, keepdims=True), ok, cand)
        score = np.where(ok, self.utility(obs, k, rows, c), -np.inf)
        best = ok & (score == score.max(axis=1, keepdims=True))
        has = cand.any(axis=1)
        best[~has, 0] = True  # (no candidate: a placeholder, replaced by -1 below)
        return np.where(has, goals.pick_nth(best, u), -1)


class Greedy(DTA):
    """``dta-greedy``: the best target no other robot has as its goal."""

    name = "dta-greedy"

    def weights(self, cfg: Config) -> tuple[float, float, float]:
        return (
            float(cfg["dta.theta_idleness"]),
            float(cfg["dta.greedy_navigation"]),
            float(cfg["dta.greedy_origin"]),
        )

    def allowed(self, obs: Observation, k: int, rows: np.ndarray, c: np.ndarray) -> np.ndarray:
        others = np.delete(self.goal[rows], k, axis=1)  # [B, K - 1]
        cells = np.arange(self.is_target.size)
        return ~(cells[None, :, None] == others[:, None, :]).any(axis=2)


def bids(dist: np.ndarray, pos: np.ndarray, goal: np.ndarray, k: int, c: np.ndarray) -> np.ndarray:
    """int ``[B, K, C]``: each robot's bid for each cell in robot k's auction; ``pos``,
    ``goal``: int ``[B, K]`` the robots' cells and goals (-1: none), ``c`` ``[B]``: the
    auctioneer's cell."""
    g = np.maximum(goal, 0)
    via = dist[pos, g][:, :, None] + dist[g]  # [B, K, C]
    b = np.where((goal >= 0)[:, :, None], via, dist[pos])
    b = np.where(np.arange(dist.shape[0])[None, None, :] == goal[:, :, None], 0, b)
    b[:, k] = dist[c]
    return b


class SSI(DTA):
    """``dta-ssi``: the best target whose auction the robot wins."""

    name = "dta-ssi"

    def weights(self, cfg: Config) -> tuple[float, float, float]:
        return (float(cfg["dta.theta_idleness"]), float(cfg["dta.ssi_navigation"]), 0.0)

    def allowed(self, obs: Observation, k: int, rows: np.ndarray, c: np.ndarray) -> np.ndarray:
        b = bids(self.dist, obs.state.pos[rows], self.goal[rows], k, c)
        gone = obs.state.mode[rows] == GONE  # a robot that failed bids nothing
        b = np.where(gone[:, :, None], np.iinfo(np.int64).max, b)
        others = np.delete(b, k, axis=1).min(axis=1)  # [B, C]
        return b[:, k] <= others


def center_of(dist: np.ndarray, here: int, tasks: np.ndarray) -> int:
    """The cell among ``here`` and ``tasks`` (int ``[T]``, in cell order) of least sum of
    moves to the tasks (``here`` first, then the first in cell order, on a tie)."""
    best, best_sum = here, int(dist[here, tasks].sum())
    if tasks.size:
        sums = dist[np.ix_(tasks, tasks)].sum(axis=1)
        i = int(np.argmin(sums))
        if sums[i] < best_sum:
            best = int(tasks[i])
    return best


class PartSSI(DTA):
    """``dta-ssi-part``: auctions with bids from each robot's region.

    Attributes:
        owner: int ``[R, C]``, the robot whose bid for a target won its last auction
            (-1: never auctioned); a robot's *tasks* are the targets it owns.
        center: int ``[R, K]``, each robot's center (its start cell at first).
    """

    name = "dta-ssi-part"
    numpy_cell_us = 0.63  # (base.Strategy.numpy_cell_us)

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.owner = np.full((self.n_runs, self.is_target.size), -1, dtype=np.int64)
        self.center = np.array(start_cells, dtype=np.int64)

    def weights(self, cfg: Config) -> tuple[float, float, float]:
        return (float(cfg["dta.theta_idleness"]), float(cfg["dta.ssi_navigation"]), 0.0)

    def part_bids(self, r: int, x: int, gone: np.ndarray) -> np.ndarray:
        """int ``[K]``: each robot's bid for target x in run r: 0 for its goal, else the
        moves from its center to x times one more than its tasks; none (the largest
        int) from a robot that failed (``gone`` bool ``[K]``)."""
        tasks = np.bincount(np.maximum(self.owner[r], 0), self.owner[r] >= 0, self.n_agents)
        b = self.dist[self.center[r], x] * (tasks.astype(np.int64) + 1)
        return np.where(gone, np.iinfo(np.int64).max, np.where(self.goal[r] == x, 0, b))

    def award(self, r: int, x: int, winner: int, pos: np.ndarray) -> None:
        """Target x of run r goes to ``winner``; the centers of the robots whose tasks
        changed (the winner, the previous owner) are computed again."""
        before = int(self.owner[r, x])
        self.owner[r, x] = winner
        if before == winner:
            return
        for j in (winner, before) if before >= 0 else (winner,):
            tasks = np.flatnonzero(self.owner[r] == j)
            self.center[r, j] = center_of(self.dist, int(pos[j]), tasks)

    def choose(
        self,
        obs: Observation,
        k: int,
        rows: np.ndarray,
        mask: np.ndarray,
        closed: np.ndarray,
        u: np.ndarray,
    ) -> np.ndarray:
        s = obs.state
        c, cells, cand = self.any_target(obs, k, rows)
        n_cells = self.is_target.size
        util = self.utility(obs, k, rows, c)
        auction = obs.params.communication and self.n_agents > 1
        out = np.full(rows.size, -1, dtype=np.int64)
        for b, r in enumerate(rows.tolist()):
            xs = np.flatnonzero(cand[b])
            if not xs.size:
                continue
            o = min(int(u[b] * n_cells), n_cells - 1)
            order = xs[np.lexsort(((xs - o) % n_cells, -util[b, xs]))]
            out[b] = order[0]
            if not auction:
                continue
            pos = s.pos[r]
            gone = s.mode[r] == GONE
            for x in order.tolist():
                bid = self.part_bids(r, x, gone)
                others = np.delete(bid, k)
                winner = k if bid[k] <= others.min() else int(np.argmin(np.where(
                    np.arange(self.n_agents) == k, np.iinfo(np.int64).max, bid)))  # fmt: skip
                self.award(r, x, winner, pos)
                if winner == k:
                    out[b] = x
                    break
        return out
