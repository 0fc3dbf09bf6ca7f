"""The compiled engine: the whole time loop of a batch, scalar, in numba.

One call advances every run of a batch by a block of team steps, in place, on the same
arrays the numpy engine uses (:class:`qpatrol.world.State`, the strategy's arrays,
:class:`qpatrol.measures.Measures`, the trajectory ring), so everything after the loop
(summaries, files, checkpoints) is shared. Each step of a run reads like §3 of the
paper: the world finds each robot's open moves, the strategy chooses (its compiled
twin in :mod:`qpatrol.engines.compiled`, e.g. greedy over Q with ties and epsilon from
the run's uniforms), the team moves under the traffic rules of :mod:`qpatrol.traffic`,
each robot that entered a cell is paid, and the strategy learns (e.g. ``Q(s, a) <- Q(s,
a) + (1/N) (r + gamma max Q(s', .) - Q(s, a))``). The arithmetic is the numpy
engine's, operation for operation, so results are equal to the bit.

Covered: the strategies of :data:`qpatrol.engines.COMPILED_POLICIES`, any team size,
with or without battery, communication and collision avoidance (right of way, pushes,
station pockets and queues), episode quotas, and every recorder
(``record.trajectory``, ``record.transitions``, ``record.watch``,
``record.timeline``). Other strategies run on the numpy engine (see
:func:`qpatrol.engines.compiled_gap`).

The loop is compiled without numba's reference counting (``_nrt=False``): it
allocates nothing (its working arrays come from :func:`scratch`), and every call of a
strategy's ``act``/``learn`` would otherwise pay an atomic increment and decrement per
array argument, which made the loop several times slower. It is compiled four times
(``SPEC_*``): for any strategy; for Q-learning without battery or timeline, with the
rest left out; and for Q-learning without battery, timeline or Q-update recorders, whose
steps run in a kernel of their own, one for a lone robot (:func:`_solo_qlearning`, its
state in registers: twice the speed of the general loop) and one for teams
(:func:`_team_qlearning`, the battery's rules left out, a step without conflicts in one
pass over the robots: about twice). Both draw their uniforms themselves, stepping each
run's PCG64 state with numpy's arithmetic (:mod:`qpatrol.engines.compiled.pcg`); the
other loops read them from blocks drawn beforehand.

The loop releases the GIL, and a batch's runs share nothing they write, so
:meth:`Loop.run` may advance them in lanes of consecutive runs, one thread each, each
lane with its own working arrays and output buffers (:mod:`qpatrol.engines.threads`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor, wait

import numpy as np
from numba import njit

from qpatrol.engines import compiled
from qpatrol.engines.compiled import pcg
from qpatrol.engines.compiled.choice import MASKED, POPCOUNT, legal_bits, pick
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
#: in its own kernel (:func:`_solo_qlearning`, :func:`_team_qlearning`).
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
#: Q(s, N), Q(s, E), Q(s, S), Q(s, W) after the update.
UP_INT, UP_FLOAT = 9, 9


PATROL, HOMING, QUEUED, CHARGING = 0, 1, 2, 3  # battery.PATROL ...


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _priority(wait, mode, depart_left, k, n_agents, t_mod):
    """:func:`qpatrol.traffic.priority` of robot k at step t (``t_mod = t % n_agents``,
    taken once per step: an integer division per robot cost more than the rest of
    this): class, then wait, then turn ``(n_agents - 1) - (k - t) % n_agents``."""
    if depart_left > 0:
        cls = 3
    elif mode == HOMING:
        cls = 2
    elif mode == PATROL:
        cls = 1
    else:
        cls = 0
    back = k - t_mod  # (k - t) % n_agents, without a division
    if back < 0:
        back += n_agents
    turn = (n_agents - 1) - back
    return cls * (1 << 40) + min(wait, 1 << 30) * n_agents + turn


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _kept_out(c, pocket_of, reserved_r):
    """:func:`qpatrol.battery.held_pockets`: cell c lies in the pocket of a held station."""
    h = pocket_of[c]
    return h >= 0 and reserved_r[h] >= 0


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _way_out(nbrs, pocket_of, pocket_depth, pocket_entry, occ_r, c, station):
    """:func:`qpatrol.battery.way_out` of a robot on cell c (-1: none)."""
    if station < 0:
        return -1
    h = station
    if pocket_of[c] == h:
        for d in range(4):
            nb = nbrs[c, d]
            if nb >= 0 and (pocket_of[nb] != h or pocket_depth[nb] < pocket_depth[c]):
                return d
        return -1
    if c != pocket_entry[h]:
        return -1
    for d in range(4):
        nb = nbrs[c, d]
        if nb >= 0 and pocket_of[nb] != h and occ_r[nb] < 0:
            return d
    for d in range(4):
        nb = nbrs[c, d]
        if nb >= 0 and pocket_of[nb] != h:
            return d
    return -1


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _push_path(
    nbrs, occ_r, own, start, parent, seen, queue, path, battery, mode_r, pocket_of, reserved_r
):
    """Breadth-first from ``start`` to the nearest empty cell, never through ``own``,
    charging robots, nor (battery on) cells of held pockets.

    Fills ``path[:m]`` with ``[start, ..., empty]`` and returns m (0: none). ``parent``
    and ``seen`` are scratch arrays ``[C]`` left clean on return.
    """
    if battery and mode_r[occ_r[start]] == CHARGING:
        return 0
    n_seen = 0
    seen[n_seen] = start
    n_seen += 1
    parent[start] = -1
    head = 0
    tail = 0
    queue[tail] = start
    tail += 1
    m = 0
    while head < tail and m == 0:
        c = queue[head]
        head += 1
        for d in range(4):
            nb = nbrs[c, d]
            if nb < 0 or nb == own or parent[nb] != -2:
                continue
            if battery:
                if _kept_out(nb, pocket_of, reserved_r):
                    continue
                j = occ_r[nb]
                if j >= 0 and mode_r[j] == CHARGING:
                    continue
            parent[nb] = c
            seen[n_seen] = nb
            n_seen += 1
            if occ_r[nb] < 0:
                x = nb
                while x != start:
                    path[m] = x
                    m += 1
                    x = parent[x]
                path[m] = start
                m += 1
                break
            queue[tail] = nb
            tail += 1
    for i in range(n_seen):
        parent[seen[i]] = -2
    # reverse to start -> empty
    for i in range(m // 2):
        path[i], path[m - 1 - i] = path[m - 1 - i], path[i]
    return m


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _holder_moves(
    tok,
    nbrs,
    occ_r,
    pos_r,
    want,
    moved,
    as_asked,
    parent,
    seen,
    queue,
    path,
    battery,
    mode_r,
    pocket_of,
    reserved_r,
):
    """:func:`qpatrol.traffic.holder_step` of the right-of-way holder ``tok`` of a run
    (``want[tok] >= 0``; ``occ_r``, ``pos_r`` its rows): into the cell it asks for, or
    else a neighbour (N, E, S, W), empty or emptied by pushing the robots in the way
    along :func:`_push_path`. Returns whether the push failed (it did not move as
    asked)."""
    own = pos_r[tok]
    dest = -1
    m = 0
    for ci in range(5):
        if ci == 0:
            cell = want[tok]
        else:
            cell = nbrs[own, ci - 1]
            if cell < 0 or cell == want[tok]:
                continue
            if battery and _kept_out(cell, pocket_of, reserved_r):
                continue
        if occ_r[cell] < 0:
            dest = cell
            m = 0
            break
        m = _push_path(
            nbrs,
            occ_r,
            own,
            cell,
            parent,
            seen,
            queue,
            path,
            battery,
            mode_r,
            pocket_of,
            reserved_r,
        )
        if m > 0:
            dest = cell
            break
    if dest < 0:
        return True
    for x in range(m - 2, -1, -1):
        jr = occ_r[path[x]]
        occ_r[pos_r[jr]] = -1
        occ_r[path[x + 1]] = jr
        pos_r[jr] = path[x + 1]
        moved[jr] = True
        as_asked[jr] = want[jr] == path[x + 1]
    occ_r[pos_r[tok]] = -1
    occ_r[dest] = tok
    pos_r[tok] = dest
    moved[tok] = True
    as_asked[tok] = dest == want[tok]
    return not as_asked[tok]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _sort_by_key(order, key, n):
    """Sort the robots ``order[:n]`` by ``key`` (indexed by robot), largest first, equal
    keys keeping their places: an insertion sort (a team has a few robots)."""
    for a in range(1, n):
        x = order[a]
        b = a - 1
        while b >= 0 and key[order[b]] < key[x]:
            order[b + 1] = order[b]
            b -= 1
        order[b + 1] = x


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _move_in_order(order, want, moved, as_asked, occ_r, pos_r):
    """Step 2 of :func:`qpatrol.traffic.resolve`: the robots that have not moved, in
    ``order``, each into the cell it wants if that cell is empty at that moment, pass
    after pass until a pass moves no one or leaves no one behind."""
    progress = True
    while progress:
        progress = False
        behind = False
        for a in range(order.shape[0]):
            k = order[a]
            w = want[k]
            if w >= 0 and not moved[k]:
                if occ_r[w] < 0:
                    occ_r[pos_r[k]] = -1
                    occ_r[w] = k
                    pos_r[k] = w
                    moved[k] = True
                    as_asked[k] = True
                    progress = True
                else:
                    behind = True
        progress = progress and behind


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _pass_token(
    tok,
    held,
    push_failed,
    want,
    as_asked,
    blocked_by,
    wait_r,
    mode_r,
    depart_left_r,
    t_next_mod,
    diameter,
):
    """:func:`qpatrol.traffic.pass_token` of a run after its moves: the holder keeps the
    right of way while it moves as asked (at most ``diameter`` steps); a holder whose
    push failed hands it to the robot that blocked it, if that one waits; else it goes
    to the waiting robot of highest priority at the next step (none: -1). Returns
    ``(holder, steps it has held it)``."""
    n_agents = want.shape[0]
    best_k = -1
    best_key = -1
    for k in range(n_agents):
        kk = -1
        if want[k] >= 0 and not as_asked[k]:
            kk = _priority(wait_r[k], mode_r[k], depart_left_r[k], k, n_agents, t_next_mod)
        if tok >= 0 and push_failed and k == tok:
            kk = -1
        if kk > best_key:
            best_key = kk
            best_k = k
    new = best_k
    if tok >= 0:
        blocker = blocked_by[tok]
        blocker_waits = blocker >= 0 and want[blocker] >= 0 and not as_asked[blocker]
        if as_asked[tok] and held < diameter:
            new = tok
        elif push_failed and blocker_waits:
            new = blocker
    return new, (held + 1 if (new == tok and new >= 0) else 0)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _end_episodes(
    r,
    t,
    has_dot,
    n_dots,
    max_ep,
    quota,
    dots,
    dots_left,
    ep_dots,
    ep_visits,
    ep_start,
    ep_count,
    ep_seen,
    ep_seen_state,
    active,
    ep_buf,
    n_ep,
    ended,
):
    """Episodes of run ``r`` at step ``t``: each group whose dots are all eaten, or whose
    episode reached ``max_ep`` steps, ends (a row of ``ep_buf``; its dots put back) and
    ``ended[g]`` says so; a run that met its episode ``quota`` stops. Returns the number
    of episode rows now written."""
    n_cells = has_dot.shape[0]
    ended_any = False
    for g in range(dots.shape[1]):
        ended[g] = False
        complete = dots_left[r, g] == 0
        if not (complete or (max_ep > 0 and t - ep_start[r, g] >= max_ep)):
            continue
        ended_any = True
        ended[g] = True
        cells = 0
        states = 0
        for c in range(n_cells):
            if ep_seen[r, g, c]:
                cells += 1
            for d in range(4):
                if ep_seen_state[r, g, c, d]:
                    states += 1
                ep_seen_state[r, g, c, d] = False
            ep_seen[r, g, c] = False
            dots[r, g, c] = has_dot[c]
        row = ep_buf[n_ep]
        row[0] = r
        row[1] = g
        row[2] = ep_count[r, g]
        row[3] = ep_start[r, g]
        row[4] = ep_dots[r, g]
        row[5] = cells
        row[6] = states
        row[7] = 1 if complete else 0
        row[8] = t
        n_ep += 1
        dots_left[r, g] = n_dots
        ep_dots[r, g] = 0
        ep_visits[r, g] = 0
        ep_start[r, g] = t
        ep_count[r, g] += 1
    if ended_any and quota > 0:
        low = ep_count[r, 0]
        for g in range(1, dots.shape[1]):
            low = min(low, ep_count[r, g])
        active[r] = low < quota
    return n_ep


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _ep_deadline(ep_start_r, max_ep, never):
    """The first step at which an episode of a run (its groups' start steps
    ``ep_start_r`` ``[G]``) reaches ``max_ep`` steps; ``never`` without a limit."""
    if max_ep <= 0:
        return never
    first = ep_start_r[0]
    for g in range(1, ep_start_r.shape[0]):
        first = min(first, ep_start_r[g])
    return first + max_ep


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _enter(
    c0,
    c1,
    asked,
    t,
    nbrs,
    dot_value,
    dots_g,
    last_g,
    seen_g,
    seen_state_g,
    left,
    eaten,
    entered,
    inc,
    horizon,
    lam,
):
    """A robot of a dot group moves from cell ``c0`` into ``c1`` at step ``t``: the
    group's dots (``dots_g`` ``[C]``), last visits (``last_g`` ``[C]``), cells and states
    seen this episode (``seen_g`` ``[C]``, ``seen_state_g`` ``[C, 4]``) and its
    episode's counters (dots ``left``, ``eaten``, cells ``entered``) take the visit.
    Returns ``(heading entered, dot eaten, left, eaten, entered, reward)``, the reward
    ``dot + inc min(1, idle / horizon) + lam eaten / entered``."""
    if asked >= 0:  # it moved as asked: the first direction into c1 is at most that one
        nb = nbrs[c0]
        a = asked
        a = 2 if (nb[2] == c1) & (asked > 2) else a
        a = 1 if (nb[1] == c1) & (asked > 1) else a
        a = 0 if (nb[0] == c1) & (asked > 0) else a
    else:
        a = 0
        for d in range(4):
            if nbrs[c0, d] == c1:
                a = d
                break
    ate = dots_g[c1]
    dots_g[c1] = False
    if ate:
        left -= 1
        eaten += 1
    entered += 1
    idle = t - last_g[c1]
    last_g[c1] = t
    seen_g[c1] = True
    seen_state_g[c1, a] = True
    reward = (
        (dot_value[c1] if ate else 0.0) + inc * min(1.0, idle / horizon) + lam * eaten / entered
    )
    return a, ate, left, eaten, entered, reward


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _observe(
    c,
    t,
    warmup,
    m_last_r,
    visits_k,
    window_visits_k,
    last_sum,
    gap_sum,
    gap_count,
    gap_max,
    worst,
):
    """Measures.observe of a robot's visit to cell ``c`` at step ``t``: the run's last
    visits (``m_last_r`` ``[C]``) and the robot's visit counts (``visits_k``,
    ``window_visits_k`` ``[C]``) take it; returns the run's ``(last_sum, gap_sum,
    gap_count, gap_max, worst)`` updated (inside the window, step ``t`` > ``warmup``,
    with the visit's gap and the worst idleness it ends)."""
    prev = m_last_r[c]
    m_last_r[c] = t
    last_sum += t - prev
    visits_k[c] += 1
    if t > warmup:
        window_visits_k[c] += 1
        gap = t - prev if prev > 0 else 0
        gap_sum += gap
        if prev > 0:
            gap_count += 1
        gap_max = max(gap_max, gap)
        if t - 1 > warmup:
            worst = max(worst, t - 1 - prev)
    return last_sum, gap_sum, gap_count, gap_max, worst


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
def _solo_qlearning(
    r,
    t0,
    u,
    words,
    nbrs,
    cell_moves,
    dot_value,
    has_dot,
    n_dots,
    reward_w,
    avoid,
    max_ep,
    quota,
    sp,
    pos,
    head,
    occ,
    dots,
    last,
    dots_left,
    ep_dots,
    ep_visits,
    ep_start,
    ep_count,
    ep_seen,
    ep_seen_state,
    wait,
    active,
    steps_done,
    m_last,
    m_last_sum,
    visits,
    window_visits,
    idle_total,
    worst,
    measured,
    gap_sum,
    gap_count,
    gap_max,
    max_wait,
    warmup,
    tail_pos,
    tail_n,
    ep_buf,
    n_ep,
    ended,
    sink,
):
    """Run ``r`` of a batch of lone Q-learning robots (no battery, no recorder but the
    trajectory), advanced by up to ``u.shape[1]`` steps after ``t0``: the steps of
    :func:`run_block` with what a robot alone cannot meet left out (no one else blocks
    it, waits or holds the right of way; its open moves are its legal ones), and the
    robot's cell and heading kept in registers. Its uniforms come from its stream's
    state ``words[r]`` (:mod:`qpatrol.engines.compiled.pcg`), stepped past the block's
    ``2 x u.shape[1]`` draws. The same arithmetic, operation for operation, as
    :func:`qpatrol.engines.compiled.qlearning.act` and ``learn`` and the world's steps.
    Returns ``(last team step taken, episode rows written)``."""
    gamma, epsilon = sp.row_f[r, 0], sp.row_f[r, 1]
    inc, horizon, lam = reward_w[r, 0], reward_w[r, 1], reward_w[r, 2]
    use_heading = sp.ipar[0] != 0
    q, n = sp.q, sp.n
    # the run's rows (views), and what nothing inside the kernel reads kept in
    # registers and stored once at the end: cell, heading, occupancy, wait, steps done
    q_r, n_r = q[r, 0], n[r, 0]
    q_f, n_f = q_r.reshape(-1), n_r.reshape(-1)  # flat: one index, not three
    warm = _touch_tables(q_f, n_f)
    for cc in range(last.shape[2]):
        warm += last[r, 0, cc] + m_last[r, cc]
    sink[0] = warm
    # the run's stream (PCG64, pcg): its state, its increment, the increment of two draws
    s_lo, s_hi, inc_lo, inc_hi = words[r, 0], words[r, 1], words[r, 2], words[r, 3]
    inc2_lo, inc2_hi = pcg.double_inc(inc_lo, inc_hi)
    dots_r, last_r, seen_r, seen_state_r = (
        dots[r, 0],
        last[r, 0],
        ep_seen[r, 0],
        ep_seen_state[r, 0],
    )
    c0 = c = pos[r, 0]
    h = head[r, 0]
    # the episode's counters, stored before an episode ends and at the end
    left, eaten, entered, start = dots_left[r, 0], ep_dots[r, 0], ep_visits[r, 0], ep_start[r, 0]
    going = active[r]
    # the run's measures (Measures), stored at the end
    m_last_r, visits_r, window_visits_r = m_last[r], visits[r, 0], window_visits[r, 0]
    last_sum, idle_sum, n_measured = m_last_sum[r], idle_total[r], measured[r]
    g_sum, g_count, g_max, worst_r = gap_sum[r], gap_count[r], gap_max[r], worst[r]
    t_end = t0
    # the best legal Q of the state the robot stands in, once known: a learning step
    # bootstraps from the very row the next step chooses from (the state reached), and
    # no update between them writes that row (a move leaves its cell)
    best = -np.inf
    known = False
    for i in range(u.shape[1]):
        if not going:
            break
        t = t0 + i + 1
        # --- the robot chooses: greedy over its legal moves (qlearning.act) -----------
        hs = h if use_heading else 0
        at = (c * 4 + hs) * 4  # Q(c, hs, .), flat
        if not known:
            best = -np.inf
            for d in range(4):
                if nbrs[c, d] >= 0 and q_f[at + d] > best:
                    best = q_f[at + d]
        # the step's two uniforms: the first for epsilon, the second to break ties, each
        # computed only where read
        a_lo, a_hi, s_lo, s_hi = pcg.two_steps(s_lo, s_hi, inc_lo, inc_hi, inc2_lo, inc2_hi)
        explore = epsilon > 0.0 and pcg.uniform(a_lo, a_hi) < epsilon
        bits = 0
        count = 0
        for d in range(4):
            if nbrs[c, d] >= 0 and (explore or q_f[at + d] == best):
                bits |= 1 << d
                count += 1
        aa = pick(bits, count, pcg.uniform(s_lo, s_hi))
        if aa >= 0:
            # --- it moves and enters c1: dots, visits, reward, heading ----------------
            c1 = nbrs[c, aa]
            a, _, left, eaten, entered, reward = _enter(
                c,
                c1,
                -1,
                t,
                nbrs,
                dot_value,
                dots_r,
                last_r,
                seen_r,
                seen_state_r,
                left,
                eaten,
                entered,
                inc,
                horizon,
                lam,
            )
        if left == 0 or (max_ep > 0 and t - start >= max_ep):
            dots_left[r, 0], ep_dots[r, 0], ep_visits[r, 0] = left, eaten, entered
            n_ep = _end_episodes(
                r,
                t,
                has_dot,
                n_dots,
                max_ep,
                quota,
                dots,
                dots_left,
                ep_dots,
                ep_visits,
                ep_start,
                ep_count,
                ep_seen,
                ep_seen_state,
                active,
                ep_buf,
                n_ep,
                ended,
            )
            left, eaten, entered = dots_left[r, 0], ep_dots[r, 0], ep_visits[r, 0]
            start, going = ep_start[r, 0], active[r]
        if aa >= 0:
            # --- it learns (qlearning.learn) ------------------------------------------
            hb = aa if use_heading else 0  # the state reached: (c1, hb)
            at1 = (c1 * 4 + hb) * 4  # Q(c1, hb, .), flat
            m1 = MASKED[cell_moves[c1]]  # its greatest Q over the legal moves
            top = max(
                max(q_f[at1] + m1[0], q_f[at1 + 1] + m1[1]),
                max(q_f[at1 + 2] + m1[2], q_f[at1 + 3] + m1[3]),
            )
            target = reward + gamma * top
            at0 = at + aa  # Q(c, hs, aa)
            q_sa = q_f[at0]
            n_after = n_f[at0] + 1
            alpha = 1.0 / n_after
            q_f[at0] = q_sa + alpha * (target - q_sa)
            n_f[at0] = n_after
            best = top  # the next choice's best: Q(c1, hb, .) over c1's legal moves
            known = True
            last_sum, g_sum, g_count, g_max, worst_r = _observe(
                c1,
                t,
                warmup,
                m_last_r,
                visits_r,
                window_visits_r,
                last_sum,
                g_sum,
                g_count,
                g_max,
                worst_r,
            )
            c = c1
            h = a
        if t > warmup:
            idle_sum += nbrs.shape[0] * t - last_sum
            n_measured += 1
        if tail_n > 0:
            tail_pos[r, (t - 1) % tail_n, 0] = c
        t_end = t
    pcg.store(words[r], s_lo, s_hi, (u.shape[1] - (t_end - t0)) * 2)
    dots_left[r, 0], ep_dots[r, 0], ep_visits[r, 0] = left, eaten, entered
    m_last_sum[r], idle_total[r], measured[r] = last_sum, idle_sum, n_measured
    gap_sum[r], gap_count[r], gap_max[r], worst[r] = g_sum, g_count, g_max, worst_r
    if t_end > t0:  # the stores the steps left out
        pos[r, 0] = c
        head[r, 0] = h
        if avoid:
            occ[r, c0] = -1
            occ[r, c] = 0
        wait[r, 0] = 0
        steps_done[r] = t_end
        if t_end > warmup:
            max_wait[r] = max(max_wait[r], 0)
    return t_end, n_ep


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _team_enters(k, c0, c1, t, learns, ha, aa, run, sums):
    """Robot ``k`` of a Q-learning team moved from cell ``c0`` into ``c1`` at step ``t``:
    its dot group takes the visit (:func:`_enter`), it learns when it made the move it
    chose (``learns``; ``ha`` its heading before, ``aa`` that move), and the measures see
    the visit (:func:`_observe`; ``sums`` the run's ``(last_sum, gap_sum, gap_count,
    gap_max, worst)``). ``run``: what the team kernel holds for its run, ``(communication,
    use_heading, warmup, (gamma, inc, horizon, lam), nbrs, cell_moves, dot_value, q_f,
    n_f, n_cells, (dots, last, seen, seen_state, left, eaten, entered), m_last, visits,
    window_visits)``, with ``q_f``, ``n_f`` the run's tables, flat, and the group rows one
    per dot group. Returns ``(heading entered, sums)``."""
    (
        communication,
        use_heading,
        warmup,
        weights,
        nbrs,
        cell_moves,
        dot_value,
        q_f,
        n_f,
        n_cells,
        group_rows,
        m_last_r,
        visits_r,
        window_visits_r,
    ) = run
    gamma, inc, horizon, lam = weights
    dots_r, last_r, seen_r, seen_state_r, left_r, eaten_r, entered_r = group_rows
    last_sum, g_sum, g_count, g_max, worst_r = sums
    g = 0 if communication else k
    a, _, left_r[g], eaten_r[g], entered_r[g], rew = _enter(
        c0,
        c1,
        aa if learns else -1,
        t,
        nbrs,
        dot_value,
        dots_r[g],
        last_r[g],
        seen_r[g],
        seen_state_r[g],
        left_r[g],
        eaten_r[g],
        entered_r[g],
        inc,
        horizon,
        lam,
    )
    if learns:  # qlearning.learn
        hs = ha if use_heading else 0
        hb = aa if use_heading else 0  # the state reached: (c1, hb)
        at1 = ((k * n_cells + c1) * 4 + hb) * 4  # Q(c1, hb, .), flat
        n0, n1, n2, n3 = q_f[at1], q_f[at1 + 1], q_f[at1 + 2], q_f[at1 + 3]
        m1 = MASKED[cell_moves[c1]]  # its greatest Q over the legal moves, branch-free
        top = max(max(n0 + m1[0], n1 + m1[1]), max(n2 + m1[2], n3 + m1[3]))
        target = rew + gamma * top
        at0 = ((k * n_cells + c0) * 4 + hs) * 4 + aa  # Q(c0, hs, aa), flat
        q_sa = q_f[at0]
        n_after = n_f[at0] + 1
        alpha = 1.0 / n_after
        q_f[at0] = q_sa + alpha * (target - q_sa)
        n_f[at0] = n_after
    sums = _observe(
        c1,
        t,
        warmup,
        m_last_r,
        visits_r[k],
        window_visits_r[k],
        last_sum,
        g_sum,
        g_count,
        g_max,
        worst_r,
    )
    return a, sums


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _team_qlearning(
    r,
    t0,
    u,
    words,
    nbrs,
    cell_moves,
    dot_value,
    has_dot,
    n_dots,
    reward_w,
    communication,
    avoid,
    diameter,
    max_ep,
    quota,
    sp,
    pos,
    head,
    occ,
    dots,
    last,
    dots_left,
    ep_dots,
    ep_visits,
    ep_start,
    ep_count,
    ep_seen,
    ep_seen_state,
    wait,
    token,
    token_held,
    active,
    steps_done,
    m_last,
    m_last_sum,
    visits,
    window_visits,
    idle_total,
    worst,
    measured,
    gap_sum,
    gap_count,
    gap_max,
    max_wait,
    wait_total,
    warmup,
    tail_pos,
    tail_n,
    ep_buf,
    n_ep,
    mode,
    depart_left,
    pocket_of,
    reserved,
    scratch,
):
    """Run ``r`` of a batch of Q-learning teams (no battery, no recorder but the
    trajectory), advanced by up to ``u.shape[1]`` team steps after ``t0``: the steps of
    :func:`run_block` with the battery's rules left out (every robot patrols and
    chooses; right of way by wait and turn alone), the run's rows read through views,
    and its right of way and measures' sums kept in registers. A step in which every
    robot asks for a cell that is empty and that no other asks for (nine steps in ten
    for four robots on map_a) moves, enters, learns and measures each robot in one pass;
    any other step takes the traffic rules' passes. The uniforms come from the run's
    stream state ``words[r]`` (:mod:`qpatrol.engines.compiled.pcg`), stepped past the
    block's ``2 x K x u.shape[1]`` draws. The same arithmetic, operation for operation,
    as :func:`qpatrol.engines.compiled.qlearning.act` and ``learn``,
    :mod:`qpatrol.traffic` and the world's steps. Returns ``(last team step taken,
    episode rows written)``."""
    (
        want,
        ask,
        prev_pos,
        prev_head,
        moved,
        as_asked,
        sink,
        blocked_by,
        order,
        key,
        _choosing,
        _eaten,
        _yielding,
        _held_back,
        _open_mask,
        ended,
        parent,
        seen,
        queue,
        path,
    ) = scratch
    n_agents, n_cells = u.shape[2], nbrs.shape[0]
    gamma, epsilon = sp.row_f[r, 0], sp.row_f[r, 1]
    inc, horizon, lam = reward_w[r, 0], reward_w[r, 1], reward_w[r, 2]
    use_heading = sp.ipar[0] != 0
    # the run's rows (views)
    q_r, n_r = sp.q[r], sp.n[r]
    q_f, n_f = q_r.reshape(-1), n_r.reshape(-1)  # flat: one index, not four
    sink[0] = _touch_tables(q_f, n_f)  # (16 x 4 and 256 x 4: about 10 % faster)
    # the run's stream (PCG64, pcg): its state, its increment, the increment of two draws
    s_lo, s_hi, inc_lo, inc_hi = words[r, 0], words[r, 1], words[r, 2], words[r, 3]
    inc2_lo, inc2_hi = pcg.double_inc(inc_lo, inc_hi)
    pos_r, head_r, occ_r, wait_r = pos[r], head[r], occ[r], wait[r]
    dots_r, last_r, seen_r, seen_state_r = dots[r], last[r], ep_seen[r], ep_seen_state[r]
    left_r, eaten_r, entered_r = dots_left[r], ep_dots[r], ep_visits[r]
    m_last_r, visits_r, window_visits_r = m_last[r], visits[r], window_visits[r]
    mode_r, depart_left_r, reserved_r = mode[r], depart_left[r], reserved[r]
    # what only this kernel reads, in registers and stored at the end: the right of
    # way, the measures' sums
    tok, held = token[r], token_held[r]
    idle_sum, n_measured = idle_total[r], measured[r]
    sums = (m_last_sum[r], gap_sum[r], gap_count[r], gap_max[r], worst[r])  # _observe's
    run = (  # what each robot's entry needs (_team_enters)
        communication,
        use_heading,
        warmup,
        (gamma, inc, horizon, lam),
        nbrs,
        cell_moves,
        dot_value,
        q_f,
        n_f,
        n_cells,
        (dots_r, last_r, seen_r, seen_state_r, left_r, eaten_r, entered_r),
        m_last_r,
        visits_r,
        window_visits_r,
    )
    top_wait, wait_sum = max_wait[r], wait_total[r]
    waiting = 0  # robots waiting after the last step
    for k in range(n_agents):
        if wait_r[k] > 0:
            waiting += 1
    going = active[r]
    # the first step at which a group's episode reaches max_ep steps: before it and
    # while every group has dots left, no episode ends (_end_episodes is not called)
    n_groups = left_r.shape[0]
    deadline = _ep_deadline(ep_start[r], max_ep, t0 + u.shape[1] + 1)
    t_end = t0
    t_next_mod = (t0 + 1) % n_agents  # t % n_agents of the first step
    for i in range(u.shape[1]):
        if not going:
            break
        t = t0 + i + 1
        t_mod = t_next_mod
        t_next_mod = t_mod + 1 if t_mod + 1 < n_agents else 0  # (t + 1) % n_agents
        # --- each robot's open moves and its choice (world.begin_step, qlearning.act)
        for k in range(n_agents):
            c = pos_r[k]
            hk = head_r[k]
            legal = cell_moves[c]
            free = legal
            if avoid and k != tok:  # the legal moves into cells no robot stands in
                nb = nbrs[c]  # (a wall's -1 reads the last cell: masked by legal)
                taken = (
                    (1 if occ_r[nb[0]] >= 0 else 0)
                    | (2 if occ_r[nb[1]] >= 0 else 0)
                    | (4 if occ_r[nb[2]] >= 0 else 0)
                    | (8 if occ_r[nb[3]] >= 0 else 0)
                )
                free = legal & ~taken
                if free == 0:  # base.prefer_open: every legal move where none is open
                    free = legal
            hs = hk if use_heading else 0
            # the greatest Q of the open moves, with no branch per move (MASKED)
            at = ((k * n_cells + c) * 4 + hs) * 4  # Q(c, hs, .), flat
            mf = MASKED[free]
            v0 = q_f[at] + mf[0]
            v1 = q_f[at + 1] + mf[1]
            v2 = q_f[at + 2] + mf[2]
            v3 = q_f[at + 3] + mf[3]
            best = max(max(v0, v1), max(v2, v3))
            # the robot's two uniforms of the step, each computed only where read
            a_lo, a_hi, s_lo, s_hi = pcg.two_steps(s_lo, s_hi, inc_lo, inc_hi, inc2_lo, inc2_hi)
            explore = epsilon > 0.0 and pcg.uniform(a_lo, a_hi) < epsilon
            if explore:
                bits = free
            else:
                bits = (
                    (1 if v0 == best else 0)
                    | (2 if v1 == best else 0)
                    | (4 if v2 == best else 0)
                    | (8 if v3 == best else 0)
                ) & free
            aa = pick(bits, POPCOUNT[bits], pcg.uniform(s_lo, s_hi))
            ask[k] = aa
            want[k] = nbrs[c, aa] if aa >= 0 else -1
        # --- the common step: every robot asks for a cell that is empty now and that
        # no other asks for. Then traffic.resolve moves every robot as asked whatever the
        # order (the holder of the right of way pushes no one), no one waits, and the
        # right of way stays with a holder that moved, for at most `diameter` steps
        # (traffic.pass_token): each robot moves, enters, learns and is measured in one
        # pass, in robot order (the order of the entries below)
        clear = True
        if avoid:
            for a in range(n_agents):
                wa = want[a]
                if wa >= 0:
                    if occ_r[wa] >= 0:
                        clear = False
                    for b in range(a + 1, n_agents):
                        if want[b] == wa:
                            clear = False
        in_window = t > warmup
        if clear:
            for k in range(n_agents):
                c1 = want[k]
                if c1 < 0:
                    continue
                c0 = pos_r[k]
                if avoid:
                    occ_r[c0] = -1
                    occ_r[c1] = k
                pos_r[k] = c1
                ha = head_r[k]
                head_r[k], sums = _team_enters(k, c0, c1, t, True, ha, ask[k], run, sums)
            if waiting > 0:
                for k in range(n_agents):
                    wait_r[k] = 0
                waiting = 0
            longest = 0
            if avoid:
                if tok >= 0 and want[tok] >= 0 and held < diameter:
                    held += 1
                else:
                    tok, held = -1, 0
        else:
            for k in range(n_agents):
                prev_pos[k] = pos_r[k]
                prev_head[k] = head_r[k]
                moved[k] = False
                as_asked[k] = False
            push_failed = False
            if not avoid:
                for k in range(n_agents):
                    if want[k] >= 0:
                        pos_r[k] = want[k]
                        moved[k] = True
                        as_asked[k] = True
            else:
                if tok >= 0 and want[tok] >= 0:
                    # 1. the holder takes its cell, pushing robots aside, or steps aside
                    push_failed = _holder_moves(
                        tok,
                        nbrs,
                        occ_r,
                        pos_r,
                        want,
                        moved,
                        as_asked,
                        parent,
                        seen,
                        queue,
                        path,
                        False,
                        mode_r,
                        pocket_of,
                        reserved_r,
                    )
                # 2. everyone else, in priority order, into cells empty at that moment (the
                # order of traffic.priority: every robot patrols, so wait, then turn)
                if waiting == 0:  # by turn alone: robot t % n_agents first, then the next ones
                    for a in range(n_agents):
                        k = t_mod + a
                        order[a] = k if k < n_agents else k - n_agents
                else:
                    for k in range(n_agents):
                        key[k] = _priority(wait_r[k], PATROL, 0, k, n_agents, t_mod)
                        order[k] = k
                    _sort_by_key(order, key, n_agents)
                _move_in_order(order, want, moved, as_asked, occ_r, pos_r)
            # --- each robot that moved enters its cell (dots, visits, reward, heading); one
            # that made the move it chose learns (qlearning.learn); the measures see the
            # visit (Measures.observe). Robot after robot: each touches only its group's
            # dots and its own Q-table, and the measures their own arrays, in robot order
            for k in range(n_agents):
                if not moved[k]:
                    continue
                head_r[k], sums = _team_enters(
                    k, prev_pos[k], pos_r[k], t, as_asked[k], prev_head[k], ask[k], run, sums
                )
            # --- waits, who blocked whom, the right of way ---------------------------------
            waiting = 0  # robots waiting now, and the longest wait
            longest = 0
            for k in range(n_agents):
                failed = ask[k] >= 0 and not as_asked[k]
                blocked_by[k] = occ_r[want[k]] if failed else -1
                wk = wait_r[k] + 1 if failed else 0
                wait_r[k] = wk
                if wk > 0:
                    waiting += 1
                longest = max(longest, wk)
            if avoid:
                tok, held = _pass_token(
                    tok,
                    held,
                    push_failed,
                    want,
                    as_asked,
                    blocked_by,
                    wait_r,
                    mode_r,
                    depart_left_r,
                    t_next_mod,
                    diameter,
                )
        # --- episodes: all dots eaten, or too long -------------------------------------
        due = t >= deadline
        for g in range(n_groups):
            if left_r[g] == 0:
                due = True
        if due:
            n_ep = _end_episodes(
                r,
                t,
                has_dot,
                n_dots,
                max_ep,
                quota,
                dots,
                dots_left,
                ep_dots,
                ep_visits,
                ep_start,
                ep_count,
                ep_seen,
                ep_seen_state,
                active,
                ep_buf,
                n_ep,
                ended,
            )
            going = active[r]
            deadline = _ep_deadline(ep_start[r], max_ep, t0 + u.shape[1] + 1)
        if in_window:
            idle_sum += n_cells * t - sums[0]
            n_measured += 1
            top_wait = max(top_wait, longest)
            wait_sum += waiting
        if tail_n > 0:
            slot = (t - 1) % tail_n
            for k in range(n_agents):
                tail_pos[r, slot, k] = pos_r[k]
        t_end = t
    pcg.store(words[r], s_lo, s_hi, (u.shape[1] - (t_end - t0)) * n_agents * 2)
    token[r], token_held[r] = tok, held
    m_last_sum[r], idle_total[r], measured[r] = sums[0], idle_sum, n_measured
    gap_sum[r], gap_count[r], gap_max[r], worst[r] = sums[1], sums[2], sums[3], sums[4]
    max_wait[r], wait_total[r] = top_wait, wait_sum
    if t_end > t0:
        steps_done[r] = t_end
    return t_end, n_ep


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def run_block(
    spec_marker,
    t0,
    u,
    words,
    nbrs,
    wall_legal,
    cell_moves,
    dot_value,
    has_dot,
    reward_w,
    communication,
    avoid,
    diameter,
    max_ep,
    quota,
    code,
    sp,
    pos,
    head,
    occ,
    dots,
    last,
    dots_left,
    ep_dots,
    ep_visits,
    ep_start,
    ep_count,
    ep_seen,
    ep_seen_state,
    wait,
    token,
    token_held,
    active,
    steps_done,
    m_last,
    m_last_sum,
    visits,
    window_visits,
    idle_total,
    worst,
    measured,
    gap_sum,
    gap_count,
    gap_max,
    max_wait,
    wait_total,
    warmup,
    tail_pos,
    tail_n,
    ep_buf,
    battery,
    homes,
    home_dist,
    home_dir,
    nearest,
    depart_len,
    pocket_of,
    pocket_depth,
    pocket_entry,
    capacity,
    margin,
    charge_steps,
    charge,
    mode,
    rest,
    goal,
    queued_since,
    depart_left,
    reserved,
    min_charge,
    record_all,
    watched,
    up_int,
    up_float,
    tl_window,
    tl_last,
    tl_last_sum,
    tl_idle_sum,
    tl_worst,
    tl_steps,
    tl_buf,
    scratch,
):
    """Advance every active run by up to ``u.shape[1]`` team steps after step ``t0``.

    ``spec_marker``: an int8 array whose ``ndim`` is the loop to compile (``SPEC_*``;
    :class:`Loop` picks it). ``u``: float ``[R, T, K, 2]``, each robot's two uniforms
    of each step; the Q-learning kernels (``SPEC_QLEARNING_SOLO``, ``_TEAM``) take its
    shape alone (``[R, T, K, 0]``) and draw them from ``words`` (uint64 ``[R, 4]``, each
    run's PCG64 state, :mod:`qpatrol.engines.compiled.pcg`), which they step past
    ``T x K x 2`` draws. ``cell_moves``: int64 ``[C]``, each cell's legal moves as 4
    bits (:func:`qpatrol.engines.compiled.choice.legal_bits` of ``nbrs``), which the
    kernels read to leave out walls with no branch (``MASKED``). Arrays are the engine's
    state (see module doc), modified in place. Ended episodes are written to
    ``ep_buf`` ``[E, EP_COLS]``.
    Q-updates of every robot (``record_all``) or of the ``watched`` cells (bool ``[C]``)
    go to ``up_int`` ``[U, UP_INT]`` and ``up_float`` ``[U, UP_FLOAT]``.
    With ``tl_window`` > 0 the idleness timeline (:class:`qpatrol.timeline.Timeline`,
    its arrays ``tl_*``) is kept too, each closed window a row of ``tl_buf`` ``[W, 6]``
    (run row, window, first step, last step, idleness sum, worst).
    ``reward_w``: float64 ``[R, 3]``, each run's reward weights (incremental value,
    idle horizon, lambda).
    Returns ``(last team step taken by any run, episode rows, update rows written,
    timeline rows written)``.
    """
    spec = spec_marker.ndim  # a constant of the compiled code, one overload per value
    n_runs, n_steps, n_agents = u.shape[0], u.shape[1], u.shape[2]
    if spec >= SPEC_QLEARNING:  # compile-time constants: the unused code is removed
        code = compiled.QLEARNING
        battery = False
        tl_window = 0
    n_cells = nbrs.shape[0]
    # np.int64(0), not 0: a literal 0 would have numba compile each kernel twice, for a
    # literal argument and for an int64 one
    n_dots = np.int64(0)
    for c in range(n_cells):
        if has_dot[c]:
            n_dots += 1
    (
        want,
        ask,
        prev_pos,
        prev_head,
        moved,
        as_asked,
        reward,
        blocked_by,
        order,
        key,
        choosing,
        eaten,
        yielding,
        held_back,
        open_mask,
        ended,
        parent,
        seen,
        queue,
        path,
    ) = scratch
    n_up = 0
    n_homes = homes.shape[0]
    for c in range(n_cells):
        parent[c] = -2
    t_end = t0
    n_ep = np.int64(0)
    n_tl = 0
    for r in range(n_runs):
        if spec == SPEC_QLEARNING_SOLO:
            t_r, n_ep = _solo_qlearning(
                r,
                t0,
                u,
                words,
                nbrs,
                cell_moves,
                dot_value,
                has_dot,
                n_dots,
                reward_w,
                avoid,
                max_ep,
                quota,
                sp,
                pos,
                head,
                occ,
                dots,
                last,
                dots_left,
                ep_dots,
                ep_visits,
                ep_start,
                ep_count,
                ep_seen,
                ep_seen_state,
                wait,
                active,
                steps_done,
                m_last,
                m_last_sum,
                visits,
                window_visits,
                idle_total,
                worst,
                measured,
                gap_sum,
                gap_count,
                gap_max,
                max_wait,
                warmup,
                tail_pos,
                tail_n,
                ep_buf,
                n_ep,
                ended,
                reward,
            )
            t_end = max(t_end, t_r)
            continue
        if spec == SPEC_QLEARNING_TEAM:
            t_r, n_ep = _team_qlearning(
                r,
                t0,
                u,
                words,
                nbrs,
                cell_moves,
                dot_value,
                has_dot,
                n_dots,
                reward_w,
                communication,
                avoid,
                diameter,
                max_ep,
                quota,
                sp,
                pos,
                head,
                occ,
                dots,
                last,
                dots_left,
                ep_dots,
                ep_visits,
                ep_start,
                ep_count,
                ep_seen,
                ep_seen_state,
                wait,
                token,
                token_held,
                active,
                steps_done,
                m_last,
                m_last_sum,
                visits,
                window_visits,
                idle_total,
                worst,
                measured,
                gap_sum,
                gap_count,
                gap_max,
                max_wait,
                wait_total,
                warmup,
                tail_pos,
                tail_n,
                ep_buf,
                n_ep,
                mode,
                depart_left,
                pocket_of,
                reserved,
                scratch,
            )
            t_end = max(t_end, t_r)
            continue
        t_next_mod = (t0 + 1) % n_agents  # t % n_agents of the first step
        for i in range(n_steps):
            if not active[r]:
                break
            t = t0 + i + 1
            t_mod = t_next_mod
            t_next_mod = t_mod + 1 if t_mod + 1 < n_agents else 0  # (t + 1) % n_agents
            tok = token[r]
            if battery:
                # battery.begin: charging countdown, robots that need a station, the queue
                for k in range(n_agents):
                    if mode[r, k] == CHARGING:
                        rest[r, k] -= 1
                        if rest[r, k] < 0:
                            rest[r, k] = 0
                            mode[r, k] = PATROL
                            charge[r, k] = capacity
                            depart_left[r, k] = 2 * depart_len[goal[r, k]]
                any_queued = False
                for k in range(n_agents):
                    if (
                        mode[r, k] == PATROL
                        and depart_left[r, k] == 0
                        and charge[r, k] <= nearest[pos[r, k]] + margin + 1
                    ):
                        mode[r, k] = QUEUED
                        queued_since[r, k] = t
                    if mode[r, k] == QUEUED:
                        any_queued = True
                if any_queued:
                    # _assign_stations: first come first served (ties: lower index)
                    for k in range(n_agents):
                        order[k] = k
                        if mode[r, k] == QUEUED:
                            key[k] = queued_since[r, k] * n_agents + k
                        else:
                            key[k] = (1 << 50) * n_agents + k
                    for a in range(1, n_agents):
                        x = order[a]
                        b = a - 1
                        while b >= 0 and key[order[b]] > key[x]:
                            order[b + 1] = order[b]
                            b -= 1
                        order[b + 1] = x
                    for a in range(n_agents):
                        k = order[a]
                        if mode[r, k] != QUEUED:
                            break
                        best_h = -1
                        best_d = np.iinfo(np.int64).max
                        for h in range(n_homes):
                            dist = home_dist[h, pos[r, k]]
                            if reserved[r, h] < 0 and dist <= charge[r, k] and dist < best_d:
                                best_d = dist
                                best_h = h
                        if best_h >= 0:
                            reserved[r, best_h] = k
                            goal[r, k] = best_h
                            mode[r, k] = HOMING
            # --- observe (world.begin_step): who chooses, the open moves ----------------
            for k in range(n_agents):
                c = pos[r, k]
                choosing[k] = mode[r, k] == PATROL
                held_back[k] = False
                yielding[k] = False
                any_open = False
                for d in range(4):
                    nb = nbrs[c, d]
                    ok = nb >= 0
                    if ok and battery:  # battery.closed_cells: deeper into a held pocket
                        hp = pocket_of[nb]
                        if hp >= 0:
                            holder = reserved[r, hp]
                            if holder >= 0 and holder != k:
                                if pocket_of[c] != hp or pocket_depth[nb] > pocket_depth[c]:
                                    ok = False
                    if ok and avoid and k != tok and occ[r, nb] >= 0:
                        ok = False
                    open_mask[k, d] = ok
                    any_open = any_open or ok
                if not any_open:  # base.prefer_open: every legal move where none is open
                    for d in range(4):
                        open_mask[k, d] = nbrs[c, d] >= 0
                prev_pos[k] = c
                prev_head[k] = head[r, k]
                moved[k] = False
                as_asked[k] = False
            # --- the strategy chooses (Strategy.act) ----------------------------------
            compiled.act(
                code,
                r,
                i,
                t,
                u,
                nbrs,
                wall_legal,
                dot_value,
                communication,
                battery,
                pocket_of,
                pos,
                head,
                last,
                reserved,
                open_mask,
                choosing,
                ask,
                sp,
            )
            if battery:
                for k in range(n_agents):
                    c = pos[r, k]
                    if mode[r, k] == HOMING:  # battery.homing_ask
                        gk = max(goal[r, k], 0)
                        direction = home_dir[gk, c]
                        entry = pocket_entry[gk]
                        if entry >= 0:
                            depth_others = -1
                            for j2 in range(n_agents):
                                if j2 != k and pocket_of[pos[r, j2]] == gk:
                                    depth_others = max(depth_others, pocket_depth[pos[r, j2]])
                            occupied = depth_others >= 0
                            my_depth = pocket_depth[c] if pocket_of[c] == gk else 0
                            at_entry = c == entry
                            nxt = nbrs[c, max(direction, 0)]
                            entering = (
                                direction >= 0 and my_depth == 0 and not at_entry and nxt == entry
                            )
                            held = occupied and entering
                            yld = occupied and (
                                at_entry or (depth_others > my_depth and my_depth > 0)
                            )
                            out = _way_out(
                                nbrs, pocket_of, pocket_depth, pocket_entry, occ[r], c, gk
                            )
                            if held:
                                direction = -1
                            elif yld:
                                direction = out
                            held_back[k] = held
                            yielding[k] = yld and out >= 0
                        ask[k] = direction
                    elif mode[r, k] == QUEUED:  # battery.queued_ask
                        station = -1
                        hp = pocket_of[c]
                        if hp >= 0:
                            holder = reserved[r, hp]
                            if holder >= 0 and holder != k:
                                station = hp
                        for hh in range(n_homes):
                            if c == pocket_entry[hh] and reserved[r, hh] >= 0:
                                if reserved[r, hh] != k:
                                    station = hh
                                    break
                        ask[k] = _way_out(
                            nbrs, pocket_of, pocket_depth, pocket_entry, occ[r], c, station
                        )
                        if ask[k] >= 0:
                            yielding[k] = True
            for k in range(n_agents):
                want[k] = nbrs[pos[r, k], ask[k]] if ask[k] >= 0 else -1
            # --- move (traffic.resolve) ---------------------------------------------
            push_failed = False
            if not avoid:
                for k in range(n_agents):
                    if want[k] >= 0:
                        pos[r, k] = want[k]
                        moved[k] = True
                        as_asked[k] = True
            else:
                if tok >= 0 and want[tok] >= 0:
                    # 1. the holder takes its cell, pushing robots aside, or steps aside
                    push_failed = _holder_moves(
                        tok,
                        nbrs,
                        occ[r],
                        pos[r],
                        want,
                        moved,
                        as_asked,
                        parent,
                        seen,
                        queue,
                        path,
                        battery,
                        mode[r],
                        pocket_of,
                        reserved[r],
                    )
                # 2. everyone else, in priority order, into cells empty at that moment
                if n_agents == 1:  # alone: the priority order is trivial
                    w = want[0]
                    if w >= 0 and not moved[0] and occ[r, w] < 0:
                        occ[r, pos[r, 0]] = -1
                        occ[r, w] = 0
                        pos[r, 0] = w
                        moved[0] = True
                        as_asked[0] = True
                for k in range(n_agents if n_agents > 1 else 0):
                    key[k] = _priority(
                        wait[r, k], mode[r, k], depart_left[r, k], k, n_agents, t_mod
                    )
                    order[k] = k
                if n_agents > 1:
                    _sort_by_key(order, key, n_agents)
                    _move_in_order(order, want, moved, as_asked, occ[r], pos[r])
            # --- entering a cell: dots, visits, reward, heading -------------------------
            for k in range(n_agents):
                reward[k] = 0.0
                eaten[k] = False
                if not moved[k]:
                    continue
                g = 0 if communication else k
                (
                    head[r, k],
                    eaten[k],
                    dots_left[r, g],
                    ep_dots[r, g],
                    ep_visits[r, g],
                    reward[k],
                ) = _enter(
                    prev_pos[k],
                    pos[r, k],
                    -1,
                    t,
                    nbrs,
                    dot_value,
                    dots[r, g],
                    last[r, g],
                    ep_seen[r, g],
                    ep_seen_state[r, g],
                    dots_left[r, g],
                    ep_dots[r, g],
                    ep_visits[r, g],
                    reward_w[r, 0],
                    reward_w[r, 1],
                    reward_w[r, 2],
                )
            if battery:
                # a move costs one unit; yielding (pushed aside, or out of a pocket) is free
                for k in range(n_agents):
                    if not moved[k]:
                        continue
                    if as_asked[k] and not yielding[k]:
                        charge[r, k] -= 1
                    elif mode[r, k] == HOMING or mode[r, k] == QUEUED:  # credit_detour
                        gk = max(goal[r, k], 0)
                        if mode[r, k] == HOMING:
                            d_before = home_dist[gk, prev_pos[k]]
                            d_after = home_dist[gk, pos[r, k]]
                        else:
                            d_before = nearest[prev_pos[k]]
                            d_after = nearest[pos[r, k]]
                        credit = max(d_after - d_before, 0)
                        charge[r, k] = min(charge[r, k] + credit, capacity)
                # battery.end: departed robots release stations, arrivals start charging
                for k in range(n_agents):
                    if depart_left[r, k] > 0:
                        depart_left[r, k] -= 1
                        if depart_left[r, k] == 0 or ask[k] < 0:
                            reserved[r, goal[r, k]] = -1
                            goal[r, k] = -1
                            depart_left[r, k] = 0
                for k in range(n_agents):
                    if mode[r, k] == HOMING and pos[r, k] == homes[max(goal[r, k], 0)]:
                        if charge_steps > 0:
                            mode[r, k] = CHARGING
                            rest[r, k] = charge_steps
                        else:
                            mode[r, k] = PATROL
                            charge[r, k] = capacity
                            depart_left[r, k] = 2 * depart_len[goal[r, k]]
            # --- waits, who blocked whom, the right of way -----------------------------
            for k in range(n_agents):
                failed = ask[k] >= 0 and not as_asked[k]
                blocked_by[k] = occ[r, want[k]] if failed else -1
                if battery and (mode[r, k] == QUEUED or held_back[k]):
                    failed = True
                wait[r, k] = wait[r, k] + 1 if failed else 0
            if avoid and n_agents > 1:
                token[r], token_held[r] = _pass_token(
                    tok,
                    token_held[r],
                    push_failed,
                    want,
                    as_asked,
                    blocked_by,
                    wait[r],
                    mode[r],
                    depart_left[r],
                    t_next_mod,
                    diameter,
                )
            steps_done[r] = t
            # --- episodes: all dots eaten, or too long ---------------------------------
            n_ep = _end_episodes(
                r,
                t,
                has_dot,
                n_dots,
                max_ep,
                quota,
                dots,
                dots_left,
                ep_dots,
                ep_visits,
                ep_start,
                ep_count,
                ep_seen,
                ep_seen_state,
                active,
                ep_buf,
                n_ep,
                ended,
            )
            # --- the strategy learns (Strategy.learn) ----------------------------------
            n_up = compiled.learn(
                code,
                r,
                t,
                nbrs,
                wall_legal,
                dot_value,
                has_dot,
                communication,
                pos,
                prev_pos,
                prev_head,
                moved,
                ask,
                as_asked,
                choosing,
                reward,
                eaten,
                blocked_by,
                ended,
                active,
                sp,
                record_all,
                watched,
                up_int,
                up_float,
                n_up,
            )
            # --- measures (Measures.observe) and the trajectory ring -------------------
            in_window = t > warmup
            for k in range(n_agents):
                if not moved[k]:
                    continue
                m_last_sum[r], gap_sum[r], gap_count[r], gap_max[r], worst[r] = _observe(
                    pos[r, k],
                    t,
                    warmup,
                    m_last[r],
                    visits[r, k],
                    window_visits[r, k],
                    m_last_sum[r],
                    gap_sum[r],
                    gap_count[r],
                    gap_max[r],
                    worst[r],
                )
            if tl_window > 0:
                # Timeline.observe: its own last visits, peaks inside t's window
                start = ((t - 1) // tl_window) * tl_window + 1
                for k in range(n_agents):
                    if not moved[k]:
                        continue
                    c = pos[r, k]
                    prev = tl_last[r, c]
                    tl_last[r, c] = t
                    tl_last_sum[r] += t - prev
                    if t - 1 >= start:
                        tl_worst[r] = max(tl_worst[r], t - 1 - prev)
                tl_idle_sum[r] += n_cells * t - tl_last_sum[r]
                tl_steps[r] += 1
                if t % tl_window == 0:  # Timeline._close
                    low = tl_last[r, 0]
                    for c in range(1, n_cells):
                        low = min(low, tl_last[r, c])
                    row = tl_buf[n_tl]
                    row[0] = r
                    row[1] = (t - 1) // tl_window
                    row[2] = t - tl_steps[r] + 1
                    row[3] = t
                    row[4] = tl_idle_sum[r]
                    row[5] = max(tl_worst[r], t - low)
                    n_tl += 1
                    tl_idle_sum[r] = 0
                    tl_worst[r] = 0
                    tl_steps[r] = 0
            if battery:
                low = charge[r, 0]
                for k in range(1, n_agents):
                    low = min(low, charge[r, k])
                min_charge[r] = min(min_charge[r], low)
            if in_window:
                idle_total[r] += n_cells * t - m_last_sum[r]
                measured[r] += 1
                top_wait = wait[r, 0]
                waiting = 0
                for k in range(n_agents):
                    top_wait = max(top_wait, wait[r, k])
                    if wait[r, k] > 0:
                        waiting += 1
                max_wait[r] = max(max_wait[r], top_wait)
                wait_total[r] += waiting
            if tail_n > 0:
                slot = (t - 1) % tail_n
                for k in range(n_agents):
                    tail_pos[r, slot, k] = pos[r, k]
            if t > t_end:
                t_end = t
    return t_end, n_ep, n_up, n_tl


# the caches of the loop and of the functions it calls without inlining them (the
# kernels, which inline the choice and the streams' draws) also follow the files of
# qpatrol.engines.compiled
for _f in (_priority, _kept_out, _way_out, _push_path, _solo_qlearning, _team_qlearning):
    compiled.key_cache(_f, __file__)
compiled.key_cache(run_block, __file__)
del _f


def scratch(n_agents: int, n_groups: int, n_cells: int) -> tuple[np.ndarray, ...]:
    """The loop's working arrays, allocated once per batch (the loop itself allocates
    nothing: it is compiled without numba's reference counting, which would otherwise
    cost an atomic increment and decrement per array argument of every call): per robot
    ``[K]`` want, ask, prev_pos, prev_head, moved, as_asked, reward, blocked_by, order,
    key, choosing, eaten, yielding, held_back; open_mask ``[K, 4]``; ended ``[G]``; and
    the push search's parent, seen, queue, path ``[C]``."""
    i8, b1, k = np.int64, np.bool_, n_agents
    return (
        *(np.zeros(k, i8) for _ in range(4)),
        np.zeros(k, b1),
        np.zeros(k, b1),
        np.zeros(k, np.float64),
        *(np.zeros(k, i8) for _ in range(3)),
        *(np.zeros(k, b1) for _ in range(4)),
        np.zeros((k, 4), b1),
        np.zeros(n_groups, b1),
        *(np.zeros(n_cells, i8) for _ in range(4)),
    )


class Loop:
    """The compiled loop over one batch: its constant arguments and its buffers, so a
    call costs little even for one team step (when a checkpointer wants every step).

    Args:
        state, p, strategy, measures, tail, rec: the objects the numpy loop uses too
            (their arrays are updated in place).
        max_steps: most team steps one :meth:`run` will be given.
        timeline: the idleness timeline, or None.
        words: where the loop may draw its uniforms itself
            (:attr:`draws_itself`), the runs' streams: a function giving their PCG64
            states, uint64 ``[R, 4]`` (:meth:`qpatrol.rng.Streams.words`), the same
            array at every call, stepped in place by :meth:`run`. Otherwise (or
            without it) each call of :meth:`run` reads uniforms drawn beforehand.
    """

    def __init__(
        self,
        state: State,
        p: Params,
        strategy,
        measures,
        tail,
        rec,
        max_steps: int,
        timeline=None,
        words: Callable[[], np.ndarray] | None = None,
    ):
        s, m = state, measures
        self.state, self.p = s, p
        self.strategy = strategy
        self.code, self.pack = compiled.pack(strategy)
        n_runs, k = s.pos.shape
        n_dots = int(p.has_dot.sum())
        shortest = -(-n_dots // k)
        if p.max_episode_steps:
            shortest = min(shortest, p.max_episode_steps)
        cap = n_runs * p.n_groups * (max_steps // max(1, shortest) + 1)
        self.ep_buf = np.empty((cap, EP_COLS), dtype=np.int64)
        tail_pos = tail.pos if tail.n else np.zeros((1, 1, 1), dtype=np.int64)
        watched = np.zeros(p.n_cells, dtype=bool)
        watched[rec.watch[(rec.watch >= 0) & (rec.watch < p.n_cells)]] = True
        rows = n_runs * k * max_steps if rec.wants_updates else 1
        self.up_int = np.empty((rows, UP_INT), dtype=np.int64)
        self.up_float = np.empty((rows, UP_FLOAT), dtype=np.float64)
        # float64 [R, 3]: each run's reward weights (incremental value, idle horizon,
        # lambda), the same in every row unless the batch's rows differ
        self.reward_w = np.empty((n_runs, 3), dtype=np.float64)
        self.reward_w[:, 0] = p.incremental_value
        self.reward_w[:, 1] = p.idle_horizon
        self.reward_w[:, 2] = p.lambda_weight
        # uint64 [R, 4]: the runs' PCG64 states (rng.Streams.words), which the
        # Q-learning kernels step as they draw (a placeholder until the spec is known)
        self.words = np.zeros((n_runs, 4), dtype=np.uint64)
        self.args = (
            self.words,
            p.neighbors,
            p.wall_legal,
            legal_bits(p.neighbors),
            p.dot_value,
            p.has_dot,
            self.reward_w,
            p.communication,
            p.avoid_collisions,
            p.diameter,
            p.max_episode_steps,
            p.episodes,
            self.code,
            self.pack,
            s.pos,
            s.head,
            s.occ,
            s.dots,
            s.last,
            s.dots_left,
            s.ep_dots,
            s.ep_visits,
            s.ep_start,
            s.ep_count,
            s.ep_seen,
            s.ep_seen_state,
            s.wait,
            s.token,
            s.token_held,
            s.active,
            s.steps_done,
            m.last,
            m.last_sum,
            m.visits,
            m.window_visits,
            m.idle_total,
            m.worst,
            m.measured,
            m.gap_sum,
            m.gap_count,
            m.gap_max,
            m.max_wait,
            m.wait_total,
            m.warmup,
            tail_pos,
            tail.n,
            self.ep_buf,
            p.battery,
            p.homes,
            p.home_dist,
            p.home_dir,
            p.nearest_home_dist,
            p.depart_len,
            p.pocket_of,
            p.pocket_depth,
            p.pocket_entry,
            p.capacity,
            p.margin,
            p.charge_steps,
            s.charge,
            s.mode,
            s.rest,
            s.goal,
            s.queued_since,
            s.depart_left,
            s.reserved,
            m.min_charge,
            rec.transitions,
            watched,
            self.up_int,
            self.up_float,
            *self._timeline_args(timeline, n_runs, p.n_cells, max_steps),
            scratch(k, p.n_groups, p.n_cells),
        )
        self.timeline = timeline if timeline is not None and timeline.window else None
        # the arguments with a leading runs axis, sliced for a call on some runs only
        owners = [s, m, tail] + ([timeline] if self.timeline is not None else [])
        ids = {
            id(v)
            for o in owners
            for v in vars(o).values()
            if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == n_runs
        } | {id(self.reward_w), id(self.words)}
        self.per_run = [j for j, a in enumerate(self.args) if id(a) in ids]
        # the strategy's per-run arrays (not its constants, however many rows they have;
        # nor a one-row placeholder)
        self.pack_per_run = [
            f
            for f, name in enumerate(Pack._fields)
            if name in PER_RUN and n_runs > 1 and self.pack[f].shape[0] == n_runs
        ]
        self.n_runs = n_runs
        self.spec = SPEC_ANY
        if self.code == compiled.QLEARNING and not p.battery and self.timeline is None:
            self.spec = SPEC_QLEARNING
            if not rec.wants_updates and words is not None:
                self.spec = SPEC_QLEARNING_SOLO if k == 1 else SPEC_QLEARNING_TEAM
        #: the loop draws each run's uniforms itself, from its stream's words (the
        #: Q-learning kernels): :meth:`run` is given their shape alone, ``[R, T, K, 0]``
        self.draws_itself = self.spec in (SPEC_QLEARNING_SOLO, SPEC_QLEARNING_TEAM)
        if self.draws_itself:
            self.words = words()
            self.args = (self.words, *self.args[1:])
        self.spec_marker = np.zeros((1,) * self.spec, dtype=np.int8)
        self.pack_at = next(j for j, a in enumerate(self.args) if a is self.pack)
        # each lane's own arrays: output buffers and working arrays (see _lane_args)
        at = {id(a): j for j, a in enumerate(self.args)}
        self.ep_at, self.tl_at = at[id(self.ep_buf)], at[id(self.tl_buf)]
        self.up_at, self.up_f_at = at[id(self.up_int)], at[id(self.up_float)]
        self._own = (self.ep_at, self.up_at, self.up_f_at, self.tl_at, len(self.args) - 1)
        self._lanes: list[tuple[int, tuple] | None] = [None]  # lane i > 0: (runs, args)

    def _timeline_args(self, tl, n_runs: int, n_cells: int, max_steps: int) -> tuple:
        """The timeline's arrays (tiny dummies when it is off) and its row buffer."""
        if tl is None or not tl.window:
            one, row = np.zeros(1, dtype=np.int64), np.zeros((1, 1), dtype=np.int64)
            self.tl_buf = np.zeros((1, 6), dtype=np.int64)
            return (0, row, one, one, one, one, self.tl_buf)
        self.tl_buf = np.empty((n_runs * (max_steps // tl.window + 2), 6), dtype=np.int64)
        return (
            tl.window,
            tl.last,
            tl.last_sum,
            tl.idle_sum,
            tl.worst,
            tl.steps,
            self.tl_buf,
        )

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
            args = list(self.args)
            for j in self._own:
                a = args[j]
                if isinstance(a, tuple):  # the working arrays
                    args[j] = tuple(map(np.zeros_like, a))
                else:  # a buffer of rows: as many per run as lane 0's
                    per_run = max(1, a.shape[0] // self.n_runs) if a.shape[0] > 1 else 0
                    args[j] = np.empty((max(1, per_run * n), *a.shape[1:]), dtype=a.dtype)
            self._lanes[lane] = have = (n, tuple(args))
        return have[1]

    def _call(self, args: tuple, u: np.ndarray, lo: int, hi: int) -> tuple[int, int, int, int]:
        """``run_block`` with a lane's ``args`` on batch rows ``lo..hi-1`` (``u``: their
        uniforms ``[hi - lo, T, K, 2]``), the rows of its output buffers renumbered to
        batch rows."""
        if (lo, hi) != (0, self.n_runs):
            args = list(args)
            for j in self.per_run:
                args[j] = args[j][lo:hi]
            pack = list(self.pack)
            for f in self.pack_per_run:
                pack[f] = pack[f][lo:hi]
            args[self.pack_at] = Pack(*pack)
        t_end, n_ep, n_up, n_tl = run_block(self.spec_marker, self.t0, u, *args)
        if lo:
            args[self.ep_at][:n_ep, 0] += lo
            args[self.up_at][:n_up, 0] += lo
            args[self.tl_at][:n_tl, 0] += lo
        return t_end, n_ep, n_up, n_tl

    def _lane(self, lane: int, groups: Iterable[tuple[int, int, np.ndarray]]) -> tuple:
        """Run a lane's groups of rows, one after the other: ``(last step, [episode
        rows], [update int rows], [update float rows], [timeline rows])``, copies."""
        args = self._lane_args(lane)
        ep, up_i, up_f, tl = (args[j] for j in (self.ep_at, self.up_at, self.up_f_at, self.tl_at))
        t_end, eps, ups_i, ups_f, tls = self.t0, [], [], [], []
        for lo, hi, uu in groups:
            t_g, n_ep, n_up, n_tl = self._call(args, np.ascontiguousarray(uu), lo, hi)
            t_end = max(t_end, int(t_g))
            eps.append(ep[:n_ep].copy())
            ups_i.append(up_i[:n_up].copy())
            ups_f.append(up_f[:n_up].copy())
            tls.append(tl[:n_tl].copy())
        return t_end, eps, ups_i, ups_f, tls

    def run(
        self, lanes: list[tuple[int, int, Iterable[tuple[int, int, np.ndarray]]]]
    ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """Advance the batch by up to ``T`` team steps. ``lanes``: ``(lo, hi, rows)``,
        consecutive ranges of rows covering the batch in order, each with its groups of
        rows ``(a, b, u)`` (``u`` float ``[b - a, T, K, 2]``, or ``[b - a, T, K, 0]``
        when the loop :attr:`draws_itself`; the groups covering ``lo..hi-1`` in order),
        run group after group, each group's arrays (tables, maps, uniforms) kept in
        cache. With several lanes each runs in a thread of its own
        (the loop releases the GIL): the same numbers, as every run is computed alone.

        Returns ``(team steps taken, episode rows int [E, EP_COLS], Q-update rows int
        [U, UP_INT] and float [U, UP_FLOAT])`` (updates only as the recorder wants them);
        the loop stops early when every run has met its episode quota.
        """
        s, p = self.state, self.p
        self.t0 = t0 = s.t
        if len(lanes) == 1:
            done = [self._lane(0, lanes[0][2])]
        else:
            for i, (lo, hi, _) in enumerate(lanes):
                self._lane_args(i, hi - lo)  # allocated here, not in the threads
            pool = _pool(len(lanes))
            futures = [pool.submit(self._lane, i, g) for i, (_, _, g) in enumerate(lanes)]
            try:
                done = [f.result() for f in futures]
            finally:  # an interrupt while waiting: the lanes still finish their calls
                wait(futures)
        t_end = max(d[0] for d in done)
        eps, ups_i, ups_f, tls = ([x for d in done for x in d[j]] for j in range(1, 5))
        if self.timeline is not None:
            for rows_tl in tls:
                self.timeline.add_rows(rows_tl)
        s.t = int(t_end)
        compiled.unpack(self.strategy, self.pack, s)
        # a run that stopped before the batch did sat out its last steps: no wait, no
        # token, and a robot leaving a station released it
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
        one = len(eps) == 1
        return (
            int(t_end) - t0,
            eps[0] if one else np.concatenate(eps),
            ups_i[0] if one else np.concatenate(ups_i),
            ups_f[0] if one else np.concatenate(ups_f),
        )


_POOLS: dict[int, ThreadPoolExecutor] = {}


def _pool(n: int) -> ThreadPoolExecutor:
    """A pool of ``n`` threads, kept for the process (lanes of every batch reuse it)."""
    if n not in _POOLS:
        _POOLS[n] = ThreadPoolExecutor(n, thread_name_prefix="qpatrol-lane")
    return _POOLS[n]
