"""The compiled engine: the whole time loop of a batch, scalar, in numba.

One call advances every run of a batch by a block of team steps, in place, on the same
arrays the numpy engine uses (:class:`qpatrol.world.State`, the strategy's arrays,
:class:`qpatrol.measures.Measures`, the trajectory ring), so everything after the loop
(summaries, files, checkpoints) is shared. Each step of a run reads like §3 of the
paper: the world finds each robot's open moves, the strategy chooses (its compiled
twin in :mod:`qpatrol.engines.compiled`, e.g. greedy over Q with ties and epsilon from
the run's uniforms), the team moves under the traffic rules of :mod:`qpatrol.world.traffic`,
each robot that entered a cell is paid, and the strategy learns (e.g. ``Q(s, a) <- Q(s,
a) + (1/N) (r + gamma max Q(s', .) - Q(s, a))``). The arithmetic is the numpy
engine's, operation for operation, so results are equal to the bit.

Covered: the strategies of :data:`qpatrol.engines.COMPILED_POLICIES`, any team size,
with or without battery, communication and collision avoidance (right of way, pushes,
station pockets and queues), episode quotas, and every recorder
(``record.trajectory``, ``record.transitions``, ``record.watch``,
``record.timeline``). Other strategies run on the numpy engine (see
:func:`qpatrol.engines.compiled_gap`).

A step is the world's phases, each a small compiled function in a module of
:mod:`qpatrol.engines.compiled` named for it, written once and called by the one loop,
:func:`run_block`: the step's uniforms (:mod:`~qpatrol.engines.compiled.pcg`: each
run's numpy PCG64 stream stepped in registers), the battery's
(:mod:`~qpatrol.engines.compiled.stations`: begin, asks, costs, stations), the moves
(:mod:`~qpatrol.engines.compiled.moves`: open moves, traffic.resolve, waits, the right
of way), entering cells and eating (:mod:`~qpatrol.engines.compiled.enter`), ending
episodes (:mod:`~qpatrol.engines.compiled.episodes`), the strategy's ``act``/``learn``
(``compiled/<strategy>.py``; the Q-learning choice and update are
:func:`qpatrol.engines.compiled.qlearning.choose` and ``update``), and the measures
(:mod:`~qpatrol.engines.compiled.observe`). Their arguments are bundled as the numpy
engine's objects are (:mod:`~qpatrol.engines.compiled.bundles`: ``Params``,
``World``, ``Meas``, ``Out``, ``Work``), the very arrays, so a phase names what it
reads. The phases are compiled as functions of their own, once for every
specialisation of the loop that calls them (numba inlining them into the loop made
its cold compile about a third longer; LLVM inlines the small ones back), and so are
the strategies' small helpers, but not the strategies' ``act``/``learn`` nor the
dispatch to them (:func:`compiled.act`): as calls, each passing the argument bundles,
the loop took twice the time a step.

The loop is compiled without numba's reference counting (``_nrt=False``): it
allocates nothing (its working arrays come from :func:`bundles.work`), and every call
of a strategy's ``act``/``learn`` would otherwise pay an atomic increment and decrement
per array argument, which made the loop several times slower. The compiler
specialises it (``SPEC_*``, a compile-time constant): for any strategy; and for
Q-learning without battery or timeline, where every branch on the spec leaves the
other strategies' and the battery's code out before numba types it (cold compile:
about a third of the general loop's).

The loop releases the GIL, and a batch's runs share nothing they write, so
:meth:`Loop.run` may advance them in lanes of consecutive runs, one thread each, each
lane with its own working arrays and output buffers (:mod:`qpatrol.engines.threads`).
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait

import numpy as np
from numba import njit
from numba.core.dispatcher import Dispatcher

from qpatrol.engines import compiled
from qpatrol.engines.compiled import (
    bundles,
    enter,
    episodes,
    fail,
    moves,
    observe,
    pcg,
    qlearning,
    stations,
)
from qpatrol.engines.compiled.choice import legal_bits, ports_of
from qpatrol.engines.compiled.pack import PER_RUN, Pack
from qpatrol.world import Params, State

#: Columns of the episode buffer: run, group, episode, start, dots, cells, states,
#: complete, t.
EP_COLS = 9
#: The compiled loops of :func:`run_block`, one machine code each (the value is the
#: ``ndim`` of its marker argument, so numba compiles and caches each apart and the
#: loop sees it as a constant): any strategy and setting; ``qlearning`` without battery
#: or timeline (the other strategies' and the battery's code left out); and, without
#: Q-update recorders either, a lone ``qlearning`` robot and a ``qlearning`` team, each
#: a loop of its own (:func:`_solo_qlearning`, :func:`_team_qlearning`).
SPEC_ANY = 1
SPEC_QLEARNING = 2
SPEC_QLEARNING_SOLO = 3
SPEC_QLEARNING_TEAM = 4
#: Each loop's name in :func:`qpatrol.engines.compiled_loop`.
SPEC_NAMES = {
    SPEC_ANY: "any",
    SPEC_QLEARNING: "qlearning",
    SPEC_QLEARNING_SOLO: "qlearning-solo",
    SPEC_QLEARNING_TEAM: "qlearning-team",
}
#: Columns of the Q-update buffers: ints run, step, agent, cell, heading, action,
#: next cell, next heading, dot; floats reward, alpha, q_before, q_after, bootstrap,
#: Q(s, N), Q(s, E), Q(s, S), Q(s, W) after the update (a graph's first four ports).
UP_INT, UP_FLOAT = 9, 9
#: Where :class:`Loop`'s arguments hold the output rows (``Out``) and the working arrays.
_OUT, _WORK = 6, 7


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _touch_tables(q_f, n_f):
    """Read a run's Q-table and visit counts (flat, float64 and int32) once, a cache line
    at a time, before the kernel's steps, and return a sum to store (so that the reads
    stay): a batch's runs take turns, a block of steps each, and a miss inside the
    steps waits on the choice of the next move."""
    warm = 0.0
    for x in range(0, q_f.shape[0], 8):  # float64, 8 to a 64-byte line
        warm += q_f[x]
    for x in range(0, n_f.shape[0], 16):  # int32, 16 to a line
        warm += n_f[x]
    return warm


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _solo_qlearning(r, t0, n_steps, words, p, s, m, o, sp, n_ep, w):
    """Run ``r`` of a batch of lone Q-learning robots (no battery, no recorder but the
    trajectory), advanced by up to ``n_steps`` steps after ``t0``: the phases of
    :func:`run_block` with what a robot alone cannot meet left out (no one else blocks
    it, waits or holds the right of way; its open moves are its legal ones), and the
    robot's cell, heading, episode counters and measures' sums kept in registers. Its
    uniforms come from its stream's state ``words[r]`` (:mod:`pcg`), stepped past the
    block's ``2 x n_steps`` draws. Returns ``(last team step taken, episode rows
    written)``."""
    gamma, epsilon, use_heading, q_f, n_f = qlearning.tables(sp, r)
    weights = (p.reward_w[r, 0], p.reward_w[r, 1], p.reward_w[r, 2])
    nbrs, cell_moves, warmup = p.nbrs, p.cell_moves, m.warmup
    nd = ports_of(p.entry, nbrs.shape[1])  # D ports (on a grid 4, a constant of the code)
    intruders = m.attack.shape[0] > 0
    warm = _touch_tables(q_f, n_f)
    for cc in range(s.last.shape[2]):
        warm += s.last[r, 0, cc] + m.last[r, cc]
    w.sink[0] = warm
    # the run's stream (PCG64, pcg): its state, its increment, the increment of two draws
    s_lo, s_hi, inc_lo, inc_hi = words[r, 0], words[r, 1], words[r, 2], words[r, 3]
    inc2_lo, inc2_hi = pcg.double_inc(inc_lo, inc_hi)
    grp = (s.dots[r, 0], s.last[r, 0], s.ep_seen[r, 0], s.ep_seen_state[r, 0])
    c0 = c = s.pos[r, 0]
    h = s.head[r, 0]
    # the episode's counters, stored before an episode ends and at the end
    cnt = (s.dots_left[r, 0], s.ep_dots[r, 0], s.ep_visits[r, 0])
    start, going = s.ep_start[r, 0], s.active[r]
    visits_r, window_visits_r = m.visits[r, 0], m.window_visits[r, 0]
    rows_r = observe.rows_of(m, r)
    sums = observe.sums_of(m, r)
    idle_sum, n_measured = m.idle_total[r], m.measured[r]
    # its task (to enter a target) ends with each move: the step it began, the longest
    # stretch without progress
    since, top_stall = s.since[r, 0], m.max_stall[r]
    t_end = t0
    # the best legal Q of the state the robot stands in, once known: a learning step
    # bootstraps from the very row the next step chooses from (the state reached), and
    # no update between them writes that row (a move leaves its cell)
    best = -np.inf
    known = False
    for i in range(n_steps):
        if not going:
            break
        t = t0 + i + 1
        # --- the robot chooses: greedy over its legal moves (qlearning.choose) --------
        hs = h if use_heading else 0
        at = (c * nd + hs) * nd  # Q(c, hs, .), flat
        legal = cell_moves[c]
        if not known:
            best = qlearning.best_of(q_f, at, legal, nd)
        # the step's two uniforms: the first for epsilon, the second to break ties
        a_lo, a_hi, s_lo, s_hi = pcg.two_steps(s_lo, s_hi, inc_lo, inc_hi, inc2_lo, inc2_hi)
        explore = epsilon > 0.0 and pcg.uniform(a_lo, a_hi) < epsilon
        u_tie = pcg.uniform(s_lo, s_hi)
        aa = qlearning.choose(q_f, at, legal, best, explore, u_tie, False, nd)
        if aa >= 0:  # --- it moves and enters c1 (a: the heading it enters with) --------
            c1 = nbrs[c, aa]
            a, _, cnt, reward = enter.enter(
                c, c1, -1, t, nbrs, p.entry, p.dot_value, grp, cnt, weights
            )
        if cnt[0] == 0 or (p.max_ep > 0 and t - start >= p.max_ep):  # --- episodes ---
            s.dots_left[r, 0], s.ep_dots[r, 0], s.ep_visits[r, 0] = cnt
            n_ep = episodes.end(r, t, p, s, o.ep_buf, n_ep, w.ended)
            cnt = (s.dots_left[r, 0], s.ep_dots[r, 0], s.ep_visits[r, 0])
            start, going = s.ep_start[r, 0], s.active[r]
        if aa >= 0:  # --- it learns (qlearning.update), the measures see the visit -----
            hb = a if use_heading else 0  # the state reached: (c1, hb)
            at1 = (c1 * nd + hb) * nd  # Q(c1, hb, .), flat
            legal1 = cell_moves[c1]
            best, _, _ = qlearning.update(
                q_f, n_f, at + aa, at1, legal1, reward, gamma, p.entry, nd
            )
            known = True  # the next choice's best: Q(c1, hb, .) over c1's legal moves
            sums = observe.visit(c1, t, warmup, p, rows_r, visits_r, window_visits_r, sums)
            if intruders:  # the arrival, then the departure (a lone robot)
                observe.arrive(r, c1, t, p.target, m)
                observe.leave(r, c, t, p.target, m)
            c = c1
            h = a
            since = t
        if t > warmup:
            idle_sum += p.n_targets * t - sums[0]
            n_measured += 1
            top_stall = max(top_stall, t - since)
        if o.tail_n > 0:
            o.tail_pos[r, (t - 1) % o.tail_n, 0] = c
        t_end = t
    pcg.store(words[r], s_lo, s_hi, (n_steps - (t_end - t0)) * 2)
    s.dots_left[r, 0], s.ep_dots[r, 0], s.ep_visits[r, 0] = cnt
    observe.store_sums(m, r, sums)
    m.idle_total[r], m.measured[r] = idle_sum, n_measured
    s.since[r, 0], m.max_stall[r] = since, top_stall
    if t_end > t0:  # the stores the steps left out
        s.pos[r, 0] = c
        s.head[r, 0] = h
        if p.avoid:
            s.occ[r, c0] = -1
            s.occ[r, c] = 0
        s.wait[r, 0] = 0
        s.steps_done[r] = t_end
        if t_end > warmup:
            m.max_wait[r] = max(m.max_wait[r], 0)
    return t_end, n_ep


@njit(cache=True, nogil=True, _nrt=False)
def _team_enters(r, k, c0, c1, t, learns, ha, aa, p, s, m, tables, sums):
    """Robot ``k`` of a Q-learning team (run ``r``) moved from cell ``c0`` into ``c1``
    at step ``t``: its dot group takes the visit (:func:`enter.group_enters`), it learns
    when it made the move it chose (``learns``; ``ha`` its heading before, ``aa`` that
    move; ``tables``: ``(gamma, use_heading, q_f, n_f)``, :func:`qlearning.update`),
    and the measures see the visit (:func:`observe.visit`, ``sums`` the run's). Returns
    ``(heading entered, sums)``."""
    g = 0 if p.communication else k
    a, _, reward = enter.group_enters(r, g, c0, c1, aa if learns else -1, t, p, s)
    if learns:
        gamma, use_heading, q_f, n_f = tables
        nd = ports_of(p.entry, p.nbrs.shape[1])
        hs = ha if use_heading else 0
        hb = a if use_heading else 0  # the state reached: (c1, hb), a the heading entered
        base = k * p.nbrs.shape[0]
        at0 = ((base + c0) * nd + hs) * nd + aa  # Q(c0, hs, aa), flat
        at1 = ((base + c1) * nd + hb) * nd  # Q(c1, hb, .)
        qlearning.update(q_f, n_f, at0, at1, p.cell_moves[c1], reward, gamma, p.entry, nd)
    rows_r = observe.rows_of(m, r)
    sums = observe.visit(c1, t, m.warmup, p, rows_r, m.visits[r, k], m.window_visits[r, k], sums)
    return a, sums


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _team_qlearning(r, t0, n_steps, words, p, s, m, o, sp, n_ep, w):
    """Run ``r`` of a batch of Q-learning teams (no battery, no recorder but the
    trajectory), advanced by up to ``n_steps`` team steps after ``t0``: the phases of
    :func:`run_block` with the battery's left out (every robot patrols and chooses;
    right of way by wait and turn alone), and the run's right of way and measures' sums
    kept in registers. A step in which every robot asks for a cell that is empty and
    that no other asks for (nine steps in ten for four robots on map_a) moves, enters,
    learns and measures each robot in one pass; any other step takes the traffic
    rules' passes (:func:`moves.resolve`). The uniforms come from the run's stream
    state ``words[r]`` (:mod:`pcg`), stepped past the block's ``2 x K x n_steps``
    draws. Returns ``(last team step taken, episode rows written)``."""
    n_agents, n_cells = s.pos.shape[1], p.nbrs.shape[0]
    nbrs, cell_moves, avoid = p.nbrs, p.cell_moves, p.avoid
    nd = ports_of(p.entry, nbrs.shape[1])  # D ports (on a grid 4, a constant of the code)
    want, ask, moved, as_asked = w.want, w.ask, w.moved, w.as_asked
    gamma, epsilon, use_heading, q_f, n_f = qlearning.tables(sp, r)
    tables = (gamma, use_heading, q_f, n_f)
    w.sink[0] = _touch_tables(q_f, n_f)  # (16 x 4 and 256 x 4: about 10 % faster)
    # the run's stream (PCG64, pcg): its state, its increment, the increment of two draws
    s_lo, s_hi, inc_lo, inc_hi = words[r, 0], words[r, 1], words[r, 2], words[r, 3]
    inc2_lo, inc2_hi = pcg.double_inc(inc_lo, inc_hi)
    pos_r, head_r, occ_r, wait_r = s.pos[r], s.head[r], s.occ[r], s.wait[r]
    # what only this kernel reads, in registers and stored at the end: the right of
    # way, the measures' sums
    tok, held = s.token[r], s.token_held[r]
    idle_sum, n_measured = m.idle_total[r], m.measured[r]
    sums = observe.sums_of(m, r)
    top_wait, wait_sum = m.max_wait[r], m.wait_total[r]
    top_stall, since_r = m.max_stall[r], s.since[r]
    waiting = 0  # robots waiting after the last step
    for k in range(n_agents):
        if wait_r[k] > 0:
            waiting += 1
    going = s.active[r]
    never = t0 + n_steps + 1
    deadline = episodes.deadline(s.ep_start[r], p.max_ep, never)
    t_end = t0
    t_next_mod = (t0 + 1) % n_agents  # t % n_agents of the first step
    for i in range(n_steps):
        if not going:
            break
        t = t0 + i + 1
        t_mod = t_next_mod
        t_next_mod = t_mod + 1 if t_mod + 1 < n_agents else 0  # (t + 1) % n_agents
        # --- each robot's open moves and its choice (world.begin_step, qlearning.act)
        for k in range(n_agents):
            c = pos_r[k]
            legal = cell_moves[c]
            free = legal
            if avoid:  # the legal moves into cells no robot stands in
                nb = nbrs[c]  # (a wall's -1 reads the last cell: masked by legal)
                if nd == 4:
                    taken = (
                        (1 if occ_r[nb[0]] >= 0 else 0)
                        | (2 if occ_r[nb[1]] >= 0 else 0)
                        | (4 if occ_r[nb[2]] >= 0 else 0)
                        | (8 if occ_r[nb[3]] >= 0 else 0)
                    )
                else:
                    taken = 0
                    for d in range(nd):
                        if occ_r[nb[d]] >= 0:
                            taken |= 1 << d
                free = legal & ~taken
                if k == tok:  # the holder: and those a push can make room for
                    for d in range(nd):
                        if (taken & legal) >> d & 1 and moves.pushable(r, c, nb[d], False, p, s, w):
                            free |= 1 << d
                if free == 0:  # base.prefer_open: every legal move where none is open
                    free = legal
            hs = head_r[k] if use_heading else 0
            at = ((k * n_cells + c) * nd + hs) * nd  # Q(c, hs, .), flat
            # the robot's two uniforms of the step (qlearning.choose)
            a_lo, a_hi, s_lo, s_hi = pcg.two_steps(s_lo, s_hi, inc_lo, inc_hi, inc2_lo, inc2_hi)
            explore = epsilon > 0.0 and pcg.uniform(a_lo, a_hi) < epsilon
            best = qlearning.best_of(q_f, at, free, nd)
            u_tie = pcg.uniform(s_lo, s_hi)
            aa = qlearning.choose(q_f, at, free, best, explore, u_tie, True, nd)
            ask[k] = aa
            want[k] = nbrs[c, aa] if aa >= 0 else -1
        # --- the moves: the common step, every robot asking for a cell that is empty
        # and that no other asks for (moves.clear), moves each robot as asked, enters,
        # learns and measures it in one pass, in robot order; any other step takes the
        # traffic rules' passes (every robot patrols: priority by the age of its task,
        # then turn). A robot that moved entered a target: its task (to enter one) ended
        handoff = -1
        clear = moves.clear(want, occ_r, avoid)
        # a step with no conflict after one in which no robot waited changes no wait
        unchanged = clear and waiting == 0
        if clear:
            for k in range(n_agents):
                c1 = want[k]
                moved[k] = as_asked[k] = w.progressed[k] = c1 >= 0
                if c1 < 0:
                    continue
                since_r[k] = t
                c0 = w.prev_pos[k] = pos_r[k]
                moves.step_into(k, c1, avoid, occ_r, pos_r)
                ha = head_r[k]
                head_r[k], sums = _team_enters(
                    r, k, c0, c1, t, True, ha, ask[k], p, s, m, tables, sums
                )
        else:
            for k in range(n_agents):
                w.prev_pos[k] = pos_r[k]
                w.prev_head[k] = head_r[k]
                moved[k] = False
                as_asked[k] = False
            handoff = moves.resolve(r, t, tok, t_mod, False, avoid, p, s, w)
            # each robot that moved enters its cell; one that made the move it chose
            # learns. Robot after robot: each touches only its group's dots and its own
            # Q-table, and the measures their own arrays, in robot order
            for k in range(n_agents):
                w.progressed[k] = moved[k]
                if moved[k]:
                    since_r[k] = t
                    c0, ha = w.prev_pos[k], w.prev_head[k]
                    head_r[k], sums = _team_enters(
                        r, k, c0, pos_r[k], t, as_asked[k], ha, ask[k], p, s, m, tables, sums
                    )
        observe.intruders(r, t, w.prev_pos, pos_r, moved, p.target, m, s.mode[r], False)
        waiting, longest = moves.waits(r, False, avoid, s, w, unchanged)
        if avoid:
            tok, held = moves.pass_token(r, t + 1, t_next_mod, tok, held, handoff, s, w)
        # --- episodes: all dots eaten, or too long -------------------------------------
        if episodes.due(t, deadline, s.dots_left[r]):
            n_ep = episodes.end(r, t, p, s, o.ep_buf, n_ep, w.ended)
            going = s.active[r]
            deadline = episodes.deadline(s.ep_start[r], p.max_ep, never)
        if t > m.warmup:
            idle_sum += p.n_targets * t - sums[0]
            n_measured += 1
            top_wait = max(top_wait, longest)
            wait_sum += waiting
            if not clear:  # (a clear step moves every robot that asked, as asked)
                m.interferences[r] += observe.blocked(w)
            for k in range(n_agents):
                top_stall = max(top_stall, t - since_r[k])
        observe.trail(r, t, pos_r, s.mode[r], o)
        t_end = t
    pcg.store(words[r], s_lo, s_hi, (n_steps - (t_end - t0)) * n_agents * 2)
    s.token[r], s.token_held[r] = tok, held
    observe.store_sums(m, r, sums)
    m.idle_total[r], m.measured[r] = idle_sum, n_measured
    m.max_wait[r], m.wait_total[r] = top_wait, wait_sum
    m.max_stall[r] = top_stall
    if t_end > t0:
        s.steps_done[r] = t_end
    return t_end, n_ep


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def run_block(spec_marker, t0, n_steps, words, p, code, sp, s, m, o, w):
    """Advance every active run by up to ``n_steps`` team steps after step ``t0``.

    ``spec_marker``: an int8 array whose ``ndim`` is the loop to compile (``SPEC_*``;
    :class:`Loop` picks it): numba compiles one machine code per value and sees it as
    a constant, so the code a loop never runs (other strategies, the battery, the
    timeline) is left out before typing. ``words``: uint64 ``[R, 4]``, each run's
    PCG64 state (:mod:`qpatrol.engines.compiled.pcg`), from which the loop draws each
    robot's two uniforms of each step, as the numpy engine's streams do, and which it
    steps past ``n_steps x K x 2`` draws. ``p``, ``s``, ``m``, ``o``, ``w``: the batch's
    constants, the world, the measures, the recorders and output rows, and the working
    arrays (:mod:`qpatrol.engines.compiled.bundles`), modified in place; ``code``,
    ``sp``: the strategy and its :class:`~qpatrol.engines.compiled.pack.Pack`. Ended
    episodes are written to ``o.ep_buf`` ``[E, EP_COLS]``; Q-updates of every robot
    (``o.record_all``) or of the ``o.watched`` cells go to ``o.up_int`` ``[U, UP_INT]``
    and ``o.up_float`` ``[U, UP_FLOAT]``; with ``o.tl_window`` > 0 each closed window of
    the idleness timeline is a row of ``o.tl_buf`` ``[W, 6]``.

    Each step of a run is the world's phases in the numpy engine's order
    (:func:`qpatrol.engines.numpy_loop.advance`): the step's uniforms
    (:func:`pcg.step_uniforms`), the battery's begin (:mod:`stations`), the open
    moves (:func:`moves.open_moves`), the strategy's choice (:func:`compiled.act`) and
    the battery's asks, the moves (:func:`moves.resolve`), entering cells
    (:func:`enter.all_enter`), the battery's costs and stations, waits and the right of
    way, episodes (:func:`episodes.step`), the strategy's learning
    (:func:`compiled.learn`) and the measures (:mod:`observe`).

    Returns ``(last team step taken by any run, episode rows, update rows written,
    timeline rows written)``.
    """
    spec = spec_marker.ndim  # a constant of the compiled code, one overload per value
    n_runs, n_agents = s.pos.shape
    battery, tl_window = p.battery, o.tl_window
    # Q-learning's loop has no battery or timeline: their code is left out where a test
    # names spec (numba prunes a branch on a constant it can see, not on a variable
    # given two values, such as these)
    if spec >= SPEC_QLEARNING:
        battery = False
        tl_window = 0
    n_cells = p.nbrs.shape[0]
    avoid = p.avoid
    for c in range(n_cells):
        w.parent[c] = -2
    t_end = t0
    n_ep = np.int64(0)
    n_up = 0
    n_tl = 0
    never = t0 + n_steps + 1
    for r in range(n_runs):
        if spec == SPEC_QLEARNING_SOLO:
            t_r, n_ep = _solo_qlearning(r, t0, n_steps, words, p, s, m, o, sp, n_ep, w)
            t_end = max(t_end, t_r)
            continue
        if spec == SPEC_QLEARNING_TEAM:
            t_r, n_ep = _team_qlearning(r, t0, n_steps, words, p, s, m, o, sp, n_ep, w)
            t_end = max(t_end, t_r)
            continue
        # the run's stream (PCG64, pcg): its state, its increment, that of two draws
        s_lo, s_hi, inc_lo, inc_hi = words[r, 0], words[r, 1], words[r, 2], words[r, 3]
        inc2_lo, inc2_hi = pcg.double_inc(inc_lo, inc_hi)
        when = episodes.deadline(s.ep_start[r], p.max_ep, never)
        if spec == SPEC_QLEARNING:  # (the tables flat: a reshape is a call)
            gamma, epsilon, use_heading, q_f, n_f = qlearning.tables(sp, r)
            slot_r = qlearning.slots(sp, r)  # (dense: the loops of their own read cells)
        sums = observe.sums_of(m, r)  # the measures' sums, in registers for the block
        rows_r = observe.rows_of(m, r)
        t_next_mod = (t0 + 1) % n_agents  # t % n_agents of the first step
        t_r = t0
        for i in range(n_steps):
            if not s.active[r]:
                break
            t = t0 + i + 1
            t_mod = t_next_mod
            t_next_mod = t_mod + 1 if t_mod + 1 < n_agents else 0  # (t + 1) % n_agents
            s_lo, s_hi = pcg.step_uniforms(
                (s_lo, s_hi, inc_lo, inc_hi, inc2_lo, inc2_hi), w.uniforms
            )
            tok = s.token[r]
            if spec == SPEC_ANY and battery:
                stations.begin(r, t, p, s, w)
                stations.close_tasks(r, t, p, s)
            moves.open_moves(r, tok, battery, avoid, p, s, w)
            if spec == SPEC_ANY and p.travels:
                moves.travellers(r, p, s, w)
            for k in range(n_agents):  # (a strategy that heads for a goal says which)
                w.aim[k] = -1
            if spec == SPEC_ANY:
                compiled.act(code, r, t, w.uniforms, battery, p, s, w, sp)
                tok = s.token[r]  # (walk followers exchanging plans pass it on)
                if p.travels:
                    if avoid and compiled.walk_follower(code):
                        moves.turn_round(r, p, s, w)
                    moves.travel_asks(w)
            else:  # (compiled.act of qlearning, the others' code not compiled)
                qlearning.act(
                    w.uniforms, s.pos[r], s.head[r], w.open_mask, w.choosing, w.ask,
                    epsilon, use_heading, q_f, slot_r, ports_of(p.entry, p.nbrs.shape[1]),
                )  # fmt: skip
            if spec == SPEC_ANY and battery:
                stations.ask(r, p, s, w)
            for k in range(n_agents):
                w.want[k] = p.nbrs[s.pos[r, k], w.ask[k]] if w.ask[k] >= 0 else -1
            moves.tasks(r, battery, p, s, w)
            plans = spec == SPEC_ANY and p.travels and compiled.keeps_plans(code)
            handoff = moves.resolve(r, t, tok, t_mod, battery, avoid, p, s, w, plans)
            if p.interaction == bundles.INTERFERENCE:
                moves.meet(r, t, p, s, w)
            swapped = handoff >= 0 and w.swapped[handoff] >= 0
            if swapped and p.travels:
                moves.turn_back(r, p, s, w)
            enter.all_enter(r, t, p, s, w)
            if spec == SPEC_ANY and battery:
                stations.pay(r, p, s, w)
                stations.end(r, p, s, w)
            moves.progress(r, t, p, s, w)
            waiting, longest = moves.waits(r, battery, avoid, s, w)
            if avoid and n_agents > 1:
                s.token[r], s.token_held[r] = moves.pass_token(
                    r, t + 1, t_next_mod, tok, s.token_held[r], handoff, s, w
                )
            s.steps_done[r] = t
            n_ep, when = episodes.step(r, t, p, s, o.ep_buf, n_ep, w.ended, when, never)
            if spec == SPEC_ANY:
                if swapped:
                    compiled.exchange(code, r, w, sp)
                n_up = compiled.learn(code, r, t, p, s, w, sp, o, n_up)
            else:
                n_up = qlearning.learn(r, t, p, w, o, n_up, gamma, use_heading, q_f, n_f, slot_r)
            if spec == SPEC_ANY and t == p.fail_at:  # robots fail, before the step is measured
                waiting, longest = fail.apply(r, s)
            # --- the measures (Measures.observe), the timeline, the trajectory ring ----
            for k in range(n_agents):
                if w.moved[k]:
                    c, vk, wk = s.pos[r, k], m.visits[r, k], m.window_visits[r, k]
                    sums = observe.visit(c, t, m.warmup, p, rows_r, vk, wk, sums)
            failing = spec == SPEC_ANY and t == p.fail_at
            observe.intruders_called(
                r, t, w.prev_pos, s.pos[r], w.moved, p.target, m, s.mode[r], failing
            )
            if spec == SPEC_ANY and tl_window > 0:
                n_tl = observe.timeline(
                    r, t, tl_window, s.pos[r], w.moved, p.target, p.n_targets, o, n_tl
                )
            if spec == SPEC_ANY and battery:
                stations.lowest_charge(r, s, m.min_charge)
            observe.step_measures(r, t, p.n_targets, sums[0], waiting, longest, m)
            if t > m.warmup:
                m.interferences[r] += observe.blocked(w)
                observe.stalls(r, t, s, m)
            observe.trail(r, t, s.pos[r], s.mode[r], o)
            t_r = t
        observe.store_sums(m, r, sums)
        # the stream stepped past the draws of the steps the run sat out
        pcg.store(words[r], s_lo, s_hi, (n_steps - (t_r - t0)) * n_agents * 2)
        t_end = max(t_end, t_r)
    return t_end, n_ep, n_up, n_tl


def _key_caches() -> None:
    """Key the cache of every compiled function of the loop that numba does not inline
    (the loop, the phases and strategies compiled as functions of their
    own) on every file of :mod:`qpatrol.engines.compiled` and this one
    (:func:`compiled.key_cache`): each inlines code of other files."""
    names = [m.name for m in pkgutil.iter_modules(compiled.__path__)]
    mods = [compiled, *(importlib.import_module(f"{compiled.__name__}.{n}") for n in names)]
    for mod in [*mods, sys.modules[__name__]]:
        for f in vars(mod).values():
            if (
                isinstance(f, Dispatcher)
                and f.py_func.__module__ == mod.__name__
                and f.targetoptions.get("inline") != "always"
            ):
                compiled.key_cache(f, __file__)


_key_caches()


class Loop:
    """The compiled loop over one batch: its constant arguments and its buffers, so a
    call costs little even for one team step (when a checkpointer wants every step).

    Args:
        state, p, strategy, measures, tail, rec: the objects the numpy loop uses too
            (their arrays are updated in place).
        max_steps: most team steps one :meth:`run` will be given.
        timeline: the idleness timeline, or None.
        words: the runs' streams, from which the loop draws its uniforms itself: their
            PCG64 states, uint64 ``[R, 4]`` (:meth:`qpatrol.world.rng.Streams.words`),
            the same array at every call, stepped in place by :meth:`run` (call
            ``words()`` again after anyone else drew from the streams).
    """

    #: Where :attr:`args` holds the output rows (``bundles.Out``).
    out_at = _OUT

    def __init__(
        self,
        state: State,
        p: Params,
        strategy,
        measures,
        tail,
        rec,
        max_steps: int,
        words: Callable[[], np.ndarray],
        timeline=None,
    ):
        s, m = state, measures
        self.state, self.p = s, p
        self.strategy = strategy
        self.code, self.pack = compiled.pack(strategy)
        n_runs, k = s.pos.shape
        self.timeline = timeline if timeline is not None and timeline.window else None
        self.spec = SPEC_ANY
        # (a graph with waypoints, whose learners decide at vertices: the general loop)
        plain = not p.battery and self.timeline is None and not p.failures_at
        plain = plain and p.onward is None and p.ball is None  # (no interference stops)
        # (tables kept lazily: the general loop, whose learner reads rows by cell)
        plain = plain and self.pack.slot.shape[2] == 1
        if self.code == compiled.QLEARNING and plain:
            self.spec = SPEC_QLEARNING
            if not rec.wants_updates:
                self.spec = SPEC_QLEARNING_SOLO if k == 1 else SPEC_QLEARNING_TEAM
        # the lone and team learners take a grid's headings as None (D = 4 a constant of
        # their code); the general loop and the recorders' take them as an array, as a
        # graph's: one machine code for grids and graphs, compiled once (a loop compiled
        # per kind of map costs a cold start its compile twice, for a few loads a step)
        fixed_d = self.spec in (SPEC_QLEARNING_SOLO, SPEC_QLEARNING_TEAM)
        entry = bundles.compiled_entry(p.neighbors, p.entry) if fixed_d else p.entry
        n_dots = int(p.has_dot.sum())
        shortest = -(-n_dots // k)
        if p.max_episode_steps:
            shortest = min(shortest, p.max_episode_steps)
        cap = n_runs * p.n_groups * (max_steps // max(1, shortest) + 1)
        watched = np.zeros(p.n_cells, dtype=bool)
        watched[rec.watch[(rec.watch >= 0) & (rec.watch < p.n_cells)]] = True
        rows = n_runs * k * max_steps if rec.wants_updates else 1
        # float64 [R, 3]: each run's reward weights (incremental value, idle horizon,
        # lambda), the same in every row unless the batch's rows differ
        reward_w = np.empty((n_runs, 3), dtype=np.float64)
        reward_w[:, 0] = p.incremental_value
        reward_w[:, 1] = p.idle_horizon
        reward_w[:, 2] = p.lambda_weight
        # uint64 [R, 4]: the runs' PCG64 states (rng.Streams.words), stepped as it draws
        self.words = words()
        battery = (p.battery, p.homes, p.home_dist, p.home_dir, p.nearest_home_dist)
        pockets = (p.depart_len, p.pocket_of, p.pocket_depth, p.pocket_entry)
        consts = (
            p.neighbors, p.wall_legal, legal_bits(p.neighbors),
            entry, p.dot_value, p.has_dot,
        )  # fmt: skip
        rules = (p.communication, p.avoid_collisions, p.diameter, p.max_episode_steps)
        bp = bundles.Params(
            *consts, np.int64(n_dots), reward_w, *rules, p.episodes, *battery, *pockets,
            p.capacity, p.margin, p.charge_steps, p.target, np.int64(p.n_targets),
            np.int64(p.failures_at), p.onward is not None,
            p.onward if p.onward is not None else np.full((1, 1), -1, dtype=np.int64),
            p.far_cells,
            p.ahead if p.ahead is not None else np.full((1, 1), -1, dtype=np.int64),
            *bundles.interaction_args(p),
        )  # fmt: skip
        bs = bundles.World(*(getattr(s, f) for f in bundles.World._fields))
        bm = bundles.Meas(
            m.last, m.last_sum, m.visits, m.window_visits, m.idle_total, m.worst, m.measured,
            m.gap_sum, m.gap_count, m.gap_max, m.max_wait, m.wait_total, m.warmup,
            m.min_charge, m.gap_sq, m.target_gap_sum, m.target_gap_count, m.cycle_start,
            m.cycle_seen, m.cycles, m.interferences, m.attack, np.int64(m.horizon),
            m.empty_since, m.random_missed, m.stretch_count, m.stretch_sum, m.stretch_equal,
            m.gaps, m.tail_departures, m.tail_missed, m.max_stall,
        )  # fmt: skip
        tail_pos = tail.pos if tail.n else np.zeros((1, 1, 1), dtype=np.int64)
        ups = (np.empty((rows, UP_INT), np.int64), np.empty((rows, UP_FLOAT), np.float64))
        ep_buf = np.empty((cap, EP_COLS), dtype=np.int64)
        tl = self._timeline_args(timeline, n_runs, max_steps)
        bo = bundles.Out(tail_pos, tail.n, ep_buf, rec.transitions, watched, *ups, *tl)
        self.args = (self.words, bp, self.code, self.pack, bs, bm, bo)
        self.args += (bundles.work(k, p.n_groups, p.n_cells, p.neighbors.shape[1]),)
        # the arrays with a leading runs axis, sliced for a call on some runs only
        owners = [s, m, tail] + ([timeline] if self.timeline is not None else [])
        self._per_run = {
            id(v)
            for o in owners
            for v in vars(o).values()
            if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == n_runs
        } | {id(reward_w), id(self.words)}
        # the strategy's per-run arrays (not its constants, however many rows they have;
        # nor a one-row placeholder)
        self.pack_per_run = [
            f
            for f, name in enumerate(Pack._fields)
            if name in PER_RUN and n_runs > 1 and self.pack[f].shape[0] == n_runs
        ]
        self.n_runs = n_runs
        self.spec_marker = np.zeros((1,) * self.spec, dtype=np.int8)
        self._lanes: list[tuple[int, tuple] | None] = [None]  # lane i > 0: (runs, args)

    def _timeline_args(self, tl, n_runs: int, max_steps: int) -> tuple:
        """The timeline's arrays (tiny dummies when it is off) and its row buffer."""
        if tl is None or not tl.window:
            one, row = np.zeros(1, dtype=np.int64), np.zeros((1, 1), dtype=np.int64)
            return (0, row, one, one, one, one, np.zeros((1, 6), dtype=np.int64))
        tl_buf = np.empty((n_runs * (max_steps // tl.window + 2), 6), dtype=np.int64)
        return (tl.window, tl.last, tl.last_sum, tl.idle_sum, tl.worst, tl.steps, tl_buf)

    def _lane_args(self, lane: int, rows: int | None = None) -> tuple:
        """The arguments of lane ``lane``: lane 0's are :attr:`args`; another lane has
        its own working arrays and output buffers (episode, Q-update and timeline rows,
        sized for ``rows`` runs), so that lanes may run at once (:meth:`run`)."""
        if lane == 0:
            return self.args
        while len(self._lanes) <= lane:
            self._lanes.append(None)
        have = self._lanes[lane]
        if have is None or have[0] < (rows or 1):
            n = rows or 1
            o = self.args[_OUT]
            bufs = {}
            for name in ("ep_buf", "up_int", "up_float", "tl_buf"):
                a = getattr(o, name)  # a buffer of rows: as many per run as lane 0's
                per_run = max(1, a.shape[0] // self.n_runs) if a.shape[0] > 1 else 0
                bufs[name] = np.empty((max(1, per_run * n), *a.shape[1:]), dtype=a.dtype)
            work = bundles.Work(*map(np.zeros_like, self.args[_WORK]))
            args = (*self.args[:_OUT], o._replace(**bufs), work)
            self._lanes[lane] = have = (n, args)
        return have[1]

    def _slice(self, a, lo: int, hi: int):
        """Argument ``a`` for batch rows ``lo..hi-1``: its per-run arrays (inside a
        bundle too) sliced."""
        if isinstance(a, Pack):
            pack = list(a)
            for f in self.pack_per_run:
                pack[f] = pack[f][lo:hi]
            return Pack(*pack)
        if isinstance(a, tuple):
            return type(a)(*(self._slice(x, lo, hi) for x in a))
        return a[lo:hi] if id(a) in self._per_run else a

    def _call(self, args: tuple, n: int, lo: int, hi: int) -> tuple[int, int, int, int]:
        """``run_block`` of ``n`` steps with a lane's ``args`` on batch rows ``lo..hi-1``,
        the rows of its output buffers renumbered to batch rows."""
        if (lo, hi) != (0, self.n_runs):
            args = tuple(self._slice(a, lo, hi) for a in args)
        t_end, n_ep, n_up, n_tl = run_block(self.spec_marker, self.t0, n, *args)
        if lo:
            o = args[_OUT]
            o.ep_buf[:n_ep, 0] += lo
            o.up_int[:n_up, 0] += lo
            o.tl_buf[:n_tl, 0] += lo
        return t_end, n_ep, n_up, n_tl

    def _lane(self, lane: int, n: int, lo: int, hi: int) -> tuple:
        """Run lane ``lane`` (batch rows ``lo..hi-1``) by ``n`` steps: ``(last step,
        episode rows, update int rows, update float rows, timeline rows)``, copies."""
        args = self._lane_args(lane)
        o = args[_OUT]
        t_end, n_ep, n_up, n_tl = self._call(args, n, lo, hi)
        return (
            max(self.t0, int(t_end)),
            o.ep_buf[:n_ep].copy(),
            o.up_int[:n_up].copy(),
            o.up_float[:n_up].copy(),
            o.tl_buf[:n_tl].copy(),
        )

    def run(
        self, n: int, lanes: list[tuple[int, int]]
    ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """Advance the batch by up to ``n`` team steps. ``lanes``: ``(lo, hi)``,
        consecutive ranges of rows covering the batch in order. With several lanes each
        runs in a thread of its own (the loop releases the GIL): the same numbers, as
        every run is computed alone, from its own stream.

        Returns ``(team steps taken, episode rows int [E, EP_COLS], Q-update rows int
        [U, UP_INT] and float [U, UP_FLOAT])`` (updates only as the recorder wants them);
        the loop stops early when every run has met its episode quota.
        """
        s, p = self.state, self.p
        self.t0 = t0 = s.t
        if len(lanes) == 1:
            done = [self._lane(0, n, *lanes[0])]
        else:
            for i, (lo, hi) in enumerate(lanes):
                self._lane_args(i, hi - lo)  # allocated here, not in the threads
            pool = _pool(len(lanes))
            futures = [pool.submit(self._lane, i, n, lo, hi) for i, (lo, hi) in enumerate(lanes)]
            try:
                done = [f.result() for f in futures]
            finally:  # an interrupt while waiting: the lanes still finish their calls
                wait(futures)
        t_end = max(d[0] for d in done)
        eps, ups_i, ups_f, tls = ([d[j] for d in done] for j in range(1, 5))
        if self.timeline is not None:
            for rows_tl in tls:
                self.timeline.add_rows(rows_tl)
        s.t = int(t_end)
        compiled.unpack(self.strategy, self.pack, s)
        sat_out(s, p)
        one = len(eps) == 1
        return (
            int(t_end) - t0,
            eps[0] if one else np.concatenate(eps),
            ups_i[0] if one else np.concatenate(ups_i),
            ups_f[0] if one else np.concatenate(ups_f),
        )


def sat_out(s: State, p: Params) -> None:
    """After a call of the compiled loop (or a step of the batched env): a run that
    stopped before the batch did (its episode quota met) sat out its last steps, as on
    the numpy engine: no wait, no token, and a robot leaving a station released it."""
    out = s.steps_done < s.t
    if out.any():
        s.wait[out] = 0
        if p.avoid_collisions and p.n_agents > 1:
            s.token[out] = -1
            s.token_held[out] = 0
        rows_out, ks = np.nonzero(out[:, None] & (s.depart_left > 0))
        s.reserved[rows_out, s.goal[rows_out, ks]] = -1
        s.goal[rows_out, ks] = -1
        s.depart_left[rows_out, ks] = 0


_POOLS: dict[int, ThreadPoolExecutor] = {}


def _pool(n: int) -> ThreadPoolExecutor:
    """A pool of ``n`` threads, kept for the process (lanes of every batch reuse it)."""
    if n not in _POOLS:
        _POOLS[n] = ThreadPoolExecutor(n, thread_name_prefix="qpatrol-lane")
    return _POOLS[n]
