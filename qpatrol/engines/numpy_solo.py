"""The numpy engine's fast step for lone Q-learners: one robot per run, battery off.

One team step of every run in about fifty numpy calls, on flat views of the same arrays
the general step uses (:mod:`qpatrol.world`, the learner's tables, the measures), so
the two may alternate from one step to the next: :func:`step` is used while every run
is active and every robot has a move, the general step otherwise. Work per step does
not grow with the map: a Q row is one gather from the table viewed as ``[R C 4, 4]``
(row ``(r C + cell) 4 + heading``), walls are ``-inf``, and no ``[runs, cells]`` array
is allocated. The arithmetic is the general step's, operation for operation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qpatrol.learner import _COUNT, _NTH
from qpatrol.measures import Measures
from qpatrol.records import Recorder, Tail
from qpatrol.world import Params, State, _end_episodes


def covers(p: Params, strategy: object) -> bool:
    """True when :func:`step` applies: qlearning, one robot, battery off (on a map where
    no cell is its own neighbour)."""
    if p.n_agents != 1 or p.battery or getattr(strategy, "name", "") != "qlearning":
        return False
    return not (p.neighbors == np.arange(p.n_cells)[:, None]).any()


@dataclass
class Solo:
    """Constants of the fast step for one batch (built once per simulate call)."""

    nbrs: np.ndarray  # int [C 4], next cell per (cell, direction), -1 = wall
    legal: np.ndarray  # bool [C, 4]
    dir_of: np.ndarray  # int [C 4]: the direction traffic.direction_of reports
    row0: np.ndarray  # int [R]: r C 4, first Q row of run r
    cell0: np.ndarray  # int [R]: r C, first cell of run r in [R C] maps
    nth: np.ndarray  # int [16 4]: learner._NTH flattened
    bits: np.ndarray  # int [4]: 1, 2, 4, 8


def prepare(p: Params, n_runs: int) -> Solo:
    """The constants of :func:`step` for ``n_runs`` runs on ``p``'s map."""
    c = p.n_cells
    nbrs = p.neighbors
    dir_of = (nbrs[:, None, :] == nbrs[:, :, None]).argmax(axis=2)  # first d with same cell
    return Solo(
        nbrs=nbrs.reshape(-1),
        legal=p.wall_legal,
        dir_of=dir_of.reshape(-1),
        row0=np.arange(n_runs, dtype=np.int64) * (c * 4),
        cell0=np.arange(n_runs, dtype=np.int64) * c,
        nth=_NTH.reshape(-1),
        bits=np.array([1, 2, 4, 8]),
    )


def step(
    solo: Solo,
    s: State,
    p: Params,
    strategy: object,
    u: np.ndarray,
    m: Measures,
    rec: Recorder,
    tail: Tail,
) -> bool:
    """One team step of every run (all active), in place; False if it does not apply
    this step (a robot without a legal move), and then nothing was changed."""
    q2 = strategy.q.reshape(-1, 4)  # [R C 4, 4], views of [R, 1, C, 4, 4]
    q1 = strategy.q.reshape(-1)
    n1 = strategy.n.reshape(-1)
    pos = s.pos[:, 0]
    c0 = pos.copy()
    h0 = s.head[:, 0] if strategy.use_heading else 0
    row = solo.row0 + c0 * 4 + h0
    legal = solo.legal[c0]
    masked = np.where(legal, q2[row], -np.inf)
    cand = legal & (masked == masked.max(axis=1)[:, None])
    if strategy.epsilon > 0.0:
        cand = np.where((u[:, 0, 0] < strategy.epsilon)[:, None], legal, cand)
    mask = cand @ solo.bits
    count = _COUNT[mask]
    if not count.all():
        return False
    j = np.minimum((u[:, 0, 1] * count).astype(np.int64), count - 1)
    a = solo.nth[mask * 4 + j]
    ca = c0 * 4 + a
    c1 = solo.nbrs[ca]
    d = solo.dir_of[ca]
    t = s.t = s.t + 1
    pos[:] = c1
    gi = solo.cell0 + c1  # flat [R C] index of the cell entered
    if p.avoid_collisions:
        occ = s.occ.reshape(-1)
        occ[solo.cell0 + c0] = -1
        occ[gi] = 0
    s.head[:, 0] = d
    # --- entering the cell: dots, visits, reward (world.step) ---------------------------
    dots = s.dots.reshape(-1)
    ate = dots[gi]
    dots[gi] = False
    dots_left, ep_dots, ep_visits = s.dots_left[:, 0], s.ep_dots[:, 0], s.ep_visits[:, 0]
    dots_left -= ate
    ep_dots += ate
    ep_visits += 1
    last = s.last.reshape(-1)
    idle = t - last[gi]
    last[gi] = t
    s.ep_seen.reshape(-1)[gi] = True
    s.ep_seen_state.reshape(-1)[gi * 4 + d] = True
    reward = (
        np.where(ate, p.dot_value[c1], 0.0)
        + p.incremental_value * np.minimum(1.0, idle / p.idle_horizon)
        + p.lambda_weight * ep_dots / ep_visits
    )
    s.wait = np.zeros_like(s.wait)  # every asked move was made
    s.steps_done[:] = t
    ended = dots_left == 0
    if p.max_episode_steps:
        ended |= t - s.ep_start[:, 0] >= p.max_episode_steps
    if ended.any():
        rec.episodes(t, _end_episodes(s, p))
    # --- learn (qlearning.learn): every robot made the move it chose ---------------------
    hb = a if strategy.use_heading else 0
    bootstrap = strategy.gamma * np.where(solo.legal[c1], q2[solo.row0 + c1 * 4 + hb], -np.inf).max(
        axis=1
    )
    target = reward + bootstrap
    idx = row * 4 + a
    q_sa = q1[idx]
    n_after = n1[idx] + 1
    alpha = 1.0 / n_after
    q1[idx] = q_sa + alpha * (target - q_sa)
    n1[idx] = n_after
    # --- measures (Measures.observe) -------------------------------------------------------
    prev = m.last.reshape(-1)[gi]
    m.last.reshape(-1)[gi] = t
    m.last_sum += t - prev
    m.visits.reshape(-1)[gi] += 1
    if t > m.warmup:
        m.window_visits.reshape(-1)[gi] += 1
        seen = prev > 0
        gap = np.where(seen, t - prev, 0)
        m.gap_sum += gap
        m.gap_count += seen
        np.maximum(m.gap_max, gap, out=m.gap_max)
        if t - 1 > m.warmup:
            np.maximum(m.worst, t - 1 - prev, out=m.worst)
        m.idle_total += m.n_cells * t - m.last_sum
        m.measured += 1
        # waits are all 0: max_wait and wait_total do not change
    tail.observe(s)
    return True
