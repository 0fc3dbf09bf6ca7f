"""``qlearning-idleness``: Q-learning paid the idleness of the cell entered (beyond the paper).

In the spirit of Santana, Ramalho, Corruble and Ratitch (AAMAS 2004): tabular
Q-learning patrol agents rewarded with the idleness of the cell they reach, with
idleness information in their state. Not the paper's model (that is ``qlearning``,
untouched); every key is ``qidle.*``.

State ``(cell, heading, idlest)``: ``heading`` is the direction of the move that
brought the robot to its cell (as in ``qlearning``; on a patrol graph the port it
arrived through), ``idlest`` the port (direction, on a grid) of the robot's non-wall
neighbour visited longest ago on its last-visit map (the team's shared map with
communication on, its own otherwise), first in port order (N, E, S, W) on a tie. On a
patrol graph robots decide at vertices only, and every neighbour read (``idlest``,
``r(s, a)``) is the vertex at the port's far end; a transition runs from the decision
at a vertex to the arrival at the next, paid on entering it (``qlearning``'s rule).
``qidle.state`` drops a part (ablations): ``cell_heading``, ``cell_idle``.

Reward of entering ``s'`` at team step ``t`` (``qidle.reward``):

* ``idleness``: ``min(cap, idle(s') / scale)``, ``idle(s') = t - last visit of s'`` on
  the robot's last-visit map before this visit (a cell never entered counts as visited
  at step 0), ``scale = cells / robots`` (the revisit interval of an ideal even patrol),
  ``cap = qidle.reward_cap``;
* ``dot``: the dot value of ``s'`` if its dot is still there (ablation).

Known reward (``qidle.known_reward``, default on). The reward of each move is on the
maps before the move is made, so the robot chooses ``argmax_a r(s, a) + Q(s, a)`` and
``Q`` learns the value *after* the move (an afterstate value). For every robot that
chose a move and made it, ``s -a-> s'``, in robot order (a shared entry sees every
update)::

    N(s,a) <- N(s,a) + 1;  alpha = qidle.alpha, or 1 / N(s,a) when qidle.alpha = 0
    Q(s,a) <- Q(s,a) + alpha * (gamma * max_{a'} [r(s', a') + Q(s', a')] - Q(s,a))

with ``a'`` over the non-wall moves of ``s'`` and ``r(s', a')`` read on the maps after
the whole team's step (what the robot sees when it next chooses). With
``qidle.known_reward: off`` it is plain Q-learning: the choice is ``argmax_a Q(s, a)``
and ``Q(s,a) <- Q(s,a) + alpha * (r + gamma * max_{a'} Q(s', a') - Q(s,a))`` with the
reward ``r`` the robot was paid.

Choice among the open moves (as ``qlearning``), ties broken by the run's stream; with
probability ``epsilon(t) = qidle.epsilon x max(0, 1 - t / qidle.explore_steps)`` a
uniformly random open move. With ``qidle.share`` and communication on the team keeps
one table (every robot learns into and acts on it), otherwise each robot has its own.
The table starts at ``qidle.q_init`` everywhere.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.measures.records import update_cols
from qpatrol.strategies import base, learner

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.measures.records import Recorder
    from qpatrol.world import Observation, Outcome, Params

#: ``qidle.state`` -> (uses heading, uses the idlest-neighbour feature)
STATES = {
    "cell_heading_idle": (True, True),
    "cell_heading": (True, False),
    "cell_idle": (False, True),
}


def idlest(last: np.ndarray, cells: np.ndarray, neighbors: np.ndarray) -> np.ndarray:
    """int ``[...]``: port of the non-wall neighbour of ``cells`` visited longest ago.

    Args:
        last: int ``[..., C]``, the last-visit map each entry of ``cells`` reads.
        cells: int ``[...]``.
        neighbors: int ``[C, D]``, -1 for a wall.

    Ties go to the first port (N, E, S, W order on a grid; deterministic, not random:
    the feature is part of the state).
    """
    nb = neighbors[cells]  # [..., D]
    seen = np.take_along_axis(last, np.maximum(nb, 0).reshape(*cells.shape, nb.shape[-1]), axis=-1)
    seen = np.where(nb >= 0, seen, np.iinfo(np.int64).max)
    return seen.argmin(axis=-1)


def td_step(
    q_sa: float,
    n_sa: int,
    reward: float,
    q_next: np.ndarray,
    legal_next: np.ndarray,
    gamma: float,
    alpha: float,
) -> tuple[float, int]:
    """One update of ``Q(s,a)`` (scalar form, used by the tests as the reference).

    Returns ``(q_after, n_after)``; ``alpha = 0`` means ``1 / n_after``.
    """
    n_after = n_sa + 1
    a = alpha if alpha > 0 else 1.0 / n_after
    best = max(float(q_next[b]) for b in range(len(q_next)) if legal_next[b])
    return q_sa + a * (reward + gamma * best - q_sa), n_after


class Strategy(base.Strategy):
    """Tabular Q-learning over ``(cell, heading, idlest)``; ``q``, ``n``:
    ``[R, P, C, H, F, D]`` with ``P`` tables per run (1 shared, or one per robot),
    ``H`` D headings (1 without), ``F`` D idlest ports (1 without); ``D`` = 4 on a grid."""

    name = "qlearning-idleness"
    learns = True
    per_run = ("q", "n", "last", "dots", "feat", "pending")

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.gamma = float(cfg["qidle.gamma"])
        self.alpha = float(cfg["qidle.alpha"])
        self.epsilon = float(cfg["qidle.epsilon"])
        self.explore_steps = int(cfg["qidle.explore_steps"])
        self.reward_kind = cfg["qidle.reward"]
        self.known = bool(cfg["qidle.known_reward"])
        self.cap = float(cfg["qidle.reward_cap"])
        self.scale = p.n_cells / p.n_agents
        self.use_heading, self.use_idle = STATES[cfg["qidle.state"]]
        self.shared = bool(cfg["qidle.share"]) and p.communication
        planes = 1 if self.shared else p.n_agents
        d = m.n_ports
        shape = (
            self.n_runs,
            planes,
            p.n_cells,
            d if self.use_heading else 1,
            d if self.use_idle else 1,
            d,
        )
        self.q = np.full(shape, float(cfg["qidle.q_init"]))
        self.n = np.zeros(shape, dtype=np.int32)  # a count never exceeds 10**9 (steps)
        g = p.n_groups
        # the last-visit and dot maps of every group, kept from the outcomes (= the world's)
        self.last = np.zeros((self.n_runs, g, p.n_cells), dtype=np.int64)
        self.dots = np.broadcast_to(p.has_dot, (self.n_runs, g, p.n_cells)).copy()
        self.feat = np.zeros((self.n_runs, self.n_agents), dtype=np.int64)
        # int64 [R, K, 4]: each robot's decision travelling a graph's edge (cell,
        # heading, idlest slot, port) until the next vertex; -1: none
        self.pending = np.full((self.n_runs, self.n_agents, 4), -1, dtype=np.int64)

    # --- state encoding ------------------------------------------------------------------

    def plane(self) -> np.ndarray:
        """int ``[K]``: the table each robot uses."""
        return np.zeros(self.n_agents, np.int64) if self.shared else np.arange(self.n_agents)

    def group(self) -> np.ndarray:
        """int ``[K]``: the last-visit map each robot reads."""
        k = self.n_agents
        return np.zeros(k, np.int64) if self.params.communication else np.arange(k)

    def features(self, cells: np.ndarray) -> np.ndarray:
        """int ``[R, K]``: the idlest-neighbour slot of robots standing on ``cells``."""
        if not self.use_idle:
            return np.zeros_like(cells)
        maps = self.last[:, self.group()]  # [R, K, C]
        return idlest(maps, cells, self.params.far_cells)

    def heading_slot(self, head: np.ndarray) -> np.ndarray:
        return head if self.use_heading else np.zeros_like(head)

    def epsilon_at(self, t: int) -> float:
        """The exploration probability at team step ``t``."""
        if self.explore_steps <= 0:
            return 0.0
        return self.epsilon * max(0.0, 1.0 - t / self.explore_steps)

    def reward_of(self, cells: np.ndarray, groups: np.ndarray, rows: np.ndarray, t: int):
        """float: the reward of entering ``cells`` at team step ``t`` (maps as they stand)."""
        if self.reward_kind == "dot":
            return np.where(self.dots[rows, groups, cells], self.params.dot_value[cells], 0.0)
        return np.minimum(self.cap, (t - self.last[rows, groups, cells]) / self.scale)

    def known_rewards(self, cells: np.ndarray, t: int) -> np.ndarray:
        """float ``[R, K, D]``: the reward each move out of ``cells`` would earn at step
        ``t`` (0 without ``qidle.known_reward``; walls: 0, never chosen)."""
        if not self.known:
            return np.zeros((*cells.shape, self.params.neighbors.shape[1]))
        nb = np.maximum(self.params.far_cells[cells], 0)  # [R, K, D]
        rows = np.arange(self.n_runs)[:, None, None]
        return self.reward_of(nb, self.group()[None, :, None], rows, t)

    # --- acting and learning -------------------------------------------------------------

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        s = obs.state
        R, K = s.pos.shape
        self.feat = self.features(s.pos)
        rows = np.arange(R)[:, None]
        q_row = self.q[rows, self.plane()[None, :], s.pos, self.heading_slot(s.head), self.feat]
        score = q_row + self.known_rewards(s.pos, obs.t)
        d = score.shape[-1]
        action, can = learner.choose(
            score.reshape(-1, d),
            base.prefer_open(obs).reshape(-1, d),
            u[..., 0].reshape(-1),
            u[..., 1].reshape(-1),
            self.epsilon_at(obs.t),
        )
        return np.where(can, action, -1).reshape(R, K)

    def rewards(self, out: Outcome) -> np.ndarray:
        """float ``[R, K]``: each robot's reward this step (0 where it did not move);
        updates the last-visit and dot maps, robot by robot as the world does."""
        reward = np.zeros(out.moved.shape)
        groups = self.group()
        for k in range(self.n_agents):
            rows = np.flatnonzero(out.moved[:, k])
            if rows.size == 0:
                continue
            c = out.pos[rows, k]
            g = np.full(rows.size, groups[k])
            reward[rows, k] = self.reward_of(c, g, rows, out.t)
            self.last[rows, g, c] = out.t
            self.dots[rows, g, c] = False
        ends = out.episodes
        if ends.runs.size:  # a new episode: every dot back
            self.dots[ends.runs, ends.groups] = self.params.has_dot
        return reward

    def learn(self, out: Outcome, rec: Recorder | None = None) -> None:
        reward = self.rewards(out)
        p = self.params
        # the decision of each transition: this step's (every cell decides) or, on a
        # graph with waypoints, the one taken at the vertex the robot left
        start = np.stack([out.prev_pos, out.prev_head, self.feat, out.ask], axis=-1)
        if p.onward is None:
            learns = out.choosing & out.as_asked
        else:
            rr, kk, done = learner.pending_transitions(self.pending, out, p.target, start[..., :3])
            learns = np.zeros(out.moved.shape, dtype=bool)
            learns[rr, kk] = True
            start[rr, kk] = done
        if not learns.any():
            return
        cb = out.pos
        next_feat = self.features(cb)
        next_known = self.known_rewards(cb, out.t + 1)  # [R, K, D]
        ha = self.heading_slot(start[..., 1])
        # the heading after the move (Map.entry: the move's direction on a grid)
        hb = self.heading_slot(p.entry[out.prev_pos, np.maximum(out.ask, 0)])
        planes = self.plane()
        # with the reward known before the move, Q is the value after it: no r in the target
        paid = 0.0 if self.known else 1.0
        for k in range(self.n_agents):  # in robot order: a shared entry sees every update
            rr = np.flatnonzero(learns[:, k])
            if rr.size == 0:
                continue
            pk = planes[k]
            ca, fa, aa = start[rr, k, 0], start[rr, k, 2], start[rr, k, 3]
            c2 = cb[rr, k]
            q_next = self.q[rr, pk, c2, hb[rr, k], next_feat[rr, k]] + next_known[rr, k]
            target, bootstrap = learner.td_target(
                paid * reward[rr, k], q_next, p.wall_legal[c2], self.gamma
            )
            idx = (rr, pk, ca, ha[rr, k], fa, aa)
            q_before = self.q[idx]
            q_after, n_after, alpha = learner.update(q_before, self.n[idx], target, self.alpha)
            self.q[idx] = q_after
            self.n[idx] = n_after
            if rec is not None and rec.wants_updates:
                hk, rk, dot, q_row = (
                    ha[rr, k],
                    reward[rr, k],
                    out.eaten[rr, k],
                    self.q[rr, pk, ca, ha[rr, k], fa],
                )
                cols = update_cols(
                    ca, hk, aa, rk, c2, hb[rr, k], alpha, q_before, q_after, bootstrap, dot, q_row
                )
                rec.updates(out.t, rr, np.full(rr.size, k), cols)

    def tables(self) -> dict[str, np.ndarray]:
        return {"q": self.q, "n": self.n.astype(np.int64)}

    def describe(self) -> dict[str, object]:
        return {"shared_table": self.shared, "state": self.cfg["qidle.state"]}
