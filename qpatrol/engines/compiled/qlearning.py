"""``qlearning`` compiled: the paper's §3 learner, act and learn for one run of a batch.

The numpy twin is :mod:`qpatrol.strategies.qlearning` (arithmetic operation for
operation: greedy over the open moves, ties and epsilon from the run's uniforms;
``Q(s,a) <- Q(s,a) + (1/N) (r + gamma max_{a' legal} Q(s',a') - Q(s,a))``).

Pack (see :mod:`qpatrol.engines.compiled`): ``q`` float64 and ``n`` int32
``[R, K, C, H, D]`` (``H`` = D headings, ``D`` ports: 4 on a grid); ``row_f``
float64 ``[R, 2]``: each run's ``[gamma, epsilon]`` (they may differ between the runs of a batch);
``ipar = [use_heading]``; ``robot_i`` int64 ``[R, K, 3]``: the strategy's own
``pending`` decisions on a patrol graph with waypoints (cell, heading, port; -1: none),
completed at the next vertex (:func:`learn_pending`); ``slot`` int32 ``[R, K, C + 1]``:
tables kept lazily (the strategy's ``slot``, :func:`row`), a ``[1, 1, 1]`` placeholder
when they are dense.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from qpatrol.engines.compiled.choice import (
    MASKED,
    MASKED_PORTS,
    POPCOUNT,
    heading_of,
    pick,
    ports_of,
)
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
        robot_i=strategy.pending,
        **({} if strategy.slot is None else {"slot": strategy.slot}),
    )


def _row_f(strategy) -> np.ndarray:
    """float64 ``[R, 2]``: each run's gamma and epsilon (floats, or ``[R]`` per run)."""
    out = np.empty((strategy.n_runs, 2), dtype=np.float64)
    out[:, 0] = strategy.gamma
    out[:, 1] = strategy.epsilon
    return out


def unpack(p: Pack, strategy) -> None:
    """Nothing to copy back: ``q``, ``n`` and ``pending`` are the strategy's own arrays."""


def sat_out(strategy, state) -> None:
    """A run that stopped before the batch's last step (episode quota) dropped its
    robots' pending decisions in the steps it sat out (the numpy engine's learn)."""
    strategy.pending[state.steps_done < state.t] = -1


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def best_of(q_f, at, free, nd=4):
    """The greatest ``Q(s, .)`` (``q_f[at:at + nd]``, ``nd`` ports: 4 on a grid) over the
    moves of ``free`` (a mask of ports, on a grid N=1, E=2, S=4, W=8), taken with no
    branch per move (``MASKED``); -inf for none."""
    if nd == 4:
        mf = MASKED[free]
        return max(
            max(q_f[at] + mf[0], q_f[at + 1] + mf[1]),
            max(q_f[at + 2] + mf[2], q_f[at + 3] + mf[3]),
        )
    mp = MASKED_PORTS[free]
    top = -np.inf
    for d in range(nd):
        top = max(top, q_f[at + d] + mp[d])
    return top


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def choose(q_f, at, free, best, explore, u_tie, branch_free, nd=4):
    """One robot's choice (``learner.choose``): the open move (``free``) of greatest
    ``Q(s, .)`` (``q_f[at:at + nd]``, ``nd`` ports; ``best``: :func:`best_of`, which a
    caller that knows it passes), ties broken by ``u_tie``, or with ``explore`` any open
    move; -1 where none is open.

    ``branch_free`` (a constant at each call, so the compiler keeps one of the two
    forms) picks how the candidates are found, not which: a team's loop interleaves
    robots whose masks vary, and there a branch per move mispredicts (branches: 20 %
    slower, 4 robots); a lone robot's steps are one chain of dependent loads, and there
    branches let the processor run ahead on the predicted move (branch-free: 14 %
    slower). ``tests/test_engines.py`` checks that both forms choose alike."""
    if branch_free and nd == 4:
        bits = free
        if not explore:
            bits &= (
                (1 if q_f[at] == best else 0)
                | (2 if q_f[at + 1] == best else 0)
                | (4 if q_f[at + 2] == best else 0)
                | (8 if q_f[at + 3] == best else 0)
            )
        count = POPCOUNT[bits]
    else:
        bits = 0
        count = 0
        if nd == 4:  # (a grid's: the loop the compiler unrolls)
            for d in range(4):
                if free >> d & 1 and (explore or q_f[at + d] == best):
                    bits |= 1 << d
                    count += 1
        else:
            for d in range(nd):
                if free >> d & 1 and (explore or q_f[at + d] == best):
                    bits |= 1 << d
                    count += 1
    return pick(bits, count, u_tie)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def tables(sp, r):
    """Run ``r``'s parameters and tables: ``(gamma, epsilon, use_heading, q_f, n_f)``,
    the tables ``[K, C, D, D]`` flat (one index, not four; a reshape is a call, taken
    once per run and block in the Q-learning loop)."""
    return sp.row_f[r, 0], sp.row_f[r, 1], sp.ipar[0] != 0, sp.q[r].reshape(-1), sp.n[r].reshape(-1)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def slots(sp, r):
    """Run ``r``'s rows of lazily kept tables (int32 ``[K, C + 1]``), or the dense
    tables' ``[1, 1]`` placeholder (:func:`row`)."""
    return sp.slot[r] if sp.slot.shape[2] > 1 else sp.slot[0]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def row(slot_r, k, c, m):
    """Robot ``k``'s table row of cell ``c``, as a row of the run's tables ``[K, m]``
    (``m`` rows a robot): the cell itself when they are dense (``slot_r`` :func:`slots`
    a placeholder), else ``slot_r[k, c]``, given out now, the next free one, where it is
    -1 (the numpy twin: :meth:`qpatrol.strategies.qlearning.Strategy.row_of`)."""
    if slot_r.shape[1] == 1:
        return k * m + c
    x = slot_r[k, c]
    if x < 0:
        last = slot_r.shape[1] - 1
        x = slot_r[k, last]
        if x >= m:
            raise RuntimeError("qlearning: a robot stood in more cells than steps + 2")
        slot_r[k, c] = x
        slot_r[k, last] = x + 1
    return k * m + x


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def act(ur, pos_r, head_r, open_mask, choosing, ask, epsilon, use_heading, q_f, slot_r, nd):
    """``ask[k]`` for every choosing robot of a run (``pos_r``, ``head_r`` int ``[K]``;
    ``open_mask`` bool ``[K, D]``; ``ur`` float ``[K, 2]``: the step's uniforms;
    ``q_f``: :func:`tables`; ``slot_r``: :func:`slots`; ``nd``: D,
    :func:`~qpatrol.engines.compiled.choice.ports_of`): :func:`choose` over its open
    moves; -1 for the others."""
    m = q_f.shape[0] // (pos_r.shape[0] * nd * nd)
    for k in range(pos_r.shape[0]):
        if not choosing[k]:
            ask[k] = -1
            continue
        hs = head_r[k] if use_heading else 0
        at = (row(slot_r, k, pos_r[k], m) * nd + hs) * nd  # Q(c, hs, .), flat
        if nd == 4:
            free = (
                (1 if open_mask[k, 0] else 0)
                | (2 if open_mask[k, 1] else 0)
                | (4 if open_mask[k, 2] else 0)
                | (8 if open_mask[k, 3] else 0)
            )
        else:
            free = 0
            for d in range(nd):
                if open_mask[k, d]:
                    free |= 1 << d
        explore = epsilon > 0.0 and ur[k, 0] < epsilon
        best = best_of(q_f, at, free, nd)
        ask[k] = choose(q_f, at, free, best, explore, ur[k, 1], True, nd)


@njit(cache=True, nogil=True, _nrt=False)
def update(q_f, n_f, at0, at1, legal1, reward, gamma, entry, nd):
    """The Q-learning update of one robot, on its tables flat (``q_f`` float64, ``n_f``
    int32): ``Q(s, a) <- Q(s, a) + (1/N) (r + gamma max_{a' legal} Q(s', a') - Q(s,
    a))``, ``Q(s, a)`` at ``at0`` and ``Q(s', .)`` at ``at1..at1+D-1`` (D ports:
    :func:`~qpatrol.engines.compiled.choice.ports_of` ``(entry, nd)``, 4 on a grid,
    whose ``entry`` is None), the greatest over the legal moves of s' (``legal1``, a
    mask of ports: :func:`best_of`). Returns ``(max Q(s', .), alpha, Q(s, a) before)``."""
    top = best_of(q_f, at1, legal1, ports_of(entry, nd))
    target = reward + gamma * top
    q_sa = q_f[at0]
    n_after = n_f[at0] + 1
    alpha = 1.0 / n_after
    q_f[at0] = q_sa + alpha * (target - q_sa)
    n_f[at0] = n_after
    return top, alpha, q_sa


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def learn(r, t, p, w, o, n_up, gamma, use_heading, q_f, n_f, slot_r):
    """The update of every robot of run ``r`` that made the move it chose, in robot
    order (:func:`update`; ``q_f``, ``n_f``: :func:`tables`; ``slot_r``: :func:`slots`,
    the row of the cell left first, then of the cell entered); Q-updates recorded as
    :meth:`qpatrol.measures.records.Recorder.updates` wants them. ``p``, ``w``, ``o``:
    the loop's ``Params``, ``Work`` and ``Out`` (:mod:`qpatrol.engines.compiled.bundles`).
    Returns the number of update rows now written."""
    nd = ports_of(p.entry, p.nbrs.shape[1])
    m = q_f.shape[0] // (w.prev_pos.shape[0] * nd * nd)
    for k in range(w.prev_pos.shape[0]):
        if not w.as_asked[k] or not w.choosing[k]:
            continue
        ca = w.prev_pos[k]
        ha = w.prev_head[k] if use_heading else 0
        aa = w.ask[k]
        cb = p.nbrs[ca, aa]
        hb = heading_of(p.entry, ca, aa) if use_heading else 0  # after the move
        at = (row(slot_r, k, ca, m) * nd + ha) * nd  # Q(ca, ha, .), flat
        at1 = (row(slot_r, k, cb, m) * nd + hb) * nd  # Q(cb, hb, .)
        legal1 = p.cell_moves[cb]
        reward = w.reward[k]
        top, alpha, q_sa = update(q_f, n_f, at + aa, at1, legal1, reward, gamma, p.entry, nd)
        if wanted(o, ca):
            ints = (r, t, k, ca, ha, aa, cb, hb, 1 if w.eaten[k] else 0)
            floats = (w.reward[k], alpha, q_sa, q_f[at + aa], gamma * top)
            n_up = record(o, n_up, ints, floats, q_f[at : at + nd])
    return n_up


@njit(cache=True, nogil=True, _nrt=False)
def learn_pending(r, t, p, s, w, o, n_up, gamma, use_heading, q_f, n_f, pend, slot_r):
    """:func:`learn` on a patrol graph with waypoints (``learner.pending_transitions``):
    a robot that chose a move and made it starts a decision (``pend`` int64 ``[K, 3]``:
    cell, heading, port; -1: none); one travelling its edge (``w.travel``) keeps it
    while it moves on as asked or waits; any other drops it. A decision whose robot has
    just entered a vertex completes: ``Q(s, a)`` of the decision is updated towards
    ``r + gamma max Q(s', .)``, ``r`` the reward of entering the vertex, ``s'`` (the
    vertex, the port arrived by); ``slot_r``: :func:`slots`. Returns the number of update
    rows now written."""
    nd = ports_of(p.entry, p.nbrs.shape[1])
    m = q_f.shape[0] // (w.prev_pos.shape[0] * nd * nd)
    for k in range(w.prev_pos.shape[0]):
        decided = w.as_asked[k] and w.choosing[k]
        keep = w.travel[k] >= 0 and pend[k, 0] >= 0 and (w.as_asked[k] or not w.moved[k])
        keep = keep and w.swapped[k] < 0  # (a robot that exchanged its task drops it)
        if not keep and not decided:
            pend[k, 0], pend[k, 1], pend[k, 2] = -1, -1, -1
        if decided:
            pend[k, 0], pend[k, 1], pend[k, 2] = w.prev_pos[k], w.prev_head[k], w.ask[k]
        if pend[k, 0] < 0 or not w.as_asked[k] or not p.target[s.pos[r, k]]:
            continue
        ca = pend[k, 0]
        ha = pend[k, 1] if use_heading else 0
        aa = pend[k, 2]
        pend[k, 0], pend[k, 1], pend[k, 2] = -1, -1, -1
        c_last, a_last = w.prev_pos[k], w.ask[k]  # the move into the vertex
        cb = p.nbrs[c_last, a_last]
        hb = heading_of(p.entry, c_last, a_last) if use_heading else 0
        at = (row(slot_r, k, ca, m) * nd + ha) * nd  # Q(ca, ha, .), flat
        at1 = (row(slot_r, k, cb, m) * nd + hb) * nd  # Q(cb, hb, .)
        reward = w.reward[k]
        top, alpha, q_sa = update(
            q_f, n_f, at + aa, at1, p.cell_moves[cb], reward, gamma, p.entry, nd
        )
        if wanted(o, ca):
            ints = (r, t, k, ca, ha, aa, cb, hb, 1 if w.eaten[k] else 0)
            floats = (reward, alpha, q_sa, q_f[at + aa], gamma * top)
            n_up = record(o, n_up, ints, floats, q_f[at : at + nd])
    return n_up
