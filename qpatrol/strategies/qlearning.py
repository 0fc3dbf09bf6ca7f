"""``qlearning``: the paper's learner (Hernandez et al. §3-§4), one Q-table per robot.

State ``(cell, heading)``, heading being the direction of the move that brought the
robot to its cell (``learning.state_space: cell`` drops it); on a patrol graph the
port of its cell it arrived through (:attr:`qpatrol.maps.Map.entry`), so a graph's
table has D heading slots and D moves. The robot acts greedily
over its open moves (moves into walls are never choices; moves into cells where
another robot stands are avoided while an open move exists), ties broken by the run's
stream, with an optional ``learning.epsilon`` of uniformly random moves. After a move
it chose and made, ``s -a-> s'`` with the world's reward ``r``::

    N(s,a) <- N(s,a) + 1;  alpha = 1 / N(s,a)
    Q(s,a) <- Q(s,a) + alpha * (r + gamma * max_{a' not into a wall} Q(s',a') - Q(s,a))

A robot that waits, is pushed aside, or moves home does not update.

On a patrol graph a robot decides at vertices only (the world carries it along an
edge's waypoints): the state is ``(vertex, port arrived by)`` and a transition runs
from the decision at ``v`` (action: a port) to the arrival at the next vertex ``v'``,
paid the reward of entering ``v'`` (waypoints are not states and pay nothing). The
decision waits in ``pending`` until then; it is dropped without an update when the
robot is pushed, goes home, fails or its run ends. With unit edges (and on a grid)
every transition completes in the step of its decision, as above. The initial
table is ``q_init x multiplier`` for every state (North 3, West 2, East 2, South 1); on
a patrol graph, whose ports have no compass direction, every move starts at
``multiplier x`` the largest ``q_init``.

Tables kept lazily (``learning.table``): a robot's table has a row (its ``D x D``
values for one cell) for every cell it has chosen a move in or entered by a move it
chose, and only those. Above
:data:`~qpatrol.world.limits.LAZY_BYTES` of dense tables per run (``auto``; 512
robots on 100,000 cells would need 10 GB) a robot keeps ``min(C, steps + 2)`` rows,
given out in the order it first reads them (``slot``); a row starts at the
initial values, which is what the dense table holds for every cell not yet read,
so the values read and written are the same and so is every result. A robot reads
only the rows of cells it stands in (its choice) or has just entered (the target of
its update), at most one new one a step.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.maps import DIRECTIONS
from qpatrol.measures.records import update_cols
from qpatrol.strategies import base, learner
from qpatrol.util.arrays import at, flat, take_rows
from qpatrol.world import limits, per_row

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.measures.records import Recorder
    from qpatrol.world import Observation, Outcome, Params


class Strategy(base.Strategy):
    """Tabular Q-learning; ``q`` (float64) and ``n`` are ``[R, K, M, D heading, D action]``
    (``D`` = 4 on a grid), ``M`` rows per robot: its cells (``M = C``), or, kept lazily,
    the cells it has stood in, row ``slot[r, k, c]`` for cell ``c`` (int32 ``[R, K, C +
    1]``, -1: none yet; ``slot[r, k, C]``: the rows given out); ``slot`` is None when
    the tables are dense.

    ``n`` is kept as int32 (a count never exceeds the steps of a run, at most 10**9) and
    written as int64 (:meth:`tables`); ``1.0 / (n + 1)`` is the same float either way.
    """

    name = "qlearning"
    learns = True

    #: The arrays with a leading runs axis (:mod:`qpatrol.run.batching` cuts them per point).
    per_run = ("q", "n", "pending")
    #: The config keys this strategy reads that may differ between a batch's rows.
    RUN_KEYS = (
        "learning.gamma",
        "learning.epsilon",
        "learning.multiplier",
        *(f"learning.q_init.{d}" for d in DIRECTIONS),
    )

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.use_heading = cfg["learning.state_space"] == "cell_heading"
        C, d = p.n_cells, m.n_ports
        self.rows = limits.table_rows(cfg, C, self.n_agents, d)
        self.slot: np.ndarray | None = None
        if self.rows < C:
            self.slot = np.full((self.n_runs, self.n_agents, C + 1), -1, dtype=np.int32)
            self.slot[..., C] = 0
            self.per_run = (*type(self).per_run, "slot")
        self.use_run_values(None)
        self.n = np.zeros(self.q.shape, dtype=np.int32)
        # int64 [R, K, 3]: each robot's decision travelling a graph's edge (cell, heading,
        # port) until it reaches the next vertex; -1: none (learner.pending_transitions)
        self.pending = np.full((self.n_runs, self.n_agents, 3), -1, dtype=np.int64)

    def use_run_values(self, values: dict[str, np.ndarray] | None, table: bool = True) -> None:
        """Take the values of :data:`RUN_KEYS` that differ between the batch's rows
        (config key -> float64 ``[R]``; the others from the config) and, with ``table``,
        set the initial table ``q`` from them. ``gamma`` and ``epsilon`` are then
        floats, or float64 ``[R]`` where the rows differ; ``q_init`` is ``[D]`` or
        ``[R, D]``."""
        cfg, values = self.cfg, values or {}
        q_init = np.array([cfg[f"learning.q_init.{d}"] for d in DIRECTIONS], dtype=np.float64)
        self.q_init = self._per_port(q_init * cfg["learning.multiplier"])
        self.gamma = float(cfg["learning.gamma"])
        self.epsilon = float(cfg["learning.epsilon"])
        d = self.map.n_ports
        shape = (self.n_runs, self.n_agents, self.rows, d, d)
        if any(f"learning.q_init.{d}" in values for d in DIRECTIONS) or (
            "learning.multiplier" in values
        ):
            rows = np.empty((self.n_runs, 4))
            for i, d in enumerate(DIRECTIONS):
                rows[:, i] = values.get(f"learning.q_init.{d}", cfg[f"learning.q_init.{d}"])
            mult = values.get("learning.multiplier", cfg["learning.multiplier"])
            self.q_init = self._per_port(rows * np.asarray(mult, dtype=np.float64).reshape(-1, 1))
            if table:
                self.q = np.broadcast_to(self.q_init[:, None, None, None, :], shape).copy()
        elif table:  # one run's table, copied into each run's (faster than one broadcast)
            self.q = np.empty(shape)
            self.q[...] = np.broadcast_to(self.q_init, shape[1:]).copy()
        if "learning.gamma" in values:
            self.gamma = np.asarray(values["learning.gamma"], dtype=np.float64)
        if "learning.epsilon" in values:
            self.epsilon = np.asarray(values["learning.epsilon"], dtype=np.float64)

    def _per_port(self, q_init: np.ndarray) -> np.ndarray:
        """The initial values ``[..., 4]`` (N, E, S, W) as one per port ``[..., D]``: the
        same on a grid; on a patrol graph the largest of the four for every port."""
        if not self.map.is_graph:
            return q_init
        top = q_init.max(axis=-1, keepdims=True)
        return np.repeat(top, self.map.n_ports, axis=-1)

    def _heading(self, head: np.ndarray) -> np.ndarray:
        return head if self.use_heading else np.zeros_like(head)

    def _by_robot(self) -> tuple[int, ...]:
        """The shape of ``q`` with its runs and robots axes as one, ``[R * K, M, D, D]``:
        robot k of run r has table ``r * K + k``."""
        return (-1, *self.q.shape[2:])

    def row_of(self, rr: np.ndarray, kk: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """int ``[B]``: the row of cell ``cells`` in the table of robot ``kk`` of run
        ``rr`` (int ``[B]`` each, no robot twice), given out now where it has none."""
        if self.slot is None:
            return cells
        flat_slot = flat(self.slot)
        where = at(self.slot.shape, rr, kk, cells)
        row = flat_slot[where]
        new = row < 0
        if new.any():
            used = at(self.slot.shape, rr[new], kk[new], self.params.n_cells)
            row[new] = flat_slot[used]
            if (row[new] >= self.rows).any():
                raise RuntimeError("qlearning: a robot stood in more cells than steps + 2")
            flat_slot[where[new]] = row[new]
            flat_slot[used] += 1
        return row

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        s = obs.state
        R, K = s.pos.shape
        robot = np.arange(R * K).reshape(R, K)  # each robot's table in q by robot
        cells = s.pos
        if self.slot is not None:  # the rows of the choosing robots' cells (0: unread)
            cells = np.zeros_like(s.pos)
            rr, kk = np.nonzero(obs.choosing)
            cells[rr, kk] = self.row_of(rr, kk, s.pos[rr, kk])
        state = at(self._by_robot(), robot, cells, self._heading(s.head))
        q_row = take_rows(self.q, state)  # Q(s, .) of each robot's state: float [R, K, D]
        d = q_row.shape[-1]
        action, can = learner.choose(
            q_row.reshape(-1, d),
            base.prefer_open(obs).reshape(-1, d),
            u[..., 0].reshape(-1),
            u[..., 1].reshape(-1),
            self.epsilon if np.ndim(self.epsilon) == 0 else np.repeat(self.epsilon, K),
        )
        return np.where(can, action, -1).reshape(R, K)

    def learn(self, out: Outcome, rec: Recorder | None = None) -> None:
        p = self.params
        if p.onward is None:  # every cell decides: each transition is one move
            rr, kk = np.nonzero(out.choosing & out.as_asked)
        else:  # decisions at a graph's vertices, completed at the next vertex
            before = np.stack([out.prev_pos, out.prev_head], axis=-1)
            rr, kk, done = learner.pending_transitions(self.pending, out, p.target, before)
        if rr.size == 0:
            return
        # the robots learning, int [B]: flat in [R, K], and their tables in q by robot
        robot = at(out.moved.shape, rr, kk)
        by_robot = self._by_robot()
        last_c, last_a = flat(out.prev_pos)[robot], flat(out.ask)[robot]  # the move into s'
        if p.onward is None:
            ca, ha, aa = last_c, self._heading(flat(out.prev_head)[robot]), last_a
        else:
            ca, ha, aa = done[:, 0], self._heading(done[:, 1]), done[:, 2]
        move = at(p.neighbors.shape, last_c, last_a)
        cb = flat(p.neighbors)[move]
        hb = self._heading(flat(p.entry)[move])  # the heading after the move
        reward = flat(out.reward)[robot]
        row_a, row_b = self.row_of(rr, kk, ca), self.row_of(rr, kk, cb)
        target, bootstrap = learner.td_target(
            reward,
            take_rows(self.q, at(by_robot, robot, row_b, hb)),
            np.take(p.wall_legal, cb, axis=0),
            per_row(self.gamma, rr),
        )
        sa = at(by_robot, robot, row_a, ha, aa)  # int [B], Q(s, a) flat in q
        q_before = flat(self.q)[sa]
        q_after, n_after, alpha = learner.update(q_before, flat(self.n)[sa], target)
        flat(self.q)[sa] = q_after
        flat(self.n)[sa] = n_after
        if rec is not None and rec.wants_updates:
            dot = flat(out.eaten)[robot]
            q_row = take_rows(self.q, at(by_robot, robot, row_a, ha))
            cols = update_cols(
                ca, ha, aa, reward, cb, hb, alpha, q_before, q_after, bootstrap, dot, q_row
            )
            rec.updates(out.t, rr, kk, cols)

    def tables(self) -> dict[str, np.ndarray]:
        """``q`` and ``n`` (int64); kept lazily, the rows given out only, with ``slot``
        (int32 ``[R, K, C]``, the row of each cell, -1: none) and ``q_init`` (float64
        ``[R, D]``, the values of every cell without a row):
        :func:`dense_tables` reads them back."""
        if self.slot is None:
            return {"q": self.q, "n": self.n.astype(np.int64)}
        used = int(self.slot[..., -1].max(initial=0))  # (the rows given out, no more)
        return {
            "q": self.q[:, :, :used],
            "n": self.n[:, :, :used].astype(np.int64),
            "slot": self.slot[..., :-1],
            "q_init": np.broadcast_to(self.q_init, (self.n_runs, self.q.shape[-1])).copy(),
        }


def dense_tables(z, run: int, agent: int) -> tuple[np.ndarray, np.ndarray]:
    """``(q [C, D, D], n [C, D, D])`` of one robot from the arrays of ``q_table.npz``
    (``z``, any mapping: :meth:`Strategy.tables`), dense or kept lazily."""
    q, n = z["q"][run, agent], z["n"][run, agent]
    if "slot" not in z:
        return q, n
    slot, q_init = z["slot"][run, agent], z["q_init"][run]
    has = slot >= 0
    dq = np.empty((slot.shape[0], *q.shape[1:]), dtype=q.dtype)
    dq[...] = q_init
    dq[has] = q[slot[has]]
    dn = np.zeros((slot.shape[0], *n.shape[1:]), dtype=n.dtype)
    dn[has] = n[slot[has]]
    return dq, dn
