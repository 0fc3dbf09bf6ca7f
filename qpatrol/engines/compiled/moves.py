"""The team's moves in the compiled loop: :mod:`qpatrol.world.traffic`, one run at a time.

``open_moves`` (world.begin_step: each robot's open moves), ``resolve`` (the holder of
the right of way first, pushing robots aside, then the others in priority order into
cells empty at that moment), ``waits`` (who waits, who blocked whom) and
``pass_token`` (the right of way for the next step). ``p``, ``s``, ``w``: the loop's
:class:`~qpatrol.engines.compiled.bundles.Params`, ``World`` and ``Work``; ``r`` the run.
"""

from __future__ import annotations

from numba import njit

from qpatrol.engines.compiled.bundles import INTERFERENCE
from qpatrol.engines.compiled.choice import ports_of
from qpatrol.engines.compiled.stations import (
    CHARGING,
    GONE,
    HOMING,
    PATROL,
    QUEUED,
    closed,
    kept_out,
)


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def turn_of(k, n_agents, t_mod):
    """Robot k's turn at step t (``t_mod = t % n_agents``, taken once per step: an
    integer division per robot cost more than the rest of this): ``(n_agents - 1) - (k -
    t) % n_agents``."""
    back = k - t_mod  # (k - t) % n_agents, without a division
    if back < 0:
        back += n_agents
    return (n_agents - 1) - back


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def priority(age, k, n_agents, t_mod):
    """:func:`qpatrol.world.traffic.priority` of robot k at step t: the age of its task
    (``t - since``, clipped to ``[0, 2^30]``), then its turn (:func:`turn_of`)."""
    return min(max(age, 0), 1 << 30) * n_agents + turn_of(k, n_agents, t_mod)


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def push_path(
    nbrs, entry, occ_r, own, start, scratch, battery, mode_r, pocket_of, pocket_depth, reserved_r
):
    """Breadth-first from ``start`` to the nearest empty cell, never through ``own``,
    charging robots, nor (battery on) into a held pocket or deeper inside one (a step
    towards its junction is allowed).

    ``scratch``: the loop's ``(w.parent, w.seen, w.queue, w.path)`` (four arrays, not
    the whole ``Work``: fewer arguments to pass). Fills ``path[:m]`` with ``[start, ...,
    empty]`` and returns m (0: none). ``parent`` (-2 everywhere) and ``seen`` are
    scratch arrays ``[C]`` left clean. ``entry``: ``Params.entry`` (None on a grid: D
    = 4 a constant, :func:`~qpatrol.engines.compiled.choice.ports_of`).
    """
    parent, seen, queue, path = scratch
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
        for d in range(ports_of(entry, nbrs.shape[1])):
            nb = nbrs[c, d]
            if nb < 0 or nb == own or parent[nb] != -2:
                continue
            if battery:
                if kept_out(nb, pocket_of, reserved_r) and (
                    pocket_of[nb] != pocket_of[c] or pocket_depth[nb] >= pocket_depth[c]
                ):
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
def holder_moves(
    tok, nbrs, entry, occ_r, pos_r, w, battery, mode_r, pocket_of, pocket_depth, reserved_r
):
    """:func:`qpatrol.world.traffic.holder_step` of the right-of-way holder ``tok`` of a run
    (``w.want[tok] >= 0``; ``occ_r``, ``pos_r`` its rows): into the cell it asks for,
    empty or emptied by pushing the robots in the way along :func:`push_path`. Returns
    whether the push failed (it did not move)."""
    want, moved, as_asked, path = w.want, w.moved, w.as_asked, w.path
    own = pos_r[tok]
    dest = want[tok]
    m = 0
    if occ_r[dest] >= 0:
        scratch = (w.parent, w.seen, w.queue, w.path)
        m = push_path(
            nbrs, entry, occ_r, own, dest, scratch, battery, mode_r, pocket_of, pocket_depth,
            reserved_r,
        )  # fmt: skip
        if m == 0:
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
    as_asked[tok] = True
    return False


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
def _move_in_order(order, want, moved, as_asked, occ_r, pos_r, swapped):
    """Step 2 of :func:`qpatrol.world.traffic.resolve`: the robots that have not moved
    (nor exchanged tasks: ``swapped``), in ``order``, each into the cell it wants if that
    cell is empty at that moment, pass after pass until a pass moves no one or leaves no
    one behind."""
    progress = True
    while progress:
        progress = False
        behind = False
        for a in range(order.shape[0]):
            k = order[a]
            w = want[k]
            if w >= 0 and not moved[k] and swapped[k] < 0:
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
def pushable(r, c, nb, battery, p, s, w):
    """Whether the holder of the right of way on cell ``c`` of run ``r`` can enter its
    occupied neighbour ``nb``: a push path empties it (:func:`push_path`;
    traffic.feasible_moves)."""
    scratch = (w.parent, w.seen, w.queue, w.path)
    occ_r, mode_r, reserved_r = s.occ[r], s.mode[r], s.reserved[r]
    m = push_path(
        p.nbrs, p.entry, occ_r, c, nb, scratch, battery, mode_r, p.pocket_of, p.pocket_depth,
        reserved_r,
    )  # fmt: skip
    return m > 0


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def open_moves(r, tok, battery, avoid, p, s, w):
    """world.begin_step of run ``r``: who chooses (patrolling robots), and each robot's
    open moves ``w.open_mask`` (legal, not deeper into another robot's held station
    pocket (battery.closed_cells), not into a robot's cell but for the holder of the
    right of way ``tok``, who may move where a push makes room
    (traffic.feasible_moves); every legal move where none is open, base.prefer_open); the
    step's outcome cleared (``w.prev_pos``, ``prev_head``, ``moved``, ...)."""
    nbrs, pocket_of, pocket_depth, occ = p.nbrs, p.pocket_of, p.pocket_depth, s.occ
    nd = ports_of(p.entry, nbrs.shape[1])
    for k in range(s.pos.shape[1]):
        c = s.pos[r, k]
        # battery.shut_in: a patrolling robot inside another robot's held pocket steps out
        w.choosing[k] = s.mode[r, k] == PATROL and not (
            battery and pocket_of[c] >= 0 and s.reserved[r, pocket_of[c]] >= 0
            and s.reserved[r, pocket_of[c]] != k
        )  # fmt: skip
        w.held_back[k] = False
        w.yielding[k] = False
        any_open = False
        for d in range(nd):
            nb = nbrs[c, d]
            ok = nb >= 0 and not closed(r, k, c, nb, battery, pocket_of, pocket_depth, s.reserved)
            if ok and avoid and occ[r, nb] >= 0:
                # the holder of the right of way: a move a push can make room for
                ok = k == tok and pushable(r, c, nb, battery, p, s, w)
            w.open_mask[k, d] = ok
            any_open = any_open or ok
        if not any_open:
            for d in range(nd):
                w.open_mask[k, d] = nbrs[c, d] >= 0
        w.prev_pos[k] = c
        w.prev_head[k] = s.head[r, k]
        w.moved[k] = False
        w.as_asked[k] = False


@njit(cache=True, nogil=True, _nrt=False)
def travellers(r, p, s, w):
    """world.travelling of run ``r`` on a patrol graph with waypoints: a choosing robot
    on a waypoint does not choose (``w.choosing`` False) and asks for the port that
    continues its edge, ``w.travel[k] = p.onward[cell, heading]``; -1 for the others."""
    for k in range(s.pos.shape[1]):
        w.travel[k] = -1
        if w.choosing[k]:
            on = p.onward[s.pos[r, k], s.head[r, k]]
            if on >= 0:
                w.choosing[k] = False
                w.travel[k] = on


@njit(cache=True, nogil=True, _nrt=False)
def turn_round(r, p, s, w):
    """:func:`qpatrol.world.turn_round` of run ``r``: a robot travelling an edge whose
    strategy asks for the port behind it (its heading), a free cell, turns round: its
    heading becomes its onward port (``w.travel``), and it asks for the one behind."""
    for k in range(w.travel.shape[0]):
        back = s.head[r, k]
        if w.travel[k] >= 0 and w.ask[k] == back and s.occ[r, p.nbrs[s.pos[r, k], back]] < 0:
            w.travel[k], s.head[r, k] = back, w.travel[k]


@njit(cache=True, nogil=True, _nrt=False)
def travel_asks(w):
    """After the strategy's choice: each travelling robot asks for its onward port."""
    for k in range(w.travel.shape[0]):
        if w.travel[k] >= 0:
            w.ask[k] = w.travel[k]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def resolve(r, t, tok, t_mod, battery, avoid, p, s, w, plans=False):
    """:func:`qpatrol.world.traffic.resolve` of run ``r`` at step ``t`` (each robot's
    ``w.want``, -1 for none): without collision avoidance every robot moves as asked
    but a stopped one (:func:`stopped`); with it the holder ``tok`` of the right of way
    moves first (:func:`holder_moves`; if it cannot, or head on with a patrolling robot,
    :func:`hand_on`), then the others in
    priority order (:func:`priority`), each into a cell empty at that moment, but two
    robots that exchanged tasks (``plans``: the robots' goals are allocated tasks, on a
    patrol graph with waypoints; a holder head on with one hands on). Sets ``w.moved``,
    ``w.as_asked``, ``w.swapped``; returns the robot that received the failed holder's
    task or age (-1: none)."""
    n_agents = s.pos.shape[1]
    pos_r, occ_r, mode_r = s.pos[r], s.occ[r], s.mode[r]
    want, moved, as_asked, order, key = w.want, w.moved, w.as_asked, w.order, w.key
    handoff = -1
    for k in range(n_agents):
        w.swapped[k] = -1
    if not avoid:
        for k in range(n_agents):
            if want[k] >= 0 and not stopped(t, s.met[r, k], p):
                pos_r[k] = want[k]
                moved[k] = True
                as_asked[k] = True
        return handoff
    if tok >= 0 and want[tok] >= 0:
        b = occ_r[want[tok]]
        both = mode_r[tok] == PATROL and b >= 0 and mode_r[b] == PATROL
        if plans and both and want[b] == pos_r[tok]:
            # head on (traffic.head_on): the two exchange tasks rather than push
            handoff = hand_on(r, tok, b, s, w)
        else:
            failed = holder_moves(
                tok, p.nbrs, p.entry, occ_r, pos_r, w, battery, mode_r, p.pocket_of,
                p.pocket_depth, s.reserved[r],
            )  # fmt: skip
            if failed and occ_r[want[tok]] >= 0:
                handoff = hand_on(r, tok, occ_r[want[tok]], s, w)
    if n_agents == 1:  # alone: the priority order is trivial
        wk = want[0]
        if wk >= 0 and not moved[0] and occ_r[wk] < 0:
            occ_r[pos_r[0]] = -1
            occ_r[wk] = 0
            pos_r[0] = wk
            moved[0] = True
            as_asked[0] = True
        return handoff
    for k in range(n_agents):
        key[k] = priority(t - s.since[r, k], k, n_agents, t_mod)
        order[k] = k
    _sort_by_key(order, key, n_agents)
    _move_in_order(order, want, moved, as_asked, occ_r, pos_r, w.swapped)
    return handoff


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def hand_on(r, k, b, s, w):
    """:func:`qpatrol.world.traffic.hand_on`: the holder k of run r could not enter robot
    b's cell: if both patrol they exchange tasks (``aim``, ``since``; ``w.swapped``),
    else b inherits the holder's age if it is the older and the holder takes b's.
    Returns b (handed the task: first for the token among equal ages)."""
    if s.mode[r, k] == PATROL and s.mode[r, b] == PATROL:
        s.aim[r, k], s.aim[r, b] = s.aim[r, b], s.aim[r, k]
        s.since[r, k], s.since[r, b] = s.since[r, b], s.since[r, k]
        w.swapped[k] = b
        w.swapped[b] = k
    elif s.since[r, k] < s.since[r, b]:
        s.since[r, k], s.since[r, b] = s.since[r, b], s.since[r, k]
    return b


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def waits(r, battery, avoid, s, w, unchanged=False):
    """After the moves: each robot that asked and did not move as asked waits one step
    more (``s.wait``), and ``w.blocked_by`` names the robot in its way; a queued or
    held-back robot waits too (battery). ``unchanged``: a caller's promise that no wait
    changes (battery off, no robot waited before a step in which every robot that asked
    moved as asked, :func:`clear`): nothing to write, and ``w.blocked_by`` is left as it
    was, as no robot was blocked. Returns ``(robots waiting, longest wait)``."""
    waiting = 0
    longest = 0
    for k in range(0 if unchanged else s.pos.shape[1]):
        failed = w.ask[k] >= 0 and not w.as_asked[k]
        # the robot standing in the asked cell (with robots passing each other, none)
        w.blocked_by[k] = s.occ[r, w.want[k]] if failed and avoid else -1
        if battery and (s.mode[r, k] == QUEUED or w.held_back[k]):
            failed = True
        wk = s.wait[r, k] + 1 if failed else 0
        s.wait[r, k] = wk
        if wk > 0:
            waiting += 1
        longest = max(longest, wk)
    return waiting, longest


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def pass_token(r, t_next, t_next_mod, tok, held, handoff, s, w):
    """:func:`qpatrol.world.traffic.pass_token` of run ``r`` after its moves: to the robot
    with the oldest task at step ``t_next`` among the blocked robots (asked, did not
    move as asked), the holder if it still pursues its task (asked, did not progress)
    and the robot that received the failed holder's task or age (``handoff``); among
    equal ages that robot first, then the holder, then the turn; none: -1. Returns
    ``(holder, steps it has held it)``."""
    want, as_asked = w.want, w.as_asked
    n_agents = want.shape[0]
    new = -1
    best_key = -1
    for k in range(n_agents):
        holder = k == tok and want[k] >= 0 and not w.progressed[k] and s.active[r]
        handed = k == handoff
        if not (handed or holder or (want[k] >= 0 and not as_asked[k] and s.active[r])):
            continue
        first = turn_of(k, n_agents, t_next_mod)
        if holder:
            first = n_agents
        if handed:
            first = n_agents + 1
        age = min(max(t_next - s.since[r, k], 0), 1 << 30)
        kk = age * (n_agents + 2) + first
        if kk > best_key:
            best_key = kk
            new = k
    return new, (held + 1 if (new == tok and new >= 0) else 0)


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def tasks(r, battery, p, s, w):
    """:func:`qpatrol.world.task_aims` of run ``r``: each robot's aim this step
    (``s.aim``): its strategy's (``w.aim``) for a choosing robot, the vertex ahead for
    one travelling an edge, its station for a homing robot, -1 for the others; and its
    mode as it asks (``w.mode0``)."""
    for k in range(s.pos.shape[1]):
        a = -1
        if w.choosing[k]:
            a = w.aim[k]
        if p.travels and w.travel[k] >= 0:
            a = p.ahead[s.pos[r, k], s.head[r, k]]
        if battery and s.mode[r, k] == HOMING:
            a = p.homes[max(s.goal[r, k], 0)]
        s.aim[r, k] = a
        w.mode0[k] = s.mode[r, k]


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def turn_back(r, p, s, w):
    """:func:`qpatrol.world.turn_back`: robots of run ``r`` travelling an edge that took
    over a task whose aim is the vertex behind them, or the task of a robot that asked
    for their cell, turn round."""
    for k in range(s.pos.shape[1]):
        if w.swapped[k] < 0 or w.travel[k] < 0:
            continue
        c = s.pos[r, k]
        onward = p.onward[c, s.head[r, k]]
        if onward < 0:
            continue
        behind = p.ahead[c, onward]
        head_on = w.want[w.swapped[k]] == c
        if head_on or (s.aim[r, k] == behind and s.aim[r, k] != p.ahead[c, s.head[r, k]]):
            s.head[r, k] = onward


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def progress(r, t, p, s, w):
    """The tasks of run ``r`` that ended at step ``t`` (``w.progressed``; ``s.since = t``):
    a robot on its aim that entered it or was handed it (patrolling or homing when it
    asked) or, with none and patrolling, entered a target."""
    for k in range(s.pos.shape[1]):
        m0 = w.mode0[k]
        a = s.aim[r, k]
        done = False
        if a >= 0:
            got = w.moved[k] or w.swapped[k] >= 0
            done = got and s.pos[r, k] == a and (m0 == PATROL or m0 == HOMING)
        else:
            done = m0 == PATROL and w.moved[k] and p.target[s.pos[r, k]]
        w.progressed[k] = done
        if done:
            s.since[r, k] = t


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def stopped(t, met, p):
    """:func:`qpatrol.world.interference.stopped`: a robot that met another at the end of
    step ``met`` does not move in the ``p.stop_steps`` steps after (interference only)."""
    return p.interaction == INTERFERENCE and t - met <= p.stop_steps


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def meet(r, t, p, s, w):
    """:func:`qpatrol.world.interference.meet` of run ``r`` at the end of step ``t``: each
    robot that moved (``w.moved``), is off its cooldown and stands within ``p.radius``
    moves of a robot of lower index (``p.ball`` of its cell holds that robot's cell,
    marked in ``w.mark`` with this call's ``w.stamp``), or swapped cells with one (radius
    0), stops: ``s.met[r, k] = t``. Failed robots stand nowhere."""
    w.stamp[0] += 1
    stamp = w.stamp[0]
    ball, mark = p.ball, w.mark
    for j in range(s.pos.shape[1]):
        if s.mode[r, j] == GONE:
            continue
        c = s.pos[r, j]
        if w.moved[j] and t - s.met[r, j] >= p.cooldown:
            hit = False
            for b in range(ball.shape[1]):
                x = ball[c, b]
                if x < 0:
                    break
                if mark[x] == stamp:
                    hit = True
                    break
            if not hit and p.radius == 0:
                for i in range(j):
                    if s.mode[r, i] != GONE and w.prev_pos[i] == c and s.pos[r, i] == w.prev_pos[j]:
                        hit = True
                        break
            if hit:
                s.met[r, j] = t
        mark[c] = stamp


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def clear(want, occ_r, avoid):
    """Whether a step has no conflict: every robot that asks (``want`` ``[K]``, -1 for
    none) asks for a cell that is empty now (``occ_r`` ``[C]``) and that no other asks
    for (or collisions are not avoided). Then :func:`resolve` moves every robot as
    asked whatever the order (the holder of the right of way pushes no one), and no one
    waits: a loop may move them directly (:func:`step_into`)."""
    if not avoid:
        return True
    n_agents = want.shape[0]
    for a in range(n_agents):
        wa = want[a]
        if wa >= 0:
            if occ_r[wa] >= 0:
                return False
            for b in range(a + 1, n_agents):
                if want[b] == wa:
                    return False
    return True


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def step_into(k, c1, avoid, occ_r, pos_r):
    """Robot ``k`` leaves its cell for ``c1`` (``pos_r`` ``[K]``; with ``avoid`` the
    occupancy ``occ_r`` ``[C]`` follows)."""
    if avoid:
        occ_r[pos_r[k]] = -1
        occ_r[c1] = k
    pos_r[k] = c1
