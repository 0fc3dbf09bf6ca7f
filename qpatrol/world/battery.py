"""Batteries, homing and charging stations: a busy station is a queue, not a trap.

Each move costs one unit of charge. The rules, applied to every robot of every run:

1. A patrolling robot whose charge is at most ``distance to the nearest station +
   margin + 1`` needs a station (mode QUEUED). The ``+ 1`` makes the rule safe whatever
   the parity of capacity and distances: a robot that was above the threshold one move
   earlier still has at least ``distance + margin`` when it switches.
2. Stations are *held*, one robot per station. Robots that need a station take one in
   the order in which they began to need it (first come, first served): the nearest
   free station their charge can reach. The robot then is HOMING: it follows a shortest
   path to its station. A robot that finds no free station within reach stays where it
   is (QUEUED; waiting costs no charge) until one is released. A station whose pocket
   (rule 4) has the junction of the pocket of a station another robot is on its way to
   is not free for now: the pockets of one junction are never closed by two holders
   outside them at once.
3. On its station the robot charges for ``charge_steps`` team steps (CHARGING; it cannot
   be moved), then resumes patrol with a full charge. It keeps holding the station, with
   right of way over every other robot, for ``2 x depart_len`` team steps or until it
   stops asking to move, where ``depart_len`` is the distance from the station to the
   nearest junction: long enough to clear the corridor of a station at the end of a
   dead end before the next robot may head for it. Only then is the station released.
4. A station at the end of a dead end (more precisely: in the small part of the map
   that a junction cuts off, its *pocket*) is entered only when the pocket is empty:
   while a station is held, its pocket is closed to every other robot, and the holder
   waits one cell before the pocket's junction until the robots inside have left.
5. The charge never goes below 0 and a robot never runs out on its way: it moves on
   its own only when rules 1-2 leave it enough charge to reach its station. Being
   pushed aside by a robot with right of way (:mod:`qpatrol.world.traffic`) is *yielding*:
   it costs no charge, and a robot on its way to a station is credited the extra
   distance a push put between it and the station. So no amount of yielding can
   strand a robot; yields are counted per run.

Because a station is held by one robot at a time and the holder leaves with right of
way, robots never queue on a station's exits, and a robot waits for a station at most
until the robots ahead of it in the queue have charged and left.

Arrays are ``[R, K]`` (runs, robots) unless stated; ``H`` is the number of stations.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from qpatrol.world import Params, State

PATROL, HOMING, QUEUED, CHARGING = 0, 1, 2, 3
#: A robot that failed and left the map for good (:mod:`qpatrol.world.failures`): it
#: never chooses, asks, waits or holds a station, and stands in no cell.
GONE = 4
MODE_NAMES = ("patrol", "homing", "queued", "charging", "gone")


def initial_charge(p: Params, pos: np.ndarray) -> np.ndarray:
    """int ``[R, K]``: charge at the start (``battery.initial_charge``).

    ``full``: every robot starts with ``capacity``. ``staggered``: robot k of K starts
    with ``capacity - floor(k x capacity / K)``, but never below what it needs to reach
    a station from its start cell, so the team does not go home all at once.
    """
    r, k = pos.shape
    full = np.full((r, k), p.capacity, dtype=np.int64)
    if not (p.battery and p.staggered):
        return full
    stagger = p.capacity - (np.arange(k) * p.capacity) // k
    floor = p.nearest_home_dist[pos] + p.margin + 1
    return np.maximum(stagger[None, :], floor).astype(np.int64)


def begin(s: State, p: Params, t: int) -> None:
    """Start of team step ``t``: charging countdown, robots that need a station, queue."""
    if not p.battery:
        return
    act = s.active[:, None]
    charging = act & (s.mode == CHARGING)
    s.rest[charging] -= 1
    done = charging & (s.rest < 0)  # rested charge_steps whole steps
    if done.any():
        s.rest[done] = 0
        s.mode[done] = PATROL
        s.charge[done] = p.capacity
        s.depart_left[done] = 2 * p.depart_len[s.goal[done]]
        s.since[done] = t  # a new task: patrolling again
    low = (
        act
        & (s.mode == PATROL)
        & (s.depart_left == 0)
        & (s.charge <= p.nearest_home_dist[s.pos] + p.margin + 1)
    )
    if low.any():
        s.mode[low] = QUEUED
        s.queued_since[low] = t
        s.since[low] = t  # a new task: reaching a station
    if (s.mode == QUEUED).any():
        _assign_stations(s, p)


def close_tasks(s: State, p: Params, t: int) -> None:
    """A patrolling robot whose aim lies in the pocket of a station another robot holds
    (closed to it, rule 4) has lost its task: the task ends (``since = t``, no aim);
    its strategy chooses another goal (:mod:`qpatrol.strategies.goals` drops goals in
    held pockets). Then a robot standing in the pocket of a station another robot holds
    (it must step out, rule 4) inherits that robot's age when it is the older: it steps
    out on the holder's behalf."""
    rows = np.arange(s.n_runs)[:, None]
    a = np.maximum(s.aim, 0)
    h = p.pocket_of[a]
    holder = s.reserved[rows, np.maximum(h, 0)]
    me = np.arange(s.pos.shape[1])[None, :]
    lost = (s.aim >= 0) & (h >= 0) & (holder >= 0) & (holder != me) & (s.mode == PATROL)
    if lost.any():
        s.since[lost] = t
        s.aim[lost] = -1
    h = p.pocket_of[s.pos]
    holder = np.where(h >= 0, s.reserved[rows, np.maximum(h, 0)], -1)
    moving = (s.mode == PATROL) | (s.mode == QUEUED) | (s.mode == HOMING)
    holder = np.where(moving & (holder != me), holder, -1)
    # (not from a holder itself shut in: one level)
    free = np.take_along_axis(holder, np.maximum(holder, 0), axis=1) < 0
    shut = s.active[:, None] & (holder >= 0) & free
    if shut.any():
        theirs = np.take_along_axis(s.since, np.maximum(holder, 0), axis=1)
        s.since = np.where(shut, np.minimum(s.since, theirs), s.since)


def _assign_stations(s: State, p: Params) -> None:
    """Give free stations to queued robots, first come first served (ties: lower index);
    not a station whose pocket's junction is that of the station a robot is on its way
    to (:func:`shut_junctions`)."""
    R, K = s.pos.shape
    queued = s.active[:, None] & (s.mode == QUEUED)
    shut = shut_junctions(s, p)
    rank = np.where(queued, s.queued_since, 1 << 50) * K + np.arange(K)
    order = np.argsort(rank, axis=1, kind="stable")
    for i in range(K):
        k = order[:, i]
        rows = np.flatnonzero(queued[np.arange(R), k])
        if rows.size == 0:
            break  # queued robots come first in every run
        kk = k[rows]
        dist = p.home_dist[:, s.pos[rows, kk]].T  # [n, H]
        ok = (s.reserved[rows] < 0) & (dist <= s.charge[rows, kk][:, None]) & ~shut[rows]
        has = ok.any(axis=1)
        if not has.any():
            continue
        h = np.where(ok, dist, np.iinfo(np.int64).max).argmin(axis=1)
        rows, kk, h = rows[has], kk[has], h[has]
        s.reserved[rows, h] = kk
        s.goal[rows, kk] = h
        s.mode[rows, kk] = HOMING
        entry = p.pocket_entry
        shut[rows] |= (entry[None, :] >= 0) & (entry[None, :] == entry[h][:, None])


def shut_junctions(s: State, p: Params) -> np.ndarray:
    """bool ``[R, H]``: stations a queued robot may not take now: their pocket's junction
    is the junction of the pocket of a station a robot is on its way to (HOMING). So the
    pockets of one junction are never closed by two holders outside them at once."""
    entry = p.pocket_entry  # [H]
    homing = s.active[:, None] & (s.mode == HOMING)
    on_way = np.where(homing, entry[np.maximum(s.goal, 0)], -1)  # [R, K]
    same = (on_way[:, :, None] == entry[None, None, :]) & (entry >= 0)[None, None, :]
    return same.any(axis=1)


def homing_ask(s: State, p: Params) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(direction, held_back, yielding)``, int, bool, bool ``[R, K]``, for HOMING robots.

    The direction is the first move of a shortest path to the robot's station (-1 on
    it). While other robots are in the station's pocket, a robot about to enter it is
    *held back* (no move); one standing on the pocket's junction, or inside the pocket
    with another robot deeper in, *yields*: it steps out of their way.
    """
    none = np.full(s.pos.shape, -1, dtype=np.int64)
    no = np.zeros(s.pos.shape, dtype=bool)
    if p.homes.size == 0:
        return none, no, no
    K = s.pos.shape[1]
    goal = np.maximum(s.goal, 0)
    direction = p.home_dir[goal, s.pos]
    pocket = p.pocket_entry[goal] >= 0
    if not pocket.any():
        return direction, no, no
    # robots other than k in the pocket of k's station, and how deep the deepest is
    pocket_of_others = p.pocket_of[s.pos][:, None, :]  # [R, 1, K]
    same = (pocket_of_others == goal[..., None]) & ~np.eye(K, dtype=bool)[None]
    same &= (s.mode != GONE)[:, None, :]  # a robot that failed stands nowhere
    depth_others = np.where(same, p.pocket_depth[s.pos][:, None, :], -1).max(axis=-1)  # [R, K]
    occupied = depth_others >= 0
    my_depth = np.where(p.pocket_of[s.pos] == goal, p.pocket_depth[s.pos], 0)
    at_entry = s.pos == p.pocket_entry[goal]
    nxt = p.neighbors[s.pos, np.maximum(direction, 0)]
    entering = (direction >= 0) & (my_depth == 0) & ~at_entry & (nxt == p.pocket_entry[goal])
    held = pocket & occupied & entering
    yielding = pocket & occupied & (at_entry | (depth_others > my_depth) & (my_depth > 0))
    out = way_out(s, p, goal)
    direction = np.where(held, -1, np.where(yielding, out, direction))
    return direction, held, yielding & (out >= 0)


def way_out(s: State, p: Params, station: np.ndarray) -> np.ndarray:
    """int ``[R, K]``: the move that takes a robot out of the pocket of ``station`` (int
    ``[R, K]``): towards the junction from inside, off the junction when on it (to a free
    cell if there is one); -1 elsewhere."""
    R, K = s.pos.shape
    rows = np.arange(R)[:, None, None]
    h = np.maximum(station, 0)
    inside = p.pocket_of[s.pos] == h
    on_entry = s.pos == p.pocket_entry[h]
    nbr = p.neighbors[s.pos]  # [R, K, D]
    nb = np.maximum(nbr, 0)
    shallower = (nbr >= 0) & (
        (p.pocket_of[nb] != h[..., None]) | (p.pocket_depth[nb] < p.pocket_depth[s.pos][..., None])
    )
    outside = (nbr >= 0) & (p.pocket_of[nb] != h[..., None])
    free = outside & (s.occ[rows, nb] < 0)
    off_entry = np.where(free.any(axis=-1, keepdims=True), free, outside)
    want = np.where(inside[..., None], shallower, on_entry[..., None] & off_entry)
    return np.where((station >= 0) & want.any(axis=-1), want.argmax(axis=-1), -1)


def shut_in(s: State, p: Params) -> np.ndarray:
    """bool ``[R, K]``: patrolling robots inside the pocket of a station another robot
    holds. They do not choose: they step out (:func:`queued_ask`), so that the pocket
    empties for its holder."""
    R, K = s.pos.shape
    h = p.pocket_of[s.pos]
    holder = s.reserved[np.arange(R)[:, None], np.maximum(h, 0)]
    return (s.mode == PATROL) & (h >= 0) & (holder >= 0) & (holder != np.arange(K)[None, :])


def queued_ask(s: State, p: Params) -> np.ndarray:
    """int ``[R, K]``: a queued robot in the pocket of a station another robot holds
    steps out of it (:func:`way_out`), and so does a patrolling robot shut in such a
    pocket (:func:`shut_in`); -1 otherwise. (A robot on the pocket's junction stays: the
    holder and the robots leaving the pocket push it aside when they need the cell.)"""
    R, K = s.pos.shape
    me = np.arange(K)[None, :]
    h = p.pocket_of[s.pos]
    holder = s.reserved[np.arange(R)[:, None], np.maximum(h, 0)]
    station = np.where((h >= 0) & (holder >= 0) & (holder != me), h, -1)
    return way_out(s, p, station)


def in_held_pocket(c: int, pocket_of: list[int], reserved_r: list[int]) -> bool:
    """Cell ``c`` lies in the pocket of a held station (``pocket_of``: each cell's pocket's
    station or -1; ``reserved_r``: the robot holding each station of one run, or -1): no
    push may move a robot into it (the holder enters on its own, once the pocket is
    empty). Scalars on lists: the pushes' searches ask it of a few cells each."""
    h = pocket_of[c]
    return h >= 0 and reserved_r[h] >= 0


def closed_cells(s: State, p: Params, targets: np.ndarray) -> np.ndarray:
    """bool ``[R, K, D]``: moves deeper into the pocket of a station another robot holds.

    Moving out of such a pocket stays open, so robots inside leave it.
    """
    if p.homes.size == 0:
        return np.zeros(targets.shape, dtype=bool)
    t = np.maximum(targets, 0)
    h = p.pocket_of[t]  # [R, K, D]
    rows = np.arange(s.n_runs)[:, None, None]
    holder = s.reserved[rows, np.maximum(h, 0)]
    here = s.pos[..., None]
    deeper = (p.pocket_of[here] != h) | (p.pocket_depth[t] > p.pocket_depth[here])
    others = holder != np.arange(s.pos.shape[1])[None, :, None]
    return (targets >= 0) & (h >= 0) & (holder >= 0) & others & deeper


def credit_detour(s: State, p: Params, pushed: np.ndarray, before: np.ndarray) -> None:
    """Robots pushed aside on their way to a station get back the distance it cost."""
    if not p.battery or not pushed.any():
        return
    need_station = pushed & ((s.mode == HOMING) | (s.mode == QUEUED))
    if not need_station.any():
        return
    goal = np.maximum(s.goal, 0)
    homing = s.mode == HOMING
    d_before = np.where(homing, p.home_dist[goal, before], p.nearest_home_dist[before])
    d_after = np.where(homing, p.home_dist[goal, s.pos], p.nearest_home_dist[s.pos])
    credit = np.where(need_station, np.maximum(d_after - d_before, 0), 0)
    s.charge = np.minimum(s.charge + credit, p.capacity)


def end(s: State, p: Params, moved: np.ndarray, asked: np.ndarray) -> None:
    """End of a team step: arrivals start charging; departed robots release stations.

    Args:
        moved: bool ``[R, K]``, robots that entered a new cell this step.
        asked: bool ``[R, K]``, robots that asked for a move this step.
    """
    if not p.battery:
        return
    departing = s.depart_left > 0
    s.depart_left[departing] -= 1
    released = departing & ((s.depart_left == 0) | ~asked)
    if released.any():
        rows, ks = np.nonzero(released)
        s.reserved[rows, s.goal[rows, ks]] = -1
        s.goal[rows, ks] = -1
        s.depart_left[rows, ks] = 0
    homing = s.active[:, None] & (s.mode == HOMING)
    arrived = homing & (s.pos == p.homes[np.maximum(s.goal, 0)])
    if arrived.any():
        if p.charge_steps > 0:
            s.mode[arrived] = CHARGING
            s.rest[arrived] = p.charge_steps
        else:
            s.mode[arrived] = PATROL
            s.charge[arrived] = p.capacity
            s.depart_left[arrived] = 2 * p.depart_len[s.goal[arrived]]


def station_pockets(
    neighbors: np.ndarray, homes: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(pocket_of [C], depth [C], entry [H])``: dead-end pockets of stations.

    A station lies in a *pocket* when it is on a dead-end corridor: a one-wide chain of
    cells that leaves a junction (a cell with 3 or more free neighbours) and ends in a
    dead end. The pocket is that chain, ``entry[h]`` its junction (-1 when station h is
    in no pocket) and ``depth[c]`` the distance of a pocket cell from the junction (0
    outside pockets). ``pocket_of[c]`` is the station whose pocket holds cell c, -1 if
    none.
    """
    c = neighbors.shape[0]
    pocket_of = np.full(c, -1, dtype=np.int64)
    depth = np.zeros(c, dtype=np.int64)
    entry = np.full(homes.size, -1, dtype=np.int64)
    degree = (neighbors >= 0).sum(axis=1)
    for i, h in enumerate(homes.tolist()):
        if pocket_of[h] >= 0 or degree[h] > 2:
            continue
        # walk both ways along the corridor through h until a junction or a dead end
        ends = []
        chain = [h]
        for first in [nb for nb in neighbors[h].tolist() if nb >= 0]:
            prev, cur = h, first
            while degree[cur] == 2 and cur != h:
                chain.append(cur)
                prev, cur = (
                    cur,
                    next(nb for nb in neighbors[cur].tolist() if nb >= 0 and nb != prev),
                )
            ends.append(cur)
        if h in ends:
            continue  # a corridor that closes on itself (a ring): no dead end, no pocket
        junctions = [e for e in ends if degree[e] >= 3]
        if degree[h] == 1:
            junctions = ends if degree[ends[0]] >= 3 else []
            chain_end_dead = True
        else:
            dead = [e for e in ends if degree[e] == 1]
            chain_end_dead = len(dead) == 1 and len(junctions) == 1
            chain.extend(dead)
        if not (chain_end_dead and len(junctions) == 1):
            continue
        j = junctions[0]
        dist_j = _bfs_order(neighbors, j, blocked=-1, limit=set(chain) | {j})
        for d, cell in dist_j:
            if cell != j:
                pocket_of[cell] = i
                depth[cell] = d
        entry[i] = j
    return pocket_of, depth, entry


def _bfs_order(
    neighbors: np.ndarray, source: int, blocked: int, limit: set[int]
) -> list[tuple[int, int]]:
    """``(distance, cell)`` for cells of ``limit`` reachable from ``source``, nearest first."""
    seen = {source}
    order = [(0, source)]
    i = 0
    while i < len(order):
        d, v = order[i]
        for nb in neighbors[v].tolist():
            if nb >= 0 and nb != blocked and nb not in seen and nb in limit:
                seen.add(nb)
                order.append((d + 1, nb))
        i += 1
    return order


def door_room(
    neighbors: np.ndarray,
    homes: np.ndarray,
    home_dir: np.ndarray,
    pocket_of: np.ndarray,
    entry: np.ndarray,
) -> tuple[int, int]:
    """``(room, door)``: the fewest cells a homing robot can push robots into ahead of
    it: the smallest *room ahead*, over every station h and every cell u outside
    pockets, of the move
    u -> c1 that a robot homing to h asks for (``home_dir``), when c1 is not in h's
    pocket. The room ahead is the part of the map that the push search of
    :mod:`qpatrol.world.traffic` may use from c1 with the holder on u: the connected
    component of c1 once u, h's pocket and the pockets of other junctions (closed while
    their stations are held) are removed. A team of at most this many robots leaves a
    homing robot an empty cell ahead of it on every step of its way
    (docs/model.md, "The trip to the door"). ``door`` is the cell c1 of a move with the
    smallest room; ``(C, -1)`` if no move has a room smaller than the number of cells C.

    Args:
        neighbors: int ``[C, D]``, -1 for a wall; homes: int ``[H]``; home_dir: int
            ``[H, C]``; pocket_of: int ``[C]``; entry: int ``[H]`` (:func:`station_pockets`).
    """
    c = neighbors.shape[0]
    best, door = c, -1
    nbrs = neighbors.tolist()
    for i in range(homes.size):
        # closed to the pushes of a robot on its way to station i: its own pocket and the
        # pockets of other junctions (those of its junction are held at most while a
        # robot charges on them and leaves: battery.shut_junctions)
        same = (entry[np.maximum(pocket_of, 0)] == entry[i]) & (entry[i] >= 0)
        removed = ((pocket_of >= 0) & ~(same & (pocket_of != i))).tolist()
        sizes = _rooms_ahead(nbrs, removed)
        for u in range(c):
            d = int(home_dir[i, u])
            if removed[u] or d < 0:
                continue
            c1 = nbrs[u][d]
            if not removed[c1]:
                room = sizes(u, c1)
                if room < best:
                    best, door = room, c1
    return best, door


def _rooms_ahead(nbrs: list[list[int]], removed: list[bool]):
    """``size(u, v)``: cells of the component of v in the graph without the ``removed``
    cells and without u (u, v neighbours, neither removed), for every u at once from
    one depth-first search: entry times, subtree sizes and low points (Tarjan)."""
    c = len(nbrs)
    disc = [-1] * c
    low = [0] * c
    size = [1] * c
    parent = [-1] * c
    comp = [-1] * c
    comp_size: list[int] = []
    clock = 0
    for root in range(c):
        if removed[root] or disc[root] >= 0:
            continue
        cid = len(comp_size)
        members = 0
        disc[root] = low[root] = clock
        clock += 1
        comp[root] = cid
        stack = [(root, 0)]
        while stack:
            v, i = stack[-1]
            if i < len(nbrs[v]):
                stack[-1] = (v, i + 1)
                w = nbrs[v][i]
                if w < 0 or removed[w] or w == parent[v]:
                    continue
                if disc[w] < 0:
                    disc[w] = low[w] = clock
                    clock += 1
                    comp[w] = cid
                    parent[w] = v
                    stack.append((w, 0))
                else:
                    low[v] = min(low[v], disc[w])
            else:
                stack.pop()
                members += 1
                if parent[v] >= 0:
                    low[parent[v]] = min(low[parent[v]], low[v])
                    size[parent[v]] += size[v]
        comp_size.append(members)

    def room(u: int, v: int) -> int:
        # u's children in the search tree whose subtrees no edge joins above u: removing
        # u cuts each off on its own; the rest of u's component stays together
        cut_off = [
            w for w in nbrs[u] if w >= 0 and not removed[w] and parent[w] == u and low[w] >= disc[u]
        ]
        for w in cut_off:
            if disc[w] <= disc[v] < disc[w] + size[w]:
                return size[w]
        return comp_size[comp[u]] - 1 - sum(size[w] for w in cut_off)

    return room
