"""Robots that follow closed walks: the machinery shared by ``cyclic`` and ``partition``.

Each robot follows one closed walk (a cycle of cells, each a move from the next) and
heads for a *target* index on it. A robot on its target cell advances the target by
one; a robot elsewhere (displaced, back from charging, on its way to the walk) takes a
shortest path to its target cell. So after any detour a robot rejoins its walk where
it left it.

Two robots blocking each other head-on exchange their walks and targets: each turns
back and carries on with the other's plan. The cells they visit are the ones they
would have visited by passing through each other, and neither has to wait.

A target in the pocket of a charging station that another robot holds (see
:mod:`qpatrol.world.battery`) is skipped: the robot heads for the first cell of its walk past
the pocket, and patrols the pocket again on a later lap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.strategies import base

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.measures.records import Recorder
    from qpatrol.world import Observation, Outcome, Params


class WalkFollower(base.Strategy):
    """Robots on closed walks.

    Attributes:
        walk: int ``[W, Lmax]``, the walks' cells (padded by repeating the last).
        length: int ``[W]``, each walk's length in moves.
        wid: int ``[R, K]``, the walk each robot follows.
        target: int ``[R, K]``, the index on its walk the robot heads for.
        hold: bool ``[R, K]``, the robot waits on its target (e.g. for the team to
            gather) instead of advancing.
    """

    def __init__(
        self,
        cfg: Config,
        m: Map,
        p: Params,
        start_cells: np.ndarray,
        walks: list[np.ndarray],
    ):
        super().__init__(cfg, m, p, start_cells)
        self.dist = m.distances()
        self.length = np.array([w.size for w in walks], dtype=np.int64)
        width = int(self.length.max())
        self.walk = np.stack([np.pad(w, (0, width - w.size), mode="edge") for w in walks])
        self.wid = np.zeros((self.n_runs, self.n_agents), dtype=np.int64)
        self.target = np.zeros((self.n_runs, self.n_agents), dtype=np.int64)
        self.hold = np.zeros((self.n_runs, self.n_agents), dtype=bool)
        self.blocked_by = np.full((self.n_runs, self.n_agents), -1, dtype=np.int64)

    def goal_cells(self) -> np.ndarray:
        """int ``[R, K]``: the cell each robot heads for."""
        return self.walk[self.wid, self.target]

    def _exchange_head_on(self, choosing: np.ndarray) -> None:
        """Robots that blocked each other last step swap walks and targets."""
        bb = self.blocked_by
        R, K = bb.shape
        rows = np.arange(R)[:, None]
        other = np.maximum(bb, 0)
        mutual = (bb >= 0) & (bb[rows, other] == np.arange(K)[None, :]) & choosing
        mutual &= choosing[rows, other] & (np.arange(K)[None, :] < bb)
        rr, kk = np.nonzero(mutual)
        if rr.size == 0:
            return
        jj = bb[rr, kk]
        for arr in (self.wid, self.target):
            arr[rr, kk], arr[rr, jj] = arr[rr, jj].copy(), arr[rr, kk].copy()

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        s = obs.state
        self._exchange_head_on(obs.choosing)
        goal = self.goal_cells()
        advance = obs.choosing & (s.pos == goal) & ~self.hold
        self.target = np.where(advance, (self.target + 1) % self.length[self.wid], self.target)
        self._skip_held_pockets(obs)
        goal = self.goal_cells()
        return np.where(obs.choosing, self.step_towards(s.pos, goal), -1)

    def _skip_held_pockets(self, obs: Observation) -> None:
        """Move targets that lie in another robot's held station pocket past it."""
        p, s = self.params, obs.state
        if not p.battery or (p.pocket_of < 0).all():
            return
        me = np.arange(self.n_agents)[None, :]
        for _ in range(int(self.length.max())):
            h = p.pocket_of[self.goal_cells()]
            holder = s.reserved[np.arange(self.n_runs)[:, None], np.maximum(h, 0)]
            skip = obs.choosing & (h >= 0) & (holder >= 0) & (holder != me)
            if not skip.any():
                return
            self.target = np.where(skip, (self.target + 1) % self.length[self.wid], self.target)

    def step_towards(self, pos: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """int ``[R, K]``: the first move of a shortest path (N, E, S, W first); -1 there."""
        nbr = self.params.neighbors[pos]  # [R, K, 4]
        d_next = self.dist[np.maximum(nbr, 0), goal[..., None]]
        closer = (nbr >= 0) & (d_next == self.dist[pos, goal][..., None] - 1)
        return np.where(closer.any(axis=-1), closer.argmax(axis=-1), -1)

    def learn(self, out: Outcome, rec: Recorder | None = None) -> None:
        self.blocked_by = out.blocked_by


def nearest_index(dist: np.ndarray, walk: np.ndarray, cell: int) -> int:
    """The index of the walk cell nearest to ``cell`` (first such index)."""
    return int(np.argmin(dist[cell, walk]))
