"""Robots that pass each other and stop when they meet: ``team.interaction: interference``.

patrolling_sim's robots are bodies that pass each other under the navigation stack;
each robot, while it moves towards its goal, checks whether a robot of lower index
stands within 2 m of it and, if so, stops for 3 s and resends its goal, at most once
per 10 s (``PatrolAgent::check_interference`` and ``do_interference_behavior``). Here,
in team steps and moves:

1. Robots may share cells and pass each other along an edge: every asked move is made,
   except by a robot that is *stopped*.
2. A robot *meets* another at the end of a step in which it moved when a robot of lower
   index (not failed) stands within ``radius`` moves of it (shortest path; sharing its
   cell included) or the two swapped cells in the step. It then stops: its moves of the
   next ``stop_steps`` team steps are not made (it keeps asking; each refused move is a
   wait and an interference). It meets no robot again until ``cooldown`` steps after.
   So robot 0 never stops, as in patrolling_sim.

A robot's stop depends only on where the robots stand, never on whether the others
stop, so the rule is the same whatever order the robots are looked at in. Arrays are
``[R, K]`` unless stated.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.world import battery

if TYPE_CHECKING:
    from qpatrol.world import Params, State

#: ``State.met`` of a robot that never met another: far enough back that it is neither
#: stopped nor cooling down at step 0, whatever the config's steps.
NEVER = -(1 << 40)


def stopped(s: State, p: Params) -> np.ndarray:
    """bool ``[R, K]``: the robots whose moves are not made in step ``s.t`` (they met
    another at the end of one of the ``p.stop_steps`` steps before); none but under the
    interference interaction."""
    if p.ball is None:
        return np.zeros(s.pos.shape, dtype=bool)
    return s.t - s.met <= p.stop_steps


def meet(s: State, p: Params, prev_pos: np.ndarray, moved: np.ndarray) -> None:
    """The end of step ``s.t``: each robot that ``moved`` (bool ``[R, K]``), is off its
    cooldown and meets a robot of lower index stops (``s.met`` set to ``s.t``).

    ``prev_pos``: int ``[R, K]``, the cells before the step (for swaps, which matter
    only with ``radius`` 0: a swap leaves two robots one move apart)."""
    R, K = s.pos.shape
    rows = np.arange(R)
    here = s.active[:, None] & (s.mode != battery.GONE)  # robots standing on the map
    seen = np.zeros((R, p.n_cells), dtype=bool)  # cells of robots 0..j-1
    ball = p.ball
    for j in range(K):
        cell = s.pos[:, j]
        may = moved[:, j] & here[:, j] & (s.t - s.met[:, j] >= p.cooldown)
        if may.any():
            near = ball[cell]  # [R, B]
            hit = (seen[rows[:, None], np.maximum(near, 0)] & (near >= 0)).any(axis=1)
            if p.radius == 0 and j:
                swapped = (prev_pos[:, :j] == cell[:, None]) & (
                    s.pos[:, :j] == prev_pos[:, j, None]
                )
                hit |= (swapped & here[:, :j]).any(axis=1)
            s.met[may & hit, j] = s.t
        seen[rows[here[:, j]], cell[here[:, j]]] = True


def travel_steps(moves: int, p: Params) -> int:
    """Team steps within which a robot makes ``moves`` asked moves under the interaction:
    ``moves`` without interference; with it, each stop of ``stop_steps`` starts at most
    once per ``cooldown`` steps, so the fewest n with ``n - stop_steps x ceil(n /
    cooldown) >= moves`` (docs/model.md, "Passing robots")."""
    if p.ball is None:
        return moves
    n = moves
    while n - p.stop_steps * -(-n // p.cooldown) < moves:
        n += 1
    return n
