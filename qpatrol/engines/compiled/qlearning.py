"""``qlearning`` compiled: the paper's §3 learner, act and learn for one run of a batch.

The numpy twin is :mod:`qpatrol.strategies.qlearning` (arithmetic operation for
operation: greedy over the open moves, ties and epsilon from the run's uniforms;
``Q(s,a) <- Q(s,a) + (1/N) (r + gamma max_{a' legal} Q(s',a') - Q(s,a))``).

Pack (see :mod:`qpatrol.engines.compiled`): ``q`` float64 and ``n`` int32
``[R, K, C, H, 4]`` (``H`` = 4 headings); ``row_f`` float64 ``[R, 2]``: each run's
``[gamma, epsilon]`` (they may differ between the runs of a batch);
``ipar = [use_heading]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from qpatrol.engines.compiled.choice import pick
from qpatrol.engines.compiled.pack import Pack, dummy_pack


def pack(strategy) -> Pack:
    """The compiled arrays of a :class:`qpatrol.strategies.qlearning.Strategy` (its own
    ``q`` and ``n``, updated in place)."""
    return dummy_pack(
        row_f=_row_f(strategy),
        ipar=np.array([1 if strategy.use_heading else 0], dtype=np.int64),
        q=strategy.q,
        n=strategy.n,
    )


def _row_f(strategy) -> np.ndarray:
    """float64 ``[R, 2]``: each run's gamma and epsilon (floats, or ``[R]`` per run)."""
    out = np.empty((strategy.n_runs, 2), dtype=np.float64)
    out[:, 0] = strategy.gamma
    out[:, 1] = strategy.epsilon
    return out


def unpack(p: Pack, strategy) -> None:
    """Nothing to copy back: ``q`` and ``n`` are the strategy's own arrays."""


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def act(r, i, u, pos, head, open_mask, choosing, ask, row_f, ipar, q):
    """``ask[k]`` for every choosing robot of run ``r``: the greedy open move (ties by
    ``u[r, i, k, 1]``; with probability epsilon (``u[r, i, k, 0] < epsilon``) any open
    move), -1 where there is none."""
    epsilon = row_f[r, 1]
    use_heading = ipar[0] != 0
    for k in range(pos.shape[1]):
        if not choosing[k]:
            ask[k] = -1
            continue
        c = pos[r, k]
        h = head[r, k] if use_heading else 0
        # choice.greatest with the Q row read in place: through a tuple of the four
        # values the whole loop ran about 12 % slower (2,000,000 steps, one robot)
        best = -np.inf
        for d in range(4):
            if open_mask[k, d] and q[r, k, c, h, d] > best:
                best = q[r, k, c, h, d]
        explore = epsilon > 0.0 and u[r, i, k, 0] < epsilon
        bits = 0
        count = 0
        for d in range(4):
            if open_mask[k, d] and (explore or q[r, k, c, h, d] == best):
                bits |= 1 << d
                count += 1
        ask[k] = pick(bits, count, u[r, i, k, 1])


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def learn(
    r,
    t,
    nbrs,
    wall_legal,
    prev_pos,
    prev_head,
    ask,
    as_asked,
    choosing,
    reward,
    eaten,
    row_f,
    ipar,
    q,
    n,
    record_all,
    watched,
    up_int,
    up_float,
    n_up,
):
    """The update of every robot of run ``r`` that made the move it chose, in robot
    order; Q-updates recorded as :meth:`qpatrol.records.Recorder.updates` wants them.
    Returns the number of update rows now written."""
    gamma = row_f[r, 0]
    use_heading = ipar[0] != 0
    for k in range(prev_pos.shape[0]):
        if not as_asked[k] or not choosing[k]:
            continue
        ca = prev_pos[k]
        ha = prev_head[k] if use_heading else 0
        aa = ask[k]
        cb = nbrs[ca, aa]
        hb = aa if use_heading else 0
        top = -np.inf
        for d in range(4):
            if wall_legal[cb, d] and q[r, k, cb, hb, d] > top:
                top = q[r, k, cb, hb, d]
        target = reward[k] + gamma * top
        q_sa = q[r, k, ca, ha, aa]
        n_after = n[r, k, ca, ha, aa] + 1
        alpha = 1.0 / n_after
        q[r, k, ca, ha, aa] = q_sa + alpha * (target - q_sa)
        n[r, k, ca, ha, aa] = n_after
        if record_all or watched[ca]:  # Recorder.updates
            ri = up_int[n_up]
            ri[0] = r
            ri[1] = t
            ri[2] = k
            ri[3] = ca
            ri[4] = ha
            ri[5] = aa
            ri[6] = cb
            ri[7] = hb
            ri[8] = 1 if eaten[k] else 0
            rf = up_float[n_up]
            rf[0] = reward[k]
            rf[1] = alpha
            rf[2] = q_sa
            rf[3] = q[r, k, ca, ha, aa]
            rf[4] = gamma * top
            for d in range(4):
                rf[5 + d] = q[r, k, ca, ha, d]
            n_up += 1
    return n_up
