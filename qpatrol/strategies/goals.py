"""Robots that choose a goal *target* and travel to it: ``hcr``, ``cc``, ``gbs``, ``sebs``.

The machinery shared by the four strategies ported from patrolling_sim (Portugal and
Rocha's ROS patrol simulator). They decide at targets (every cell of a grid, the
vertices of a graph) and travel between them:

1. *Goal.* A patrolling robot chooses a goal when it has none or stands on it, and a
   robot of a *neighbour-goal* strategy (``hcr``, ``gbs``, ``sebs``) also whenever it
   stands on a target that is not its goal (its first move out was blocked, or it was
   pushed there). A neighbour-goal strategy takes one of the targets at the other end
   of its cell's ports (on a grid the neighbouring cells, on a graph the vertices at
   the far end of its edges), scored by the strategy (:meth:`GoalFollower.scores`), among
   the ports that are open (every port when none is); ``cc`` takes any target. Ties go
   to the j-th tied candidate in port (cell) order, ``j = floor(u x ties)``, ``u`` the
   robot's tie-break uniform of the step. A robot of a neighbour-goal strategy that has
   to choose off a target (it starts on a graph's waypoint) heads for the nearest target
   (lowest cell number on a tie).
2. *Held pockets.* A goal in the pocket of a station another robot holds is dropped
   and chosen again, and no such target is chosen.
3. *Travel.* Each step the robot asks for the lowest open port on a shortest path to
   its goal; if no such port is open it *insists* on the lowest port on a shortest path
   (never deeper into another robot's held pocket). Insisting is what gets a robot
   through a one-wide corridor another robot comes down the other way: it is blocked,
   gets the right of way and pushes (docs/model.md, "Movement, collisions and
   charging"); the liveness theorem, for strategies that choose among open moves, does
   not cover it.

Decisions are made robot by robot in robot order (``sebs`` reads the goals the robots
before it chose in the same step).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import numpy as np

from qpatrol.maps.core import far_targets
from qpatrol.strategies import base
from qpatrol.world import battery

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.world import Observation, Outcome, Params


def remember(memory: np.ndarray, goal: np.ndarray, out: Outcome) -> None:
    """An own record of visits (``cc``, ``hpcc``; ``memory`` int ``[R, K, C]``, in place):
    each robot that entered a cell at step ``out.t`` remembers it, and one that handed its
    goal on (its partner's goal in ``goal`` ``[R, K]`` now) counts that goal as served."""
    rr, kk = np.nonzero(out.moved)
    memory[rr, kk, out.pos[rr, kk]] = out.t
    if out.swapped is not None:
        rr, kk = np.nonzero(out.swapped >= 0)
        handed = goal[rr, out.swapped[rr, kk]]
        ok = handed >= 0
        memory[rr[ok], kk[ok], handed[ok]] = out.t


def target_neighbours(m: Map) -> tuple[np.ndarray, np.ndarray]:
    """``(tnbr, tcost)``, int ``[C, D]`` each: for a target c and port d, the target at the
    far end of the way out of c by d (through waypoints, which are not targets) and its
    length in moves; -1 (both) where c is not a target, d has no move, or the way ends
    in a dead end before a target."""
    return far_targets(m.neighbors, m.back, m.target)


def pick_nth(cand: np.ndarray, u: np.ndarray) -> np.ndarray:
    """int ``[B]``: the ``floor(u x n)``-th True column of each row of ``cand`` bool
    ``[B, N]`` (n its True entries, at least one), in column order."""
    count = cand.sum(axis=1)
    j = np.minimum((u * count).astype(np.int64), count - 1)
    rank = np.cumsum(cand, axis=1) - 1
    return np.argmax(cand & (rank == j[:, None]), axis=1)


class GoalFollower(base.Strategy):
    """Robots with a goal target.

    Attributes:
        dist: int ``[C, C]``, moves between cells.
        is_target: bool ``[C]``, the map's targets.
        tnbr, tcost: int ``[C, D]``, :func:`target_neighbours`.
        goal: int ``[R, K]``, each robot's goal target (-1: none yet).
    """

    #: The goal is a neighbouring target (else any target).
    neighbour_goals: ClassVar[bool] = True

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.dist = m.distances()
        self.is_target = m.target.copy()
        self.tnbr, self.tcost = target_neighbours(m)
        self.goal = np.full((self.n_runs, self.n_agents), -1, dtype=np.int64)

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
            if self.neighbour_goals:
                need |= ch & self.is_target[c]
            if need.any():
                r = rows[need]
                g[need] = self.choose(obs, k, r, mask[r, k], closed[r, k], u[r, k, 1])
            self.goal[:, k] = g
            ask[:, k] = np.where(ch, self.travel(c, g, ports[:, k], mask[:, k], closed[:, k]), -1)
        return ask

    def aims(self, obs: Observation) -> np.ndarray:
        """Each robot's goal (the world's ``State.aim`` of a choosing robot)."""
        return self.goal.copy()

    def exchange(self, swapped: np.ndarray) -> None:
        """Robots that exchanged tasks exchange goals."""
        self.goal = base.partners(self.goal, swapped)

    def any_target(self, obs: Observation, k: int, rows: np.ndarray) -> tuple:
        """The goals robot k may take anywhere (``cc`` and the task-assignment strategies):
        ``(cell [B], cells [B, C], cand bool [B, C])``, ``cand`` every target but the
        robot's own cell and, with the battery, those in a pocket another robot holds."""
        c = obs.state.pos[rows, k]
        n_cells = self.is_target.size
        cells = np.broadcast_to(np.arange(n_cells), (rows.size, n_cells))
        cand = self.is_target[None, :] & (cells != c[:, None])
        if obs.params.battery:
            cand &= ~self.held_by_other(obs.state, obs.params, rows, k, cells)
        return c, cells, cand

    def held_by_other(
        self, s: object, p: Params, rows: np.ndarray, k: int, cells: np.ndarray
    ) -> np.ndarray:
        """bool, the shape of ``cells`` (int, one per row of ``rows``; -1 allowed): the cell
        lies in the pocket of a station a robot other than k holds."""
        h = p.pocket_of[np.maximum(cells, 0)]
        holder = s.reserved[rows.reshape(rows.shape + (1,) * (cells.ndim - 1)), np.maximum(h, 0)]
        return (cells >= 0) & (h >= 0) & (holder >= 0) & (holder != k)

    def choose(
        self,
        obs: Observation,
        k: int,
        rows: np.ndarray,
        mask: np.ndarray,
        closed: np.ndarray,
        u: np.ndarray,
    ) -> np.ndarray:
        """int ``[B]``: the new goal of robot k in runs ``rows`` (``[B]``); ``mask``,
        ``closed``: bool ``[B, D]``, its open (or every legal) moves and the moves deeper
        into another robot's held pocket; ``u`` ``[B]``: its tie-break uniforms."""
        s = obs.state
        c = s.pos[rows, k]
        out = np.full(rows.size, -1, dtype=np.int64)
        on = self.is_target[c]
        if (~on).any():  # off a target: the nearest target outside held pockets
            b = np.flatnonzero(~on)
            cells = np.broadcast_to(np.arange(self.is_target.size), (b.size, self.is_target.size))
            ok = self.is_target[None, :] & ~self.held_by_other(s, obs.params, rows[b], k, cells)
            d = np.where(ok, self.dist[c[b]], np.iinfo(np.int64).max)
            out[b] = np.where(ok.any(axis=1), np.argmin(d, axis=1), -1)
        b = np.flatnonzero(on)
        if b.size:
            cand = self.tnbr[c[b]] >= 0
            allowed = cand & mask[b] & ~closed[b]
            fallback = cand & ~closed[b]
            allowed = np.where(allowed.any(axis=1, keepdims=True), allowed, fallback)
            allowed = np.where(allowed.any(axis=1, keepdims=True), allowed, cand)
            score = self.scores(obs, k, rows[b], c[b], allowed)
            masked = np.where(allowed, score, -np.inf)
            best = allowed & (masked == masked.max(axis=1, keepdims=True))
            d = pick_nth(best, u[b])
            out[b] = self.tnbr[c[b], d]
        return out

    def scores(
        self, obs: Observation, k: int, rows: np.ndarray, c: np.ndarray, allowed: np.ndarray
    ) -> np.ndarray:
        """float ``[B, D]``: the score of each port's far target (the greatest is chosen);
        ``allowed`` bool ``[B, D]``: the candidate ports."""
        raise NotImplementedError

    def idleness(self, obs: Observation, k: int, rows: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """int, the shape of ``cells``: ``t`` minus the last visit on robot k's group map
        (the team's shared map with communication on)."""
        g = 0 if obs.params.communication else k
        last = obs.state.last[rows.reshape(rows.shape + (1,) * (cells.ndim - 1)), g, cells]
        return obs.t - last

    def travel(
        self,
        c: np.ndarray,
        g: np.ndarray,
        ports: np.ndarray,
        mask: np.ndarray,
        closed: np.ndarray,
    ) -> np.ndarray:
        """int ``[R]``: the port asked for by a robot on cells ``c`` with goals ``g``: the
        lowest open port on a shortest path, else the lowest such port not deeper into a
        held pocket (insisting); -1 on its goal or without one. ``ports``, ``mask``,
        ``closed``: ``[R, D]``."""
        gg = np.maximum(g, 0)[:, None]
        here = self.dist[c, np.maximum(g, 0)][:, None]
        on_path = (ports >= 0) & (self.dist[np.maximum(ports, 0), gg] == here - 1)
        on_path &= ((g >= 0) & (g != c))[:, None] & ~closed
        best = on_path & mask
        use = np.where(best.any(axis=1, keepdims=True), best, on_path)
        return np.where(use.any(axis=1), np.argmax(use, axis=1), -1)
