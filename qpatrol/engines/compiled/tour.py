"""``learned-tour`` compiled: a routing table learned by local search on its route.

The numpy twin is :mod:`qpatrol.strategies.learned_tour`; per run, in its order
(:func:`learn_routes`): each learner with a patrolling robot on its route makes one
proposal from its robot's first uniform (a restart from the best order with a double
bridge after ``kick_after`` proposals without a shortening; else a 2-opt or an or-opt
move kept when the order does not lengthen); a strictly shorter best order's route
(expanded by shortest paths, repaired), if shorter than the robots' route, becomes
theirs: each heads for the route cell nearest its old target, with spacing
``floor(n / K)``. Then the loop has the robots follow their routes (:func:`routes`) as
``cyclic``'s follow their walk, with the same inlined
:func:`qpatrol.engines.compiled.follow.act`.

Pack: ``robot_i`` as :mod:`~qpatrol.engines.compiled.follow`'s; ``cell_i`` int64
``[R, 6 G + 5, M]``, rows (``G`` learners): ``0..G-1`` the routes (the follower's
``walk``), ``G`` their lengths, then ``G`` rows each of ``order``, ``best`` and
``pos``, a row of scalars (``cur_len``, ``best_len``, ``stall``, history count per
learner), two rows per learner of history (team steps, lengths), three scratch rows;
``table_i`` = the nearest targets ``[C, n]``; ``dist`` int64 ``[C, C]``; ``ipar = [0,
0, width, early exchanges on, spacing rule on, G, kick_after, T, kick window,
learn_steps (-1: the whole run), 0 (follow.py's rows mode, off)]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from qpatrol.engines.compiled import follow
from qpatrol.engines.compiled.pack import Pack, dummy_pack

DRAW = 2147483648.0  # learned_tour.DRAW


def _rows(G: int) -> dict[str, int]:
    """First row of each block of ``cell_i``."""
    return {
        "order": G + 1,
        "best": 2 * G + 1,
        "pos": 3 * G + 1,
        "scalar": 4 * G + 1,
        "history": 4 * G + 2,
        "scratch": 6 * G + 2,
    }


def pack(strategy) -> Pack:
    """Every learner's orders, routes and history, and each robot's follower columns."""
    fp = follow.pack(strategy)
    R, G, T = strategy.order.shape
    C = strategy.pos.shape[-1]
    D = strategy.params.neighbors.shape[1]
    width = strategy.walk.shape[-1]
    M = max(width, T, C * D, 4 * G, C)
    rows = _rows(G)
    cell = np.zeros((R, 6 * G + 5, M), dtype=np.int64)
    cell[:, :G, :width] = strategy.walk
    cell[:, G, :G] = strategy.length
    cell[:, rows["order"] : rows["order"] + G, :T] = strategy.order
    cell[:, rows["best"] : rows["best"] + G, :T] = strategy.best
    cell[:, rows["pos"] : rows["pos"] + G, :C] = strategy.pos
    cell[:, rows["scratch"] + 1] = -1  # the repair's first position of each move
    sc = rows["scalar"]
    for r in range(R):
        for g in range(G):
            hist = strategy.history[r][g]
            if len(hist) > M:
                raise ValueError("learned-tour: more route changes than the pack holds")
            cell[r, sc, 4 * g : 4 * g + 4] = (
                strategy.cur_len[r, g],
                strategy.best_len[r, g],
                strategy.stall[r, g],
                len(hist),
            )
            h = rows["history"] + 2 * g
            cell[r, h, : len(hist)] = [s for s, _ in hist]
            cell[r, h + 1, : len(hist)] = [n for _, n in hist]
    ipar = np.array(
        [0, 0, width, fp.ipar[3], fp.ipar[4], G, strategy.kick_after, T, 40, strategy.learn_steps]
        + [0],  # no rows mode (follow.py): learned-tour keeps the table
        dtype=np.int64,
    )
    return dummy_pack(
        ipar=ipar,
        robot_i=fp.robot_i,
        cell_i=cell,
        table_i=np.ascontiguousarray(strategy.near, dtype=np.int64),
        dist=fp.dist,
    )


def unpack(p: Pack, strategy) -> None:
    """Copy the learners and the robots back into the strategy."""
    follow.unpack(p, strategy)
    R, G, T = strategy.order.shape
    C = strategy.pos.shape[-1]
    width = strategy.walk.shape[-1]
    rows = _rows(G)
    cell = p.cell_i
    strategy.walk = cell[:, :G, :width].copy()
    strategy.length = cell[:, G, :G].copy()
    strategy.order = cell[:, rows["order"] : rows["order"] + G, :T].copy()
    strategy.best = cell[:, rows["best"] : rows["best"] + G, :T].copy()
    strategy.pos = cell[:, rows["pos"] : rows["pos"] + G, :C].copy()
    sc = cell[:, rows["scalar"]]
    strategy.cur_len = sc[:, 0 : 4 * G : 4].copy()
    strategy.best_len = sc[:, 1 : 4 * G : 4].copy()
    strategy.stall = sc[:, 2 : 4 * G : 4].copy()
    for r in range(R):
        for g in range(G):
            n = int(sc[r, 4 * g + 3])
            h = rows["history"] + 2 * g
            strategy.history[r][g] = [
                (int(a), int(b)) for a, b in zip(cell[r, h, :n], cell[r, h + 1, :n], strict=True)
            ]


sat_out = follow.sat_out


@njit(cache=True, nogil=True, _nrt=False)
def _order_length(order, T, dist):
    s = 0
    for k in range(T):
        s += dist[order[k], order[(k + 1) % T]]
    return s


@njit(cache=True, nogil=True, _nrt=False)
def _reverse(order, pos, i, j):
    while i < j:
        a = order[i]
        b = order[j]
        order[i] = b
        pos[b] = i
        order[j] = a
        pos[a] = j
        i += 1
        j -= 1


@njit(cache=True, nogil=True, _nrt=False)
def _two_opt(order, pos, T, dist, near, x):
    i = x % T
    x //= T
    a = order[i]
    b = order[(i + 1) % T]
    c = near[a, x % near.shape[1]]
    j = pos[c]
    d = order[(j + 1) % T]
    if c == b or d == a:
        return 0
    delta = dist[a, c] + dist[b, d] - dist[a, b] - dist[c, d]
    if delta > 0:
        return 0
    if (i + 1) % T <= j:
        _reverse(order, pos, (i + 1) % T, j)
    else:
        _reverse(order, pos, j + 1, i)
    return delta


@njit(cache=True, nogil=True, _nrt=False)
def _or_opt(order, pos, T, dist, near, x, buf):
    i = x % T
    x //= T
    n_seg = 1 + x % 3
    x //= 3
    rev = x % 2
    x //= 2
    if T < n_seg + 3:
        return 0
    s0 = order[i]
    s1 = order[(i + n_seg - 1) % T]
    p = order[(i - 1) % T]
    n = order[(i + n_seg) % T]
    c = near[s1 if rev != 0 else s0, x % near.shape[1]]
    j = pos[c]
    if (j - i) % T < n_seg or c == p:
        return 0
    d = order[(j + 1) % T]
    if rev != 0:
        add = dist[c, s1] + dist[s0, d]
    else:
        add = dist[c, s0] + dist[s1, d]
    delta = dist[p, n] + add - dist[p, s0] - dist[s1, n] - dist[c, d]
    if delta > 0:
        return 0
    m = 0
    k = (i + n_seg) % T
    while True:  # n .. c
        buf[m] = order[k]
        m += 1
        if order[k] == c:
            break
        k = (k + 1) % T
    for q in range(n_seg):
        buf[m] = order[(i + (n_seg - 1 - q if rev != 0 else q)) % T]
        m += 1
    k = (j + 1) % T
    while m < T:  # d .. p
        buf[m] = order[k]
        m += 1
        k = (k + 1) % T
    for q in range(T):
        order[q] = buf[q]
        pos[buf[q]] = q
    return delta


@njit(cache=True, nogil=True, _nrt=False)
def _double_bridge(order, pos, T, x, window, buf):
    i = x % T
    x //= T
    w = min(window, T - 1)
    a = 1 + x % (w - 2)
    x //= w - 2
    b = a + 1 + x % (w - 1 - a) if w - 1 - a > 0 else a + 1
    for q in range(T):
        buf[q] = order[(i + q) % T]
    m = 1
    order[0] = buf[0]
    for q in range(a + 1, b + 1):
        order[m] = buf[q]
        m += 1
    for q in range(1, a + 1):
        order[m] = buf[q]
        m += 1
    for q in range(b + 1, T):
        order[m] = buf[q]
        m += 1
    for q in range(T):
        pos[order[q]] = q


@njit(cache=True, nogil=True, _nrt=False)
def _port_to(nbrs, c, b):
    for e in range(nbrs.shape[1]):
        if nbrs[c, e] == b:
            return e
    return -1


@njit(cache=True, nogil=True, _nrt=False)
def _route(best, T, nbrs, dist, w, tmp, first):
    """The route of order ``best[:T]`` into ``w``; returns its length."""
    if T == 1:
        w[0] = best[0]
        return 1
    n = 0
    for k in range(T):  # expand by shortest paths, first port one move closer
        c = best[k]
        goal = best[(k + 1) % T]
        w[n] = c
        n += 1
        while dist[c, goal] > 1:
            for e in range(nbrs.shape[1]):
                nb = nbrs[c, e]
                if nb >= 0 and dist[nb, goal] == dist[c, goal] - 1:
                    c = nb
                    break
            w[n] = c
            n += 1
    D = nbrs.shape[1]
    while n >= 3:  # repair: no move made twice the same way
        p = -1
        q = 0
        while q < n:
            key = w[q] * D + _port_to(nbrs, w[q], w[(q + 1) % n])
            if first[key] >= 0:
                p = first[key]
                break
            first[key] = q
            q += 1
        for k in range(min(q + 1, n)):  # reset what this pass marked
            first[w[k] * D + _port_to(nbrs, w[k], w[(k + 1) % n])] = -1
        if p < 0:
            break
        for k in range(n):
            tmp[k] = w[k]
        m = p + 1
        for k in range(q - 1, p + 1, -1):
            w[m] = tmp[k]
            m += 1
        for k in range(q + 1, n):
            w[m] = tmp[k]
            m += 1
        n = m
    return n


@njit(cache=True, nogil=True, _nrt=False)
def _propose(order, best, pos, sc, g, T, dist, near, x, kick_after, window, buf):
    """One proposal of a learner; True when its best order got strictly shorter."""
    if T < 5:
        return False
    if sc[4 * g + 2] >= kick_after:
        for q in range(T):
            order[q] = best[q]
            pos[order[q]] = q
        _double_bridge(order, pos, T, x, window, buf)
        sc[4 * g] = _order_length(order, T, dist)
        sc[4 * g + 2] = 0
        return False
    if x % 2 == 0:
        delta = _two_opt(order, pos, T, dist, near, x // 2)
    else:
        delta = _or_opt(order, pos, T, dist, near, x // 2, buf)
    sc[4 * g] += delta
    sc[4 * g + 2] = 0 if delta < 0 else sc[4 * g + 2] + 1
    if sc[4 * g] < sc[4 * g + 1]:
        for q in range(T):
            best[q] = order[q]
        sc[4 * g + 1] = sc[4 * g]
        return True
    return False


# not inlined into the loop (compiled once on its own); the loop then calls the walk
# followers' ``follow.act`` with the routes, the same inlined code as cyclic's
@njit(cache=True, nogil=True, _nrt=False)
def learn_routes(r, t, ur, nbrs, choosing, ipar, robot_i, cell_i, near, dist):
    """Each learner of run ``r`` with a patrolling robot (``choosing`` bool ``[K]``)
    proposes a change; a shorter route becomes its robots'. The loop then has them
    follow ``routes(cell_i, r, ipar)`` with ``follow.act``."""
    G = ipar[5]
    T = ipar[7]
    width = ipar[2]
    ri = robot_i[r]
    cell = cell_i[r]
    sc = cell[4 * G + 1]
    scratch = 6 * G + 2
    n_agents = choosing.shape[0]
    learning = G
    if ipar[9] >= 0 and t >= ipar[9]:
        learning = 0  # learning is over: the robots keep the best route
    for g in range(learning):
        active = False
        for k in range(n_agents):
            active = active or (choosing[k] and ri[k, follow.WID] == g)
        if not active:
            continue
        x = np.int64(np.floor(ur[g, 0] * DRAW))
        if not _propose(
            cell[G + 1 + g], cell[2 * G + 1 + g], cell[3 * G + 1 + g], sc, g, T, dist, near,
            x, ipar[6], ipar[8], cell[scratch],
        ):  # fmt: skip
            continue
        new = cell[scratch + 2]
        n = _route(cell[2 * G + 1 + g], T, nbrs, dist, new, cell[scratch], cell[scratch + 1])
        if n >= cell[G, g]:
            continue  # no shorter than the route the robots follow
        walk = cell[g]
        on = 0
        for k in range(n_agents):  # old target cells, before the route changes
            if ri[k, follow.WID] == g:
                ri[k, follow.SCRATCH] = walk[ri[k, follow.TARGET]]
                on += 1
        for i in range(width):
            walk[i] = new[i] if i < n else new[n - 1]
        cell[G, g] = n
        for k in range(n_agents):
            if ri[k, follow.WID] != g:
                continue
            old = ri[k, follow.SCRATCH]
            best_i = 0
            for i in range(1, n):
                if dist[old, walk[i]] < dist[old, walk[best_i]]:
                    best_i = i
            ri[k, follow.TARGET] = best_i
            ri[k, follow.SPACING] = n // on
        h = sc[4 * g + 3]
        cell[4 * G + 2 + 2 * g, h] = t
        cell[4 * G + 3 + 2 * g, h] = n
        sc[4 * g + 3] = h + 1


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def routes(cell_i, r, ipar):
    """Run ``r``'s routes (the followers' ``walk [G, M]``) and their lengths ``[G]``."""
    G = ipar[5]
    return cell_i[r, :G], cell_i[r, G, :G]
