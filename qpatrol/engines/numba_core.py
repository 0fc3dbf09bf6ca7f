"""The compiled engine: the whole time loop of Q-learning teams, scalar, in numba.

One call advances every run of a batch by a block of team steps, in place, on the same
arrays the numpy engine uses (:class:`qpatrol.world.State`, the learner's ``q``/``n``,
:class:`qpatrol.measures.Measures`, the trajectory ring), so everything after the loop
(summaries, files, checkpoints) is shared. Each step of a run reads like §3 of the
paper: every robot chooses greedily over its open moves (ties and epsilon from the
run's uniforms), the team moves under the traffic rules of :mod:`qpatrol.traffic`,
each robot that entered a cell is paid, and each that made the move it chose updates
``Q(s, a) <- Q(s, a) + (1/N) (r + gamma max Q(s', .) - Q(s, a))``. The arithmetic is
the numpy engine's, operation for operation, so results are equal to the bit.

Covered: ``policy: qlearning`` with ``battery.enabled: off``, any team size, with or
without communication and collision avoidance, ``record.trajectory``; other configs
run on the numpy engine (:func:`qpatrol.engines.compiled_gap`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from qpatrol.world import Params, State

#: Columns of the episode buffer: run, group, episode, start, dots, cells, states,
#: complete, t.
EP_COLS = 9


@njit(cache=True, nogil=True)
def _priority(wait: int, k: int, n_agents: int, t: int) -> int:
    """:func:`qpatrol.traffic.priority` of a patrolling robot (battery off: class 1)."""
    turn = (n_agents - 1) - (k - t) % n_agents
    return (1 << 40) + min(wait, 1 << 30) * n_agents + turn


@njit(cache=True, nogil=True)
def _push_path(nbrs, occ_r, own, start, parent, seen, queue, path):
    """Breadth-first from ``start`` to the nearest empty cell, never through ``own``.

    Fills ``path[:m]`` with ``[start, ..., empty]`` and returns m (0: none). ``parent``
    and ``seen`` are scratch arrays ``[C]`` left clean on return.
    """
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


@njit(cache=True, nogil=True)
def run_block(
    t0,
    u,
    nbrs,
    wall_legal,
    dot_value,
    has_dot,
    inc,
    horizon,
    lam,
    communication,
    avoid,
    diameter,
    max_ep,
    quota,
    use_heading,
    gamma,
    epsilon,
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
    q,
    n,
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
):
    """Advance every active run by up to ``u.shape[1]`` team steps after step ``t0``.

    ``u``: float ``[R, T, K, 2]``. Arrays are the engine's state (see module doc),
    modified in place. Ended episodes are written to ``ep_buf`` ``[E, EP_COLS]``.
    Returns ``(last team step taken by any run, episode rows written)``.
    """
    n_runs, n_steps, n_agents = u.shape[0], u.shape[1], u.shape[2]
    n_cells = nbrs.shape[0]
    n_groups = dots.shape[1]
    n_dots = 0
    for c in range(n_cells):
        if has_dot[c]:
            n_dots += 1
    want = np.empty(n_agents, np.int64)
    ask = np.empty(n_agents, np.int64)
    prev_pos = np.empty(n_agents, np.int64)
    prev_head = np.empty(n_agents, np.int64)
    moved = np.empty(n_agents, np.bool_)
    as_asked = np.empty(n_agents, np.bool_)
    reward = np.empty(n_agents, np.float64)
    blocked_by = np.empty(n_agents, np.int64)
    order = np.empty(n_agents, np.int64)
    key = np.empty(n_agents, np.int64)
    mask = np.empty(4, np.bool_)
    cand = np.empty(4, np.int64)
    parent = np.full(n_cells, -2, np.int64)
    seen = np.empty(n_cells, np.int64)
    queue = np.empty(n_cells, np.int64)
    path = np.empty(n_cells, np.int64)
    t_end = t0
    n_ep = 0
    for r in range(n_runs):
        for i in range(n_steps):
            if not active[r]:
                break
            t = t0 + i + 1
            tok = token[r]
            # --- choose (qlearning.act): greedy over open moves, ties by u[..., 1] ----
            for k in range(n_agents):
                c = pos[r, k]
                h = head[r, k] if use_heading else 0
                any_open = False
                for d in range(4):
                    nb = nbrs[c, d]
                    ok = nb >= 0
                    if ok and avoid and k != tok and occ[r, nb] >= 0:
                        ok = False
                    mask[d] = ok
                    any_open = any_open or ok
                if not any_open:
                    for d in range(4):
                        mask[d] = nbrs[c, d] >= 0
                best = -np.inf
                for d in range(4):
                    if mask[d] and q[r, k, c, h, d] > best:
                        best = q[r, k, c, h, d]
                explore = epsilon > 0.0 and u[r, i, k, 0] < epsilon
                count = 0
                for d in range(4):
                    if mask[d] and (explore or q[r, k, c, h, d] == best):
                        cand[count] = d
                        count += 1
                if count == 0:
                    ask[k] = -1
                    want[k] = -1
                else:
                    j = min(np.int64(u[r, i, k, 1] * count), count - 1)
                    ask[k] = cand[j]
                    want[k] = nbrs[c, cand[j]]
                prev_pos[k] = c
                prev_head[k] = head[r, k]
                moved[k] = False
                as_asked[k] = False
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
                    own = pos[r, tok]
                    dest = -1
                    m = 0
                    for ci in range(5):
                        if ci == 0:
                            cell = want[tok]
                        else:
                            cell = nbrs[own, ci - 1]
                            if cell < 0 or cell == want[tok]:
                                continue
                        if occ[r, cell] < 0:
                            dest = cell
                            m = 0
                            break
                        m = _push_path(nbrs, occ[r], own, cell, parent, seen, queue, path)
                        if m > 0:
                            dest = cell
                            break
                    if dest < 0:
                        push_failed = True
                    else:
                        for x in range(m - 2, -1, -1):
                            jr = occ[r, path[x]]
                            occ[r, pos[r, jr]] = -1
                            occ[r, path[x + 1]] = jr
                            pos[r, jr] = path[x + 1]
                            moved[jr] = True
                            as_asked[jr] = want[jr] == path[x + 1]
                        occ[r, pos[r, tok]] = -1
                        occ[r, dest] = tok
                        pos[r, tok] = dest
                        moved[tok] = True
                        as_asked[tok] = dest == want[tok]
                        push_failed = not as_asked[tok]
                # 2. everyone else, in priority order, into cells empty at that moment
                for k in range(n_agents):
                    key[k] = _priority(wait[r, k], k, n_agents, t)
                    order[k] = k
                for a in range(1, n_agents):  # insertion sort, largest key first
                    x = order[a]
                    b = a - 1
                    while b >= 0 and key[order[b]] < key[x]:
                        order[b + 1] = order[b]
                        b -= 1
                    order[b + 1] = x
                progress = True
                while progress:
                    progress = False
                    for a in range(n_agents):
                        k = order[a]
                        w = want[k]
                        if w >= 0 and not moved[k] and occ[r, w] < 0:
                            occ[r, pos[r, k]] = -1
                            occ[r, w] = k
                            pos[r, k] = w
                            moved[k] = True
                            as_asked[k] = True
                            progress = True
            # --- entering a cell: dots, visits, reward, heading -------------------------
            for k in range(n_agents):
                reward[k] = 0.0
                if not moved[k]:
                    continue
                g = 0 if communication else k
                c0 = prev_pos[k]
                c1 = pos[r, k]
                a = 0
                for d in range(4):
                    if nbrs[c0, d] == c1:
                        a = d
                        break
                ate = dots[r, g, c1]
                dots[r, g, c1] = False
                if ate:
                    dots_left[r, g] -= 1
                    ep_dots[r, g] += 1
                ep_visits[r, g] += 1
                idle = t - last[r, g, c1]
                last[r, g, c1] = t
                ep_seen[r, g, c1] = True
                ep_seen_state[r, g, c1, a] = True
                reward[k] = (
                    (dot_value[c1] if ate else 0.0)
                    + inc * min(1.0, idle / horizon)
                    + lam * ep_dots[r, g] / ep_visits[r, g]
                )
                head[r, k] = a
            # --- waits, who blocked whom, the right of way -----------------------------
            for k in range(n_agents):
                failed = ask[k] >= 0 and not as_asked[k]
                wait[r, k] = wait[r, k] + 1 if failed else 0
                blocked_by[k] = occ[r, want[k]] if failed else -1
            if avoid and n_agents > 1:
                best_k = -1
                best_key = -1
                for k in range(n_agents):
                    kk = -1
                    if want[k] >= 0 and not as_asked[k]:
                        kk = _priority(wait[r, k], k, n_agents, t + 1)
                    if tok >= 0 and push_failed and k == tok:
                        kk = -1
                    if kk > best_key:
                        best_key = kk
                        best_k = k
                new = best_k
                if tok >= 0:
                    blocker = blocked_by[tok]
                    blocker_waits = blocker >= 0 and want[blocker] >= 0 and not as_asked[blocker]
                    if as_asked[tok] and token_held[r] < diameter:
                        new = tok
                    elif push_failed and blocker_waits:
                        new = blocker
                token_held[r] = token_held[r] + 1 if (new == tok and new >= 0) else 0
                token[r] = new
            steps_done[r] = t
            # --- episodes: all dots eaten, or too long ---------------------------------
            ended_any = False
            for g in range(n_groups):
                complete = dots_left[r, g] == 0
                if not (complete or (max_ep > 0 and t - ep_start[r, g] >= max_ep)):
                    continue
                ended_any = True
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
                for g in range(1, n_groups):
                    low = min(low, ep_count[r, g])
                active[r] = low < quota
            # --- learn (qlearning.learn): robots that made the move they chose ----------
            for k in range(n_agents):
                if not as_asked[k] or ask[k] < 0:
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
            # --- measures (Measures.observe) and the trajectory ring -------------------
            in_window = t > warmup
            for k in range(n_agents):
                if not moved[k]:
                    continue
                c = pos[r, k]
                prev = m_last[r, c]
                m_last[r, c] = t
                m_last_sum[r] += t - prev
                visits[r, k, c] += 1
                if in_window:
                    window_visits[r, k, c] += 1
                    gap = t - prev if prev > 0 else 0
                    gap_sum[r] += gap
                    if prev > 0:
                        gap_count[r] += 1
                    gap_max[r] = max(gap_max[r], gap)
                    if t - 1 > warmup:
                        worst[r] = max(worst[r], t - 1 - prev)
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
                for k in range(n_agents):
                    tail_pos[r, (t - 1) % tail_n, k] = pos[r, k]
            if t > t_end:
                t_end = t
    return t_end, n_ep


def advance(
    state: State,
    p: Params,
    strategy,
    measures,
    tail,
    u: np.ndarray,
) -> tuple[int, np.ndarray]:
    """Advance the batch by up to ``u.shape[1]`` team steps (``u``: float ``[R, T, K, 2]``).

    Returns ``(team steps taken, episode rows int [E, EP_COLS])``; the loop stops early
    when every run has met its episode quota.
    """
    s, m = state, measures
    n_runs, n_steps, k = u.shape[:3]
    n_dots = int(p.has_dot.sum())
    shortest = -(-n_dots // k)
    if p.max_episode_steps:
        shortest = min(shortest, p.max_episode_steps)
    cap = n_runs * p.n_groups * (n_steps // max(1, shortest) + 1)
    ep_buf = np.empty((cap, EP_COLS), dtype=np.int64)
    tail_pos = tail.pos if tail.n else np.zeros((1, 1, 1), dtype=np.int64)
    t0 = s.t
    t_end, n_ep = run_block(
        t0,
        u,
        p.neighbors,
        p.wall_legal,
        p.dot_value,
        p.has_dot,
        p.incremental_value,
        p.idle_horizon,
        p.lambda_weight,
        p.communication,
        p.avoid_collisions,
        p.diameter,
        p.max_episode_steps,
        p.episodes,
        strategy.use_heading,
        strategy.gamma,
        strategy.epsilon,
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
        strategy.q,
        strategy.n,
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
        ep_buf,
    )
    s.t = int(t_end)
    # a run that stopped before the batch did sat out its last steps: no wait, no token
    out = s.steps_done < s.t
    if out.any():
        s.wait[out] = 0
        s.token[out] = -1
        s.token_held[out] = 0
    return int(t_end) - t0, ep_buf[:n_ep]
