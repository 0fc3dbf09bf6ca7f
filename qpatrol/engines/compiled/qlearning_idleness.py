"""``qlearning-idleness`` compiled: Q-learning paid the idleness of the cell entered.

The numpy twin is :mod:`qpatrol.strategies.qlearning_idleness` (arithmetic operation for
operation: state ``(cell, heading, idlest)``, the idlest neighbour's port, first in port
order (N, E, S, W on a grid); the reward ``min(cap, (t - last) / scale)`` or the dot
value; the choice greedy over ``r(s, a) + Q(s, a)`` (known reward) or ``Q(s, a)`` among
the open moves, ties and ``epsilon(t) = epsilon x max(0, 1 - t / explore_steps)`` from
the run's uniforms; ``Q(s,a) <- Q(s,a) + alpha (paid r + gamma max_{a' legal} [r(s', a')
+ Q(s', a')] - Q(s,a))``, robot by robot in robot order).

Pack (see :mod:`qpatrol.engines.compiled`):

* ``q`` float64 and ``n`` int32 ``[R, P, C, H * F, D]``: the strategy's own
  ``[R, P, C, H, F, D]`` tables as views (``P`` tables: 1 shared or one per robot; slot
  ``h * F + f`` for heading ``h`` and idlest port ``f``; ``D`` ports, 4 on a grid);
* ``cell_i`` int64 ``[R, G, C]``: the strategy's own last-visit maps (``last``);
* ``cell_b`` bool ``[R, G, C]``: the strategy's own dot maps (``dots``);
* ``robot_i`` int64 ``[R, K, 7]``: per robot, the idlest-neighbour slot at its last
  choice, the slot it would see next once its run stopped (episode quota), and the
  team step of its last choice (-1: none yet); :func:`unpack` makes ``feat`` of them;
  then its ``pending`` decision on a patrol graph with waypoints (cell, heading,
  idlest slot, port; -1: none), completed at the next vertex;
* ``cell_f`` float64 ``[R, 1, K]``: working array, the robots' rewards of this step,
  a row per run (per-run like the tables, so that the runs of a batch share nothing
  they write and may run in threads at once: :mod:`qpatrol.engines.threads`);
* ``fpar = [gamma, alpha, epsilon, cap, scale]``;
* ``ipar = [explore_steps, reward is dot, known reward, use heading, use idlest,
  shared table, F]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from qpatrol.engines.compiled.choice import greatest, heading_of
from qpatrol.engines.compiled.pack import Pack, dummy_pack
from qpatrol.engines.compiled.updates import record, wanted

GAMMA, ALPHA, EPSILON, CAP, SCALE = range(5)
EXPLORE_STEPS, DOT, KNOWN, USE_HEADING, USE_IDLE, SHARED, N_FEAT = range(7)


def _slots(a: np.ndarray) -> np.ndarray:
    """A ``[R, P, C, H, F, D]`` table as the view ``[R, P, C, H * F, D]``."""
    r, p, c, h, f, d = a.shape
    v = a.reshape(r, p, c, h * f, d)
    if not np.shares_memory(v, a):
        raise ValueError("qlearning-idleness: the Q-table is not C-contiguous")
    return v


def pack(strategy) -> Pack:
    """The compiled arrays of a :class:`qpatrol.strategies.qlearning_idleness.Strategy`
    (its own ``q``, ``n``, ``last`` and ``dots``, updated in place; a copy of
    ``feat``)."""
    s = strategy
    return dummy_pack(
        fpar=np.array([s.gamma, s.alpha, s.epsilon, s.cap, s.scale], dtype=np.float64),
        ipar=np.array(
            [
                s.explore_steps,
                s.reward_kind == "dot",
                s.known,
                s.use_heading,
                s.use_idle,
                s.shared,
                s.q.shape[4],
            ],
            dtype=np.int64,
        ),
        q=_slots(s.q),
        n=_slots(s.n),
        cell_i=s.last,
        cell_b=s.dots,
        robot_i=np.concatenate(
            [np.stack([s.feat, s.feat, np.full_like(s.feat, -1)], axis=2), s.pending], axis=2
        ).astype(np.int64),
        cell_f=np.zeros((s.q.shape[0], 1, s.n_agents), dtype=np.float64),
    )


def unpack(p: Pack, strategy) -> None:
    """Set ``feat`` as the numpy engine leaves it (``q``, ``n``, ``last`` and ``dots``
    are the strategy's own): the slots of the last choice, except in runs that stopped
    before the batch's last step, where the numpy engine went on computing the slots
    (of the final maps) at every step the batch took."""
    f = p.robot_i
    t_last = f[:, :, 2].max(initial=-1)
    strategy.feat = np.where(f[:, :, 2] == t_last, f[:, :, 0], f[:, :, 1])
    strategy.pending = f[:, :, 3:7].copy()


def sat_out(strategy, state) -> None:
    """A run that stopped before the batch's last step (episode quota) dropped its
    robots' pending decisions in the steps it sat out (the numpy engine's learn)."""
    strategy.pending[state.steps_done < state.t] = -1


@njit(cache=True, nogil=True, _nrt=False)
def _idlest(nbrs, last, r, g, c):
    """Port of the non-wall neighbour of ``c`` visited longest ago on map ``g``
    (``last`` int ``[R, G, C]``), first in port order (N, E, S, W); 0 without a
    neighbour."""
    best = np.iinfo(np.int64).max
    f = 0
    for d in range(nbrs.shape[1]):
        nb = nbrs[c, d]
        if nb >= 0 and last[r, g, nb] < best:
            best = last[r, g, nb]
            f = d
    return f


@njit(cache=True, nogil=True, _nrt=False)
def _reward(sp, dot_value, r, g, c, t):
    """The reward of entering ``c`` at team step ``t`` on map ``g`` as it stands
    (``Strategy.reward_of``)."""
    if sp.ipar[DOT] != 0:
        return dot_value[c] if sp.cell_b[r, g, c] else 0.0
    return min(sp.fpar[CAP], (t - sp.cell_i[r, g, c]) / sp.fpar[SCALE])


@njit(cache=True, nogil=True, _nrt=False)
def _score(sp, dot_value, nbrs, r, g, pk, c, slot, d, t):
    """``Q(s, d) + r(s, d)`` (the reward only with ``qidle.known_reward``) of robot state
    ``(c, slot)`` on table ``pk``, map ``g`` (a wall reads cell 0; it is never chosen,
    as in ``Strategy.known_rewards``)."""
    q = sp.q[r, pk, c, slot, d]
    if sp.ipar[KNOWN] == 0:
        return q + 0.0
    return q + _reward(sp, dot_value, r, g, max(nbrs[c, d], 0), t)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def act(r, t, ur, nbrs, dot_value, communication, pos, head, open_mask, choosing, ask, sp, score_k):
    """``ask[k]`` for every choosing robot of run ``r`` at team step ``t`` (``ur``
    float ``[K, 2]``: the step's uniforms): the open move of greatest ``r(s, a) +
    Q(s, a)`` (ties by ``ur[k, 1]``; with probability ``epsilon(t)`` (``ur[k,
    0]``) any open move), -1 where there is none. Every robot's idlest slot goes to
    ``robot_i[r, k, 0]``. ``score_k`` float64 ``[K, D]``: scratch."""
    feat, ipar = sp.robot_i, sp.ipar
    use_heading = ipar[USE_HEADING] != 0
    use_idle = ipar[USE_IDLE] != 0
    shared = ipar[SHARED] != 0
    n_feat = ipar[N_FEAT]
    epsilon = 0.0
    if ipar[EXPLORE_STEPS] > 0:
        epsilon = sp.fpar[EPSILON] * max(0.0, 1.0 - t / ipar[EXPLORE_STEPS])
    for k in range(pos.shape[1]):
        c = pos[r, k]
        g = 0 if communication else k
        f = _idlest(nbrs, sp.cell_i, r, g, c) if use_idle else 0
        feat[r, k, 0] = f
        feat[r, k, 2] = t
        if not choosing[k]:
            ask[k] = -1
            continue
        pk = 0 if shared else k
        slot = (head[r, k] if use_heading else 0) * n_feat + f
        score = score_k[k]
        for d in range(nbrs.shape[1]):
            score[d] = _score(sp, dot_value, nbrs, r, g, pk, c, slot, d, t)
        explore = epsilon > 0.0 and ur[k, 0] < epsilon
        ask[k] = greatest(score, open_mask, k, explore, ur[k, 1])


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def learn(r, t, p, s, w, sp, o, n_up):
    """After team step ``t`` of run ``r``: pay the robots that entered a cell, update the
    maps (``Strategy.rewards``), then the Q-update of every robot that made the move it
    chose, in robot order, recorded as :meth:`qpatrol.measures.records.Recorder.updates` wants
    them. ``p``, ``s``, ``w``, ``o``: the loop's ``Params``, ``World``, ``Work`` and
    ``Out`` (:mod:`qpatrol.engines.compiled.bundles`); ``w.ended`` bool ``[G]``: the
    group's episode ended (every dot back); ``s.active`` bool ``[R]``: a run that
    stopped keeps the slots its robots would see next. Returns the number of update
    rows now written."""
    nbrs, wall_legal, dot_value, has_dot = p.far, p.wall_legal, p.dot_value, p.has_dot
    communication, pos, active, moved, ended = p.communication, s.pos, s.active, w.moved, w.ended
    prev_pos, prev_head, ask, as_asked, choosing = (
        w.prev_pos,
        w.prev_head,
        w.ask,
        w.as_asked,
        w.choosing,
    )
    q, n, last, dots, feat, rew = sp.q, sp.n, sp.cell_i, sp.cell_b, sp.robot_i, sp.cell_f
    fpar, ipar = sp.fpar, sp.ipar
    n_agents = pos.shape[1]
    for k in range(n_agents):  # Strategy.rewards, robot by robot as the world
        rew[r, 0, k] = 0.0
        if not moved[k]:
            continue
        c = pos[r, k]
        g = 0 if communication else k
        rew[r, 0, k] = _reward(sp, dot_value, r, g, c, t)
        last[r, g, c] = t
        dots[r, g, c] = False
    for g in range(ended.shape[0]):
        if ended[g]:
            for c in range(has_dot.shape[0]):
                dots[r, g, c] = has_dot[c]
    use_heading = ipar[USE_HEADING] != 0
    use_idle = ipar[USE_IDLE] != 0
    if not active[r]:  # the numpy engine keeps choosing (nothing) on the final maps
        for k in range(n_agents):
            g = 0 if communication else k
            feat[r, k, 1] = _idlest(nbrs, last, r, g, pos[r, k]) if use_idle else 0
    shared = ipar[SHARED] != 0
    n_feat = ipar[N_FEAT]
    gamma, alpha_par = fpar[GAMMA], fpar[ALPHA]
    paid = 0.0 if ipar[KNOWN] != 0 else 1.0
    for k in range(n_agents):  # a shared entry sees every update
        decided = as_asked[k] and choosing[k]
        ca, ha, fa, aa = prev_pos[k], prev_head[k], feat[r, k, 0], ask[k]
        if p.travels:  # decisions at a graph's vertices (learner.pending_transitions)
            keep = w.travel[k] >= 0 and feat[r, k, 3] >= 0 and (as_asked[k] or not moved[k])
            keep = keep and w.swapped[k] < 0  # (a robot that exchanged its task drops it)
            if not keep and not decided:
                for j in range(3, 7):
                    feat[r, k, j] = -1
            if decided:
                feat[r, k, 3], feat[r, k, 4], feat[r, k, 5], feat[r, k, 6] = ca, ha, fa, aa
            if feat[r, k, 3] < 0 or not as_asked[k] or not p.target[pos[r, k]]:
                continue
            ca, ha, fa, aa = feat[r, k, 3], feat[r, k, 4], feat[r, k, 5], feat[r, k, 6]
            for j in range(3, 7):
                feat[r, k, j] = -1
        elif not decided:
            continue
        pk = 0 if shared else k
        g = 0 if communication else k
        ha = ha if use_heading else 0
        sa = ha * n_feat + fa
        cb = pos[r, k]
        # the heading after the move into cb
        hb = heading_of(p.entry, prev_pos[k], ask[k]) if use_heading else 0
        sb = hb * n_feat + (_idlest(nbrs, last, r, g, cb) if use_idle else 0)
        top = -np.inf
        for d in range(nbrs.shape[1]):
            if wall_legal[cb, d]:
                v = _score(sp, dot_value, nbrs, r, g, pk, cb, sb, d, t + 1)
                if v > top:
                    top = v
        bootstrap = gamma * top
        target = paid * rew[r, 0, k] + bootstrap
        q_sa = q[r, pk, ca, sa, aa]
        n_after = n[r, pk, ca, sa, aa] + 1
        alpha = alpha_par if alpha_par > 0 else 1.0 / n_after
        q[r, pk, ca, sa, aa] = q_sa + alpha * (target - q_sa)
        n[r, pk, ca, sa, aa] = n_after
        if wanted(o, ca):
            ints = (r, t, k, ca, ha, aa, cb, hb, 1 if w.eaten[k] else 0)
            floats = (rew[r, 0, k], alpha, q_sa, q[r, pk, ca, sa, aa], bootstrap)
            n_up = record(o, n_up, ints, floats, q[r, pk, ca, sa])
    return n_up
