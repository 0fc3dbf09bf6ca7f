"""The numpy engine's fast step for lone Q-learners: one robot per run, battery off.

One team step of every run in about fifty cheap numpy calls on flat views of the
arrays the general step uses (:mod:`qpatrol.world`, the learner's tables, the
measures), so the two may alternate from one step to the next: :meth:`Solo.step` is used
while every run is active, the general step otherwise (and on a map with a cell that has
no move, where :func:`covers` is False).
Work per step does not grow with the map: a Q row is one ``take`` from the table viewed
as ``[R C 4, 4]`` (row ``(r C + cell) 4 + heading``), and no ``[runs, cells]`` array is
allocated. The arithmetic is the general step's, operation for operation, but for the
masking of walls: a Q row gets 0.0 or -inf added per move (``Solo.wall_add``), as the
compiled kernels do, instead of ``np.where``. Adding 0.0 changes a Q-value only in the
sign of a zero, which no comparison sees, nor the Q-target (its reward is never -0.0).

A lone robot always makes the move it chose, so the state it reaches is the one it
bootstraps from: the masked Q row of that state (and its maximum) are kept from one
fast step to the next and not read again, as long as no general step came in between.
"""

from __future__ import annotations

import numpy as np

from qpatrol.engines.deferred import Deferred
from qpatrol.engines.flat import max4, pick_among, view
from qpatrol.measures import Measures
from qpatrol.records import Recorder, Tail
from qpatrol.timeline import Timeline
from qpatrol.world import Params, State, _end_episodes


def covers(p: Params, strategy: object) -> bool:
    """True when :class:`Solo` applies: qlearning, one robot, battery off (on a map
    where no cell is its own neighbour)."""
    if p.n_agents != 1 or p.battery or getattr(strategy, "name", "") != "qlearning":
        return False
    if not p.wall_legal.any(axis=1).all():  # a cell without a move (a one-cell map)
        return False
    return not (p.neighbors == np.arange(p.n_cells)[:, None]).any()


class Solo:
    """The fast step of one batch: constants, flat views (valid for the whole loop:
    neither step rebinds these arrays) and what one fast step leaves for the next.

    Arrays: ``R`` runs, ``C`` cells; ``[R C]`` maps are the world's ``[R, 1, C]`` (or the
    measures' ``[R, C]`` and ``[R, 1, C]``) arrays viewed flat, index ``r C + cell``.
    """

    def __init__(self, p: Params, s: State, strategy: object, m: Measures, defer: bool = True):
        c, n_runs = p.n_cells, s.n_runs
        nbrs = p.neighbors
        dir_of = (nbrs[:, None, :] == nbrs[:, :, None]).argmax(axis=2)  # first d, same cell
        heading = np.arange(4) if strategy.use_heading else np.zeros(4, dtype=np.int64)
        self.p, self.s, self.strategy, self.m = p, s, strategy, m
        self.taken = 0  # fast steps taken (for tests)
        # the world's last visits are the measures' (one robot); a lone robot's
        # occupancy follows from its cell
        self.deferred = Deferred(s, m, defer, last=True, occ=p.avoid_collisions)
        self.nbrs = nbrs.reshape(-1)  # int [C 4]: next cell of (cell, direction), -1 wall
        self.legal = p.wall_legal  # bool [C, 4]
        self.wall_add = np.where(p.wall_legal, 0.0, -np.inf)  # float [C, 4]: -inf for walls
        self.dir_of = dir_of.reshape(-1)  # int [C 4]: the direction traffic.direction_of gives
        self.next_row = (np.maximum(nbrs, 0) * 4 + heading).reshape(-1)  # int [C 4]: Q row
        # offset (cell' 4 + heading') of the state reached by (cell, direction)
        self.row0 = np.arange(n_runs, dtype=np.int64) * (c * 4)  # int [R]: run's first Q row
        self.cell0 = np.arange(n_runs, dtype=np.int64) * c  # int [R]: run's first cell
        self.no_wait = np.zeros_like(s.wait)  # int [R, 1]: waits after a fast step
        self.q2 = view(strategy.q, (-1, 4))  # float [R C 4, 4]: Q row of (run, cell, heading)
        self.q1 = view(strategy.q, -1)  # float [R C 4 4]
        self.n1 = view(strategy.n, -1)  # int32 [R C 4 4]
        self.pos = s.pos[:, 0]  # int [R]: views of the world's [R, 1] arrays
        self.head = s.head[:, 0]
        self.occ = view(s.occ, -1)  # int [R C]
        self.dots = view(s.dots, -1)  # bool [R C]
        self.last = view(s.last, -1)  # int [R C]
        self.ep_seen = view(s.ep_seen, -1)  # bool [R C]
        self.ep_seen_state = view(s.ep_seen_state, -1)  # bool [R C 4]
        self.dots_left = s.dots_left[:, 0]  # int [R]
        self.ep_dots = s.ep_dots[:, 0]
        self.ep_visits = s.ep_visits[:, 0]
        self.ep_start = s.ep_start[:, 0]
        self.m_last = view(m.last, -1)  # int [R C]: the measures' arrays
        self.visits = view(m.visits, -1)
        self.window_visits = view(m.window_visits, -1)
        # kept from the last fast step (valid while self.t == s.t): the Q row index
        # [R], the row with its walls at -inf float [R, 4] and its max
        self.t = -1
        self.row = self.masked = self.best = None
        self.ep_start_min = 0  # min of ep_start (set at the first step)
        # epsilon: a float, or float [R] per run (np.any once, not every step)
        self.explores = bool(np.any(np.asarray(strategy.epsilon) > 0.0))

    def step(self, u: np.ndarray, rec: Recorder, tail: Tail, timeline: Timeline) -> bool:
        """One team step of every run (all active), in place; always True (every robot
        has a move: :func:`covers` excludes a map with a cell that has none).

        ``u``: float ``[R, 1, 2]``, this step's uniforms; ``timeline`` is off.
        """
        s, p, strategy, m = self.s, self.p, self.strategy, self.m
        pos = self.pos
        if self.t == s.t:
            row, masked, best = self.row, self.masked, self.best
        else:  # the first step, or a general step came in between
            row = self.row0 + (pos * 4 + (self.head if strategy.use_heading else 0))
            masked = self.q2.take(row, axis=0)
            masked += self.wall_add.take(pos, axis=0)
            best = max4(masked)
            self.ep_start_min = int(self.ep_start.min())
        # --- choose (learner.choose) --------------------------------------------------------
        # walls are -inf in ``masked`` and every cell has a legal move, so its best is
        # finite and equals no wall
        cand = masked == best[:, None]
        if self.explores:
            cand = np.where(
                (u[:, 0, 0] < strategy.epsilon)[:, None], self.legal.take(pos, axis=0), cand
            )
        a = pick_among(cand, u[:, 0, 1])
        self.taken += 1
        self.deferred.mark()
        ca = pos * 4 + a  # flat (cell, direction) index
        c1 = self.nbrs.take(ca)
        d = self.dir_of.take(ca)
        gi = self.cell0 + c1  # flat [R C] index of the cell entered
        t = s.t = s.t + 1
        if p.avoid_collisions and not self.deferred.occ:
            self.occ[self.cell0 + pos] = -1
            self.occ[gi] = 0
        pos[:] = c1
        self.head[:] = d
        # --- entering the cell: dots, visits, reward (world.step) ---------------------------
        ate = self.dots.take(gi)
        self.dots[gi] = False
        ep_dots, ep_visits = self.ep_dots, self.ep_visits
        self.dots_left -= ate
        ep_dots += ate
        ep_visits += 1
        prev = self.m_last.take(gi)  # = the world's last visit: one robot, one map
        idle = t - prev
        if not self.deferred.last:
            self.last[gi] = t
        self.m_last[gi] = t
        self.ep_seen[gi] = True
        self.ep_seen_state[gi * 4 + d] = True
        reward = (
            np.where(ate, p.dot_value.take(c1), 0.0)
            + p.incremental_value * np.minimum(1.0, idle / p.idle_horizon)
            + p.lambda_weight * ep_dots / ep_visits
        )
        s.wait = self.no_wait  # every asked move was made (s.wait is only ever rebound)
        s.steps_done.fill(t)
        ended = np.count_nonzero(self.dots_left) < self.dots_left.size
        if p.max_episode_steps and not ended:
            ended = self.ep_start_min <= t - p.max_episode_steps
        if ended:
            rec.episodes(t, _end_episodes(s, p))
            self.ep_start_min = int(self.ep_start.min())
        # --- learn (qlearning.learn): the robot made the move it chose -----------------------
        row1 = self.row0 + self.next_row.take(ca)
        masked1 = self.q2.take(row1, axis=0)
        masked1 += self.wall_add.take(c1, axis=0)
        best1 = max4(masked1)
        target = reward + strategy.gamma * best1
        idx = row * 4 + a
        q_sa = self.q1.take(idx)
        n_after = self.n1.take(idx) + 1
        alpha = 1.0 / n_after
        self.q1[idx] = q_sa + alpha * (target - q_sa)
        self.n1[idx] = n_after
        self.t = t
        self.row, self.masked, self.best = row1, masked1, best1
        # --- measures (Measures.observe) -----------------------------------------------------
        m.last_sum += idle
        if t > m.warmup and self.deferred.count_window():
            np.add.at(self.window_visits, gi, 1)
        np.add.at(self.visits, gi, 1)
        if t > m.warmup:
            seen = prev > 0
            gap = np.where(seen, idle, 0)
            m.gap_sum += gap
            m.gap_count += seen
            np.maximum(m.gap_max, gap, out=m.gap_max)
            if t - 1 > m.warmup:
                np.maximum(m.worst, idle - 1, out=m.worst)
            m.idle_total += m.n_cells * t - m.last_sum
            m.measured += 1
            # waits are all 0: max_wait and wait_total do not change
        if tail.n:
            tail.observe(s)
        return True
