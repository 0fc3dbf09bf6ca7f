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

from qpatrol.engines.compiled.choice import MASKED, pick
from qpatrol.engines.compiled.pack import Pack, dummy_pack
from qpatrol.engines.compiled.updates import record, wanted


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


@njit(cache=True, nogil=True, _nrt=False)
def update(q_f, n_f, at0, at1, m1, reward, gamma):
    """The Q-learning update of one robot, on its tables flat (``q_f`` float64, ``n_f``
    int32): ``Q(s, a) <- Q(s, a) + (1/N) (r + gamma max_{a' legal} Q(s', a') - Q(s,
    a))``, ``Q(s, a)`` at ``at0`` and ``Q(s', .)`` at ``at1..at1+3``, the greatest taken
    with no branch per move (``m1``: ``MASKED`` of the legal moves of s'). Returns
    ``(max Q(s', .), alpha, Q(s, a) before)``."""
    top = max(
        max(q_f[at1] + m1[0], q_f[at1 + 1] + m1[1]),
        max(q_f[at1 + 2] + m1[2], q_f[at1 + 3] + m1[3]),
    )
    target = reward + gamma * top
    q_sa = q_f[at0]
    n_after = n_f[at0] + 1
    alpha = 1.0 / n_after
    q_f[at0] = q_sa + alpha * (target - q_sa)
    n_f[at0] = n_after
    return top, alpha, q_sa


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def learn(r, t, p, w, sp, o, n_up):
    """The update of every robot of run ``r`` that made the move it chose, in robot
    order (:func:`update`); Q-updates recorded as :meth:`qpatrol.measures.records.Recorder.updates`
    wants them. ``p``, ``w``, ``o``: the loop's ``Params``, ``Work`` and ``Out``
    (:mod:`qpatrol.engines.compiled.bundles`). Returns the number of update rows now
    written."""
    gamma = sp.row_f[r, 0]
    use_heading = sp.ipar[0] != 0
    q_f, n_f = sp.q[r].reshape(-1), sp.n[r].reshape(-1)
    n_cells = p.nbrs.shape[0]
    for k in range(w.prev_pos.shape[0]):
        if not w.as_asked[k] or not w.choosing[k]:
            continue
        ca = w.prev_pos[k]
        ha = w.prev_head[k] if use_heading else 0
        aa = w.ask[k]
        cb = p.nbrs[ca, aa]
        hb = aa if use_heading else 0
        at = ((k * n_cells + ca) * 4 + ha) * 4  # Q(ca, ha, .), flat
        at1 = ((k * n_cells + cb) * 4 + hb) * 4  # Q(cb, hb, .)
        m1 = MASKED[p.cell_moves[cb]]
        top, alpha, q_sa = update(q_f, n_f, at + aa, at1, m1, w.reward[k], gamma)
        if wanted(o, ca):
            ints = (r, t, k, ca, ha, aa, cb, hb, 1 if w.eaten[k] else 0)
            floats = (w.reward[k], alpha, q_sa, q_f[at + aa], gamma * top)
            n_up = record(o, n_up, ints, floats, q_f[at : at + 4])
    return n_up
