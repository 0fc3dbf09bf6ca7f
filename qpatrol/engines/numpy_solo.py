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
    """Constants and flat views of the fast step for one batch, built once per loop
    (the views stay valid: neither step rebinds these arrays)."""

    nbrs: np.ndarray  # int [C 4], next cell per (cell, direction), -1 = wall
    legal: np.ndarray  # bool [C, 4]
    dir_of: np.ndarray  # int [C 4]: the direction traffic.direction_of reports
    row0: np.ndarray  # int [R]: r C 4, first Q row of run r
    cell0: np.ndarray  # int [R]: r C, first cell of run r in [R C] maps
    nth: np.ndarray  # int [16 4]: learner._NTH flattened
    bits: np.ndarray  # int [4]: 1, 2, 4, 8
    no_wait: np.ndarray  # int [R, 1] zeros: the waits after a step of this kind
    q2: np.ndarray  # float [R C 4, 4]: the Q-table, one row per (run, cell, heading)
    q1: np.ndarray  # float [R C 4 4]
    n1: np.ndarray  # int [R C 4 4]
    pos: np.ndarray  # int [R]: views of the world's [R, 1] and [R, 1, C...] arrays
    head: np.ndarray
    occ: np.ndarray  # [R C]
    dots: np.ndarray  # [R C]
    last: np.ndarray  # [R C]
    ep_seen: np.ndarray  # [R C]
    ep_seen_state: np.ndarray  # [R C 4]
    dots_left: np.ndarray  # [R]
    ep_dots: np.ndarray
    ep_visits: np.ndarray
    ep_start: np.ndarray
    m_last: np.ndarray  # [R C]: the measures' arrays
    visits: np.ndarray  # [R C]
    window_visits: np.ndarray  # [R C]


def prepare(p: Params, s: State, strategy: object, m: Measures) -> Solo:
    """The constants and views of :func:`step` for batch ``s`` on ``p``'s map."""
    c = p.n_cells
    n_runs = s.n_runs
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
        no_wait=np.zeros_like(s.wait),
        q2=_view(strategy.q, (-1, 4)),
        q1=_view(strategy.q, -1),
        n1=_view(strategy.n, -1),
        pos=s.pos[:, 0],
        head=s.head[:, 0],
        occ=_view(s.occ, -1),
        dots=_view(s.dots, -1),
        last=_view(s.last, -1),
        ep_seen=_view(s.ep_seen, -1),
        ep_seen_state=_view(s.ep_seen_state, -1),
        dots_left=s.dots_left[:, 0],
        ep_dots=s.ep_dots[:, 0],
        ep_visits=s.ep_visits[:, 0],
        ep_start=s.ep_start[:, 0],
        m_last=_view(m.last, -1),
        visits=_view(m.visits, -1),
        window_visits=_view(m.window_visits, -1),
    )


def _view(a: np.ndarray, shape: int | tuple[int, ...]) -> np.ndarray:
    """``a`` reshaped without a copy (writes through to ``a``)."""
    v = a.view()
    v.shape = shape  # raises rather than copying
    return v


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
    q2, q1, n1, pos = solo.q2, solo.q1, solo.n1, solo.pos
    c0 = pos.copy()
    h0 = solo.head if strategy.use_heading else 0
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
        solo.occ[solo.cell0 + c0] = -1
        solo.occ[gi] = 0
    solo.head[:] = d
    # --- entering the cell: dots, visits, reward (world.step) ---------------------------
    ate = solo.dots[gi]
    solo.dots[gi] = False
    ep_dots, ep_visits = solo.ep_dots, solo.ep_visits
    solo.dots_left -= ate
    ep_dots += ate
    ep_visits += 1
    idle = t - solo.last[gi]
    solo.last[gi] = t
    solo.ep_seen[gi] = True
    solo.ep_seen_state[gi * 4 + d] = True
    reward = (
        np.where(ate, p.dot_value[c1], 0.0)
        + p.incremental_value * np.minimum(1.0, idle / p.idle_horizon)
        + p.lambda_weight * ep_dots / ep_visits
    )
    s.wait = solo.no_wait  # every asked move was made (s.wait is only ever rebound)
    s.steps_done.fill(t)
    ended = not solo.dots_left.all()
    if p.max_episode_steps and not ended:
        ended = solo.ep_start.min() <= t - p.max_episode_steps
    if ended:
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
    prev = solo.m_last[gi]
    solo.m_last[gi] = t
    m.last_sum += t - prev
    solo.visits[gi] += 1
    if t > m.warmup:
        solo.window_visits[gi] += 1
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
