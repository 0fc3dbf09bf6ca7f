"""Ending episodes in the compiled loop (:meth:`qpatrol.world.World.end_episodes`).

A dot group's episode ends when its dots are all eaten or it reached ``max_ep`` steps:
its row is written, its dots put back, its counters reset; a run that met its episode
quota stops.
"""

from __future__ import annotations

from numba import njit


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def end(r, t, p, s, ep_buf, n_ep, ended):
    """Episodes of run ``r`` at step ``t``: each group whose dots are all eaten, or whose
    episode reached ``p.max_ep`` steps, ends (a row of ``ep_buf`` ``[E, EP_COLS]``: run,
    group, episode, start, dots, cells, states, complete, t; its dots put back) and
    ``ended[g]`` says so; a run that met its episode quota stops (``s.active``). Returns
    the number of episode rows now written."""
    has_dot, max_ep = p.has_dot, p.max_ep
    dots, dots_left, ep_start, ep_count = s.dots, s.dots_left, s.ep_start, s.ep_count
    ep_seen, ep_seen_state = s.ep_seen, s.ep_seen_state
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
            for d in range(ep_seen_state.shape[3]):
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
        row[4] = s.ep_dots[r, g]
        row[5] = cells
        row[6] = states
        row[7] = 1 if complete else 0
        row[8] = t
        n_ep += 1
        dots_left[r, g] = p.n_dots
        s.ep_dots[r, g] = 0
        s.ep_visits[r, g] = 0
        ep_start[r, g] = t
        ep_count[r, g] += 1
    if ended_any and p.quota > 0:
        low = ep_count[r, 0]
        for g in range(1, dots.shape[1]):
            low = min(low, ep_count[r, g])
        s.active[r] = low < p.quota
    return n_ep


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def deadline(ep_start_r, max_ep, never):
    """The first step at which an episode of a run (its groups' start steps
    ``ep_start_r`` ``[G]``) reaches ``max_ep`` steps; ``never`` without a limit: before
    it, and while every group has dots left, no episode ends."""
    if max_ep <= 0:
        return never
    first = ep_start_r[0]
    for g in range(1, ep_start_r.shape[0]):
        first = min(first, ep_start_r[g])
    return first + max_ep


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def due(t, when, left_r):
    """Whether an episode of a run may end at step ``t``: its :func:`deadline` ``when``
    is reached, or a group has no dots left (``left_r`` ``[G]``)."""
    if t >= when:
        return True
    for g in range(left_r.shape[0]):
        if left_r[g] == 0:
            return True
    return False


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def step(r, t, p, s, ep_buf, n_ep, ended, when, never):
    """:func:`end` of run ``r`` at step ``t`` when an episode may end (:func:`due`,
    ``when`` its :func:`deadline`), else only ``ended`` cleared. Returns ``(episode
    rows now written, the run's deadline)``."""
    if due(t, when, s.dots_left[r]):
        n_ep = end(r, t, p, s, ep_buf, n_ep, ended)
        when = deadline(s.ep_start[r], p.max_ep, never)
    else:
        for g in range(ended.shape[0]):
            ended[g] = False
    return n_ep, when
