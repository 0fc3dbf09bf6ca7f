"""Entering cells in the compiled loop: each robot that moved takes its new cell.

The world's step after the moves (:meth:`qpatrol.world.World.enter`): the robot's dot
group eats the cell's dot, the cell's last visit and the episode's cells and states
seen take the visit, the robot's heading is the move it entered by (``Map.entry``: on a
patrol graph the port of the new cell it arrived through), and it is paid
``dot + inc min(1, idle / horizon) + lam eaten / entered``.
"""

from __future__ import annotations

from numba import njit

from qpatrol.engines.compiled.choice import heading_of, ports_of


@njit(cache=True, nogil=True, _nrt=False)
def enter(c0, c1, asked, t, nbrs, entry, dot_value, grp, cnt, weights):
    """A robot of a dot group moves from cell ``c0`` into ``c1`` at step ``t`` (as it
    ``asked``, or -1: pushed or unknown). ``grp``: the group's dots, last visits, cells
    and states seen this episode (``[C]``, ``[C]``, ``[C]``, ``[C, D]``); ``cnt``: its
    episode's dots left, eaten and cells entered; ``weights``: ``(inc, horizon, lam)``;
    ``entry`` int ``[C, D]``: the heading after each move (``Map.entry``), None on a
    grid (``bundles.Params.entry``). Returns
    ``(heading entered, dot eaten, cnt, reward)``."""
    dots_g, last_g, seen_g, seen_state_g = grp
    left, eaten, entered = cnt
    inc, horizon, lam = weights
    nd = ports_of(entry, nbrs.shape[1])
    if asked >= 0 and nd == 4:
        # it moved as asked: the first direction into c1 is at most that one
        nb = nbrs[c0]
        a = asked
        a = 2 if (nb[2] == c1) & (asked > 2) else a
        a = 1 if (nb[1] == c1) & (asked > 1) else a
        a = 0 if (nb[0] == c1) & (asked > 0) else a
    else:  # the first port into c1
        a = 0
        for d in range(nd):
            if nbrs[c0, d] == c1:
                a = d
                break
    a = heading_of(entry, c0, a)  # a graph's: the port of c1 arrived through
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
    return a, ate, (left, eaten, entered), reward


@njit(cache=True, nogil=True, _nrt=False)
def group_enters(r, g, c0, c1, asked, t, p, s):
    """:func:`enter` for a robot of group ``g`` of run ``r``, its counters read from and
    stored to the world ``s``. Returns ``(heading entered, dot eaten, reward)``."""
    grp = (s.dots[r, g], s.last[r, g], s.ep_seen[r, g], s.ep_seen_state[r, g])
    cnt = (s.dots_left[r, g], s.ep_dots[r, g], s.ep_visits[r, g])
    weights = (p.reward_w[r, 0], p.reward_w[r, 1], p.reward_w[r, 2])
    a, ate, cnt, reward = enter(c0, c1, asked, t, p.nbrs, p.entry, p.dot_value, grp, cnt, weights)
    s.dots_left[r, g], s.ep_dots[r, g], s.ep_visits[r, g] = cnt
    return a, ate, reward


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def all_enter(r, t, p, s, w):
    """Each robot of run ``r`` that moved enters its cell (:func:`group_enters`, its
    group the team's with communication, else its own): ``s.head``, ``w.eaten``,
    ``w.reward`` (0 for the others)."""
    for k in range(s.pos.shape[1]):
        w.reward[k] = 0.0
        w.eaten[k] = False
        if not w.moved[k]:
            continue
        g = 0 if p.communication else k
        s.head[r, k], w.eaten[k], w.reward[k] = group_enters(
            r, g, w.prev_pos[k], s.pos[r, k], -1, t, p, s
        )
