"""Tabular Q-learning, as in §3-§4 of the paper, over a batch of runs.

Each agent owns a table ``Q[cell, heading, action]`` and a visit count ``N`` of the
same shape. The agent acts greedily over its *legal* actions (moves into walls are
not choices; moves into occupied cells are masked by the simulator), ties broken by
the run's own random stream, with an optional epsilon of uniformly random legal
moves. After a move ``s -a-> s'`` with reward ``r``::

    N(s,a) <- N(s,a) + 1
    alpha   = 1 / N(s,a)
    Q(s,a) <- Q(s,a) + alpha * (r + gamma * max_{a' legal in s'} Q(s',a') - Q(s,a))

The initial table is ``q_init * multiplier`` for every state: with the defaults
North 3, West 2, East 2, South 1, a state is left North first, then West or East,
South last.

Functions here are pure array functions over a leading batch axis ``B`` (the runs
whose agent acts this step); the simulator gathers and scatters the rows.
"""

from __future__ import annotations

import numpy as np

from qpatrol.util.arrays import at, flat, port_max


def choose(
    q_row: np.ndarray,
    legal: np.ndarray,
    u_explore: np.ndarray,
    u_pick: np.ndarray,
    epsilon: float | np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Greedy action with random tie-breaks, or a random legal one with probability epsilon.

    Args:
        q_row: float ``[B, D]``, Q(s, a) for the D ports (four directions on a grid).
        legal: bool ``[B, D]``, the actions that may be taken.
        u_explore: float ``[B]`` in [0, 1): explore when ``u_explore < epsilon``.
        u_pick: float ``[B]`` in [0, 1): picks among the candidates, in port order (N, E,
            S, W on a grid).
        epsilon: probability of choosing uniformly among legal actions (a float, or
            float ``[B]``, one per row).

    Returns:
        ``(action [B] int, has_move [B] bool)``; action is 0 where there is no legal move.
    """
    masked = np.where(legal, q_row, -np.inf)
    best = port_max(masked)
    cand = legal & (masked == best[:, None])
    if np.ndim(epsilon) or epsilon > 0.0:
        cand = np.where((u_explore < epsilon)[:, None], legal, cand)
    return pick(cand, u_pick)


#: Candidate masks as D-bit numbers (port p is bit ``1 << p``; on a grid N=1, E=2, S=4,
#: W=8), for any D up to 8: how many candidates each has, and the j-th candidate's port
#: in port order (N, E, S, W on a grid). A mask of the first four ports reads the rows
#: and columns the 4-bit tables had, so a grid's choices are what they were.
MAX_PORTS = 8
_BITS = 1 << np.arange(MAX_PORTS)
_COUNT = np.array([bin(m).count("1") for m in range(1 << MAX_PORTS)])
_NTH = np.array(
    [
        [d for d in range(MAX_PORTS) if m >> d & 1] + [0] * (MAX_PORTS - bin(m).count("1"))
        for m in range(1 << MAX_PORTS)
    ]
)


def pick(cand: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Choose uniformly among the True entries of each row of ``cand`` ``[B, D]``.

    The j-th candidate (in port order: N, E, S, W on a grid) is taken,
    ``j = floor(u * n_candidates)``. Returns ``(action [B], has_move [B])``; action is 0
    where there is no candidate.
    """
    mask = cand @ _BITS[: cand.shape[-1]]
    count = _COUNT[mask]
    j = np.minimum((u * count).astype(np.int64), np.maximum(count - 1, 0))
    return flat(_NTH)[at(_NTH.shape, mask, j)], count > 0


def td_target(
    reward: np.ndarray, q_next: np.ndarray, legal_next: np.ndarray, gamma: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(r + gamma * max_a' Q(s', a'), gamma * max_a' Q(s', a'))`` over legal ``a'``.

    Args:
        reward: float ``[B]``.
        q_next: float ``[B, D]``, Q(s', .).
        legal_next: bool ``[B, D]``, the non-wall moves out of s'.
        gamma: a float, or float ``[B]``, one per row.
    """
    bootstrap = gamma * port_max(np.where(legal_next, q_next, -np.inf))
    return reward + bootstrap, bootstrap


def update(
    q_sa: np.ndarray, n_sa: np.ndarray, target: np.ndarray, fixed_alpha: float = 0.0
) -> tuple[np.ndarray, ...]:
    """One Q-learning step with ``alpha = 1/N``, N counted after this choice (or a fixed
    ``alpha`` when ``fixed_alpha > 0``).

    Args:
        q_sa: float ``[B]``, Q(s, a) before the update.
        n_sa: int ``[B]``, N(s, a) before this choice.
        target: float ``[B]``, ``r + gamma * max Q(s', .)``.
        fixed_alpha: the step size; 0 means ``1/N``.

    Returns:
        ``(q_after [B], n_after [B], alpha [B])``.
    """
    n_after = n_sa + 1
    alpha = np.full(n_after.shape, fixed_alpha) if fixed_alpha > 0 else 1.0 / n_after
    return q_sa + alpha * (target - q_sa), n_after, alpha


def pending_transitions(
    pending: np.ndarray, out, target: np.ndarray, state: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The transitions of a patrol graph's learner completed by a team step; the
    decisions still travelling stay in ``pending`` (updated in place).

    A transition runs from a decision at a vertex to the arrival at the next vertex. A
    robot that chose a move and made it starts a decision; one travelling its edge
    (``out.travelling``) keeps its decision while it moves on as asked or waits; any
    other (pushed aside, homing, queued, failed, its run ended, or one that exchanged its
    task with another robot, ``out.swapped``) drops it. A decision whose robot has just
    made its move into a vertex completes.

    Args:
        pending: int ``[R, K, S + 1]``, each robot's decision not yet completed: its
            state slots (column 0 the cell, -1 for none) and the port chosen (last).
        out: the step's :class:`~qpatrol.world.Outcome`.
        target: bool ``[C]``, the vertices (every cell of a grid).
        state: int ``[R, K, S]``, each robot's state slots before the step (cell first).

    Returns:
        ``(rows, robots, done)``: int ``[B]``, ``[B]``, ``[B, S + 1]``, the completed
        transitions in run-then-robot order, each its decision's row of ``pending``.
    """
    decided = out.choosing & out.as_asked
    travel = out.travelling if out.travelling is not None else np.zeros_like(decided)
    keep = travel & (pending[..., 0] >= 0) & (out.as_asked | ~out.moved)
    if out.swapped is not None:
        keep &= out.swapped < 0
    pending[~keep & ~decided] = -1
    pending[decided] = np.concatenate([state, out.ask[..., None]], axis=-1)[decided]
    rr, kk = np.nonzero((pending[..., 0] >= 0) & out.as_asked & target[out.pos])
    done = pending[rr, kk].copy()
    pending[rr, kk] = -1
    return rr, kk, done
