"""Robots that follow closed walks: the machinery shared by ``cyclic`` and ``partition``.

Each robot follows one closed walk (a cycle of cells, each a move from the next) and
heads for a *target* index on it. A robot on its target cell advances the target by
one; a robot elsewhere (displaced, back from charging, on its way to the walk) takes a
shortest path to its target cell. So after any detour a robot rejoins its walk where
it left it.

Two robots about to meet head-on exchange their walks and targets before they move:
each turns back and carries on with the other's plan. The cells they visit are the ones
they would have visited by passing through each other, and neither has to wait. Robots
whose tasks the world exchanges (a blocked holder of the right of way,
:func:`qpatrol.world.traffic.hand_on`) exchange their plans the same way. A robot
waits (held, or for its spacing) only on a target cell: on a patrol graph's waypoint it
travels on, and waits at the next vertex.

A target in the pocket of a charging station that another robot holds (see
:mod:`qpatrol.world.battery`) is skipped: the robot heads for the first cell of its walk past
the pocket, and patrols the pocket again on a later lap.

Distances. On a map of at most :data:`qpatrol.maps.core.TABLE_CELLS` cells the robots
read the ``[C, C]`` table (``dist``); on a larger one (``dist`` None) a robot next to its
target steps onto it, and a robot farther away reads its own row of moves to its target,
searched when its target changes (``goal_rows``: breadth-first from the target, kept per
robot): the same first moves, as the distances are the same.

Robots on one walk keep their spacing. Each robot's plan carries a *spacing*: how many
walk steps its target must stay behind the target of the next patrolling robot ahead on
the same walk (for ``cyclic`` the distance between their slots, about ``L / K``; a robot
alone on its walk, as in ``partition``, never waits). A robot on its target advances it
only if the target ahead is at least its spacing further along the walk; else it waits
there. So a robot that lost steps (a yield, a push, a head-on meeting, a battery trip)
is not run into by the robots behind: each of them waits the steps it lost, one after
the other, and the team regains its spacing within K steps, every robot the same number
of steps late. Targets compared are those before this step's advances; on a tie (two
targets on one index) the robot standing on its target cell counts as ahead, then the
robot of lower index.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.maps import bfs, core
from qpatrol.strategies import base
from qpatrol.world import traffic

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.world import Observation, Params


class WalkFollower(base.Strategy):
    """Robots on closed walks.

    Attributes:
        walk: int ``[R, W, Lmax]``, each run's walks' cells (padded by repeating the
            last); the same in every run but for a strategy that learns its walks.
        length: int ``[R, W]``, each walk's length in moves.
        wid: int ``[R, K]``, the walk each robot follows.
        target: int ``[R, K]``, the index on its walk the robot heads for.
        hold: bool ``[R, K]``, the robot waits on its target (e.g. for the team to
            gather) instead of advancing.
        spacing: int ``[R, K]``, the walk steps the robot's target keeps behind the
            target of the next robot ahead on its walk (set by the strategy with
            :meth:`start_spacing` once the targets are placed).
    """

    #: The spacing rule is on (a test switches it off to see the bound fail).
    keep_spacing: bool = True
    #: Robots about to meet head-on exchange plans before they move (a test switches
    #: it off: they then meet, and only exchange once they blocked each other).
    exchange_early: bool = True
    #: Robots that exchange plans before meeting exchange the ages of their tasks too, and
    #: a task handed to the robot standing on its aim ends (a test switches it off: a
    #: robot handed back plan after plan then shows no progress while its plans advance).
    ages_with_plans: bool = True
    #: Two robots with the same plan (walk and target) exchange nothing (a test switches
    #: it off: the holder, exchanging with a robot waiting on their common target, hands
    #: it the right of way at every step, and a crowded team freezes).
    skip_same_plans: bool = True
    plans_on_edges = True

    def __init__(
        self,
        cfg: Config,
        m: Map,
        p: Params,
        start_cells: np.ndarray,
        walks: list[np.ndarray],
    ):
        super().__init__(cfg, m, p, start_cells)
        self.dist = m.distances() if m.n_cells <= core.TABLE_CELLS else None
        # rows mode (no table): each robot's (goal, row of moves to it) last searched
        self.goal_rows: dict[tuple[int, int], tuple[int, np.ndarray]] = {}
        R = self.n_runs
        length = np.array([w.size for w in walks], dtype=np.int64)
        width = int(length.max())
        walk = np.stack([np.pad(w, (0, width - w.size), mode="edge") for w in walks])
        self.walk = np.repeat(walk[None], R, axis=0)
        self.length = np.repeat(length[None], R, axis=0)
        self.rows = np.arange(R)[:, None]
        self.wid = np.zeros((self.n_runs, self.n_agents), dtype=np.int64)
        self.target = np.zeros((self.n_runs, self.n_agents), dtype=np.int64)
        self.hold = np.zeros((self.n_runs, self.n_agents), dtype=bool)
        self.spacing = np.zeros((self.n_runs, self.n_agents), dtype=np.int64)

    def start_spacing(self) -> None:
        """Each robot's spacing: the walk steps from its target to the next target ahead
        on its walk (its walk's length when it is alone on it), as the targets are now."""
        self.spacing = self.gap_ahead(np.ones((self.n_runs, self.n_agents), dtype=bool))

    def gap_ahead(self, counted: np.ndarray, on: np.ndarray | None = None) -> np.ndarray:
        """int ``[R, K]``: walk steps from each robot's target forward to the nearest
        target of another ``counted`` robot (bool ``[R, K]``) on the same walk; the
        walk's length if none. On a tie (two targets on one index) the robot standing on
        its target cell is ahead (0 steps; ``on``: bool ``[R, K]``, None: none stands on
        it), and between two that both stand or both do not, the one of lower index."""
        L = self.lap()  # [R, K]
        ahead = (self.target[:, None, :] - self.target[:, :, None]) % L[:, :, None]  # [R, k, j]
        k = np.arange(self.n_agents)
        if on is None:
            on = np.zeros_like(counted)
        first = (on[:, None, :] & ~on[:, :, None]) | (
            (on[:, None, :] == on[:, :, None]) & (k[None, :] < k[:, None])[None]
        )  # [R, k, j]: j is ahead of k on a tie
        ahead = np.where((ahead == 0) & ~first, L[:, :, None], ahead)
        other = (
            (self.wid[:, None, :] == self.wid[:, :, None])
            & counted[:, None, :]
            & (k[None, :] != k[:, None])[None]
        )
        return np.where(other, ahead, L[:, :, None]).min(axis=-1)

    def planned_wait(self) -> np.ndarray:
        """int ``[R]``: per run, the longest walk that two robots or more share at the
        start (0: none does), with the spacing rule on. Robots bunched on a walk wait for
        the ones ahead to spread out, each leaving ``spacing`` walk steps after the one
        ahead: the last leaves within the walk's length of steps when the robots ahead
        move freely (docs/model.md, "What the theorem does not give")."""
        out = np.zeros(self.n_runs, dtype=np.int64)
        if not self.keep_spacing:
            return out
        lengths = self.start_lengths()
        for r in range(self.n_runs):
            walks, count = np.unique(self.wid[r], return_counts=True)
            shared = walks[count >= 2]
            if shared.size:
                out[r] = lengths[r, shared].max()
        return out

    def start_lengths(self) -> np.ndarray:
        """int ``[R, W]``: each walk's length at the start (walks that do not change:
        their length)."""
        return self.length

    def lap(self) -> np.ndarray:
        """int ``[R, K]``: the length of each robot's walk."""
        return self.length[self.rows, self.wid]

    def goal_cells(self) -> np.ndarray:
        """int ``[R, K]``: the cell each robot heads for."""
        return self.walk[self.rows, self.wid, self.target]

    def aims(self, obs: Observation) -> np.ndarray:
        """The cell each robot heads for (its target on its walk)."""
        return self.goal_cells()

    def exchange(self, swapped: np.ndarray) -> None:
        """Robots that exchanged tasks exchange plans: walks, targets and spacings."""
        for name in ("wid", "target", "spacing"):
            setattr(self, name, base.partners(getattr(self, name), swapped))

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        obs = base.walking(obs)
        self._advance(obs, obs.choosing)
        self._skip_held_pockets(obs)
        ask = self._asks(obs)
        if self.params.avoid_collisions and self.exchange_early:
            swapped = self._exchange_before_meeting(obs, ask)
            if swapped.any():
                self._advance(obs, swapped)
                self._skip_held_pockets(obs)
                ask = self._asks(obs)
        return ask

    def _advance(self, obs: Observation, mask: np.ndarray) -> None:
        """Robots of ``mask`` (bool ``[R, K]``) standing on their target advance it by one,
        unless held or (spacing rule) the next target ahead is nearer than their spacing;
        a robot waits only on a target cell (on a graph's waypoint it travels on whatever
        it asks, so it advances there: it waits at the next vertex)."""
        stay = self.hold.copy()
        if self.keep_spacing:
            on = obs.state.pos == self.goal_cells()
            stay |= self.gap_ahead(obs.choosing, on) < self.spacing
        stay &= self.params.target[obs.state.pos]
        advance = mask & obs.choosing & (obs.state.pos == self.goal_cells()) & ~stay
        self.target = np.where(advance, (self.target + 1) % self.lap(), self.target)

    def _asks(self, obs: Observation) -> np.ndarray:
        """int ``[R, K]``: each choosing robot's first move towards its target cell."""
        return np.where(obs.choosing, self.step_towards(obs.state.pos, self.goal_cells()), -1)

    def _exchange_before_meeting(self, obs: Observation, ask: np.ndarray) -> np.ndarray:
        """Two choosing robots each of whose next cell is the other's cell, and whose
        plans differ, swap walks, targets and spacings before they move, and their tasks go
        with the plans (:func:`qpatrol.world.traffic.exchange_plans`: the ages and the
        right of way; a task handed to the robot standing on its aim ends there), as if the
        two had passed through each other. Returns bool ``[R, K]``, the robots that swapped.

        A robot's next cell is the one it asks for, or for a robot waiting on its target
        the walk's cell after it."""
        pos = obs.state.pos
        after = self.walk[self.rows, self.wid, (self.target + 1) % self.lap()]
        waits = (ask < 0) & (pos == self.goal_cells())
        nxt = np.where(
            ask >= 0,
            self.params.neighbors[pos, np.maximum(ask, 0)],
            np.where(waits, after, -1),
        )
        nxt = np.where(obs.choosing, nxt, -1)
        k = np.arange(self.n_agents)
        meets = (nxt[:, :, None] == pos[:, None, :]) & (nxt[:, None, :] == pos[:, :, None])
        meets &= (k[:, None] < k[None, :])[None]  # [R, k, j], k < j
        # robots with the same plan have nothing to exchange (a test switches it off)
        if self.skip_same_plans:
            same = (self.wid[:, :, None] == self.wid[:, None, :]) & (
                self.target[:, :, None] == self.target[:, None, :]
            )
            meets &= ~same
        rr, kk, jj = np.nonzero(meets)
        swapped = np.zeros_like(obs.choosing)
        if rr.size == 0:
            return swapped
        for arr in (self.wid, self.target, self.spacing):
            arr[rr, kk], arr[rr, jj] = arr[rr, jj].copy(), arr[rr, kk].copy()
        swapped[rr, kk] = swapped[rr, jj] = True
        if self.ages_with_plans:  # the tasks go with the plans (the world's rule)
            traffic.exchange_plans(obs.state, rr, kk, jj)
        return swapped

    def _skip_held_pockets(self, obs: Observation) -> None:
        """Move targets that lie in another robot's held station pocket past it; at most
        one lap of the robot's walk, so a walk wholly in such a pocket keeps its target
        (and a second call changes nothing)."""
        p, s = self.params, obs.state
        if not p.battery or (p.pocket_of < 0).all():
            return
        me = np.arange(self.n_agents)[None, :]
        lap = self.lap()
        done = np.zeros_like(self.target)
        for _ in range(int(self.length.max())):
            h = p.pocket_of[self.goal_cells()]
            holder = s.reserved[np.arange(self.n_runs)[:, None], np.maximum(h, 0)]
            skip = obs.choosing & (h >= 0) & (holder >= 0) & (holder != me) & (done < lap)
            if not skip.any():
                return
            self.target = np.where(skip, (self.target + 1) % lap, self.target)
            done += skip

    def step_towards(self, pos: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """int ``[R, K]``: the first move of a shortest path (lowest port first: N, E, S, W
        on a grid); -1 there."""
        nbr = self.params.neighbors[pos]  # [R, K, D]
        if self.dist is None:
            return self._step_by_rows(pos, goal, nbr)
        d_next = self.dist[np.maximum(nbr, 0), goal[..., None]]
        closer = (nbr >= 0) & (d_next == self.dist[pos, goal][..., None] - 1)
        return np.where(closer.any(axis=-1), closer.argmax(axis=-1), -1)

    def _step_by_rows(self, pos: np.ndarray, goal: np.ndarray, nbr: np.ndarray) -> np.ndarray:
        """:meth:`step_towards` without the table: onto a neighbouring goal by its first
        port; else by the robot's row of moves to its goal (searched anew when the goal
        is not the one of its row)."""
        next_to = nbr == goal[..., None]
        out = np.where(next_to.any(axis=-1), next_to.argmax(axis=-1), -1)
        far = (pos != goal) & ~next_to.any(axis=-1)
        for r, k in zip(*np.nonzero(far), strict=True):
            g, c = int(goal[r, k]), int(pos[r, k])
            kept = self.goal_rows.get((r, k))
            if kept is not None and kept[0] == g:
                row = kept[1]
            else:
                row = bfs(self.params.neighbors, g)
                self.goal_rows[(r, k)] = (g, row)
            ok = (nbr[r, k] >= 0) & (row[np.maximum(nbr[r, k], 0)] == row[c] - 1)
            out[r, k] = int(ok.argmax()) if ok.any() else -1
        return out

    def __getstate__(self) -> dict:
        """The state a checkpoint keeps: not the rows, searched again on demand."""
        state = dict(vars(self))
        state["goal_rows"] = {}
        return state


def nearest_index(
    dist: np.ndarray | None, walk: np.ndarray, cell: int, neighbors: np.ndarray | None = None
) -> int:
    """The index of the walk cell nearest to ``cell`` (first such index); without a table
    (``dist`` None) by a search from ``cell`` over ``neighbors``."""
    row = bfs(neighbors, cell) if dist is None else dist[cell]
    return int(np.argmin(row[walk]))
