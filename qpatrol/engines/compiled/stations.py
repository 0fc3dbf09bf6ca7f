"""The battery's phases in the compiled loop: :mod:`qpatrol.world.battery`, one run at a time.

``begin`` (charging countdown, robots that need a station, the queue served first come
first served), ``ask`` (the moves of robots homing or queued, which the strategy does
not choose), ``pay`` (a move costs one unit, a detour is credited) and ``end``
(departed robots release their station, arrivals start charging). ``p``, ``s``, ``w``:
the loop's :class:`~qpatrol.engines.compiled.bundles.Params`, ``World`` and ``Work``;
``r`` the run.
"""

from __future__ import annotations

import numpy as np
from numba import njit

PATROL, HOMING, QUEUED, CHARGING, GONE = 0, 1, 2, 3, 4  # battery.PATROL ...


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def kept_out(c, pocket_of, reserved_r):
    """:func:`qpatrol.world.battery.in_held_pocket`: cell c lies in the pocket of a held station."""
    h = pocket_of[c]
    return h >= 0 and reserved_r[h] >= 0


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def closed(r, k, c, nb, battery, pocket_of, pocket_depth, reserved):
    """The move from c to nb goes deeper into another robot's held pocket
    (:func:`qpatrol.world.battery.closed_cells`)."""
    if not battery or nb < 0:
        return False
    h = pocket_of[nb]
    if h < 0:
        return False
    holder = reserved[r, h]
    if holder < 0 or holder == k:
        return False
    return pocket_of[c] != h or pocket_depth[nb] > pocket_depth[c]


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def shut_junction(r, h, p, s):
    """:func:`qpatrol.world.battery.shut_junctions` of station h: the junction of its
    pocket is that of the pocket of a station a robot of run r is on its way to."""
    entry = p.pocket_entry[h]
    if entry < 0:
        return False
    for k in range(s.pos.shape[1]):
        if s.mode[r, k] == HOMING and p.pocket_entry[max(s.goal[r, k], 0)] == entry:
            return True
    return False


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def way_out(nbrs, pocket_of, pocket_depth, pocket_entry, occ_r, c, station):
    """:func:`qpatrol.world.battery.way_out` of a robot on cell c (-1: none)."""
    if station < 0:
        return -1
    h = station
    if pocket_of[c] == h:
        for d in range(nbrs.shape[1]):
            nb = nbrs[c, d]
            if nb >= 0 and (pocket_of[nb] != h or pocket_depth[nb] < pocket_depth[c]):
                return d
        return -1
    if c != pocket_entry[h]:
        return -1
    for d in range(nbrs.shape[1]):
        nb = nbrs[c, d]
        if nb >= 0 and pocket_of[nb] != h and occ_r[nb] < 0:
            return d
    for d in range(nbrs.shape[1]):
        nb = nbrs[c, d]
        if nb >= 0 and pocket_of[nb] != h:
            return d
    return -1


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def close_tasks(r, t, p, s):
    """:func:`qpatrol.world.battery.close_tasks` of run ``r``: a patrolling robot whose aim
    lies in the pocket of a station another robot holds loses its task (``since = t``,
    no aim); then a robot standing in such a pocket inherits the holder's age when it is
    the older."""
    for k in range(s.pos.shape[1]):
        a = s.aim[r, k]
        if a < 0 or s.mode[r, k] != PATROL:
            continue
        h = p.pocket_of[a]
        if h >= 0 and s.reserved[r, h] >= 0 and s.reserved[r, h] != k:
            s.since[r, k] = t
            s.aim[r, k] = -1
    if not s.active[r]:
        return
    for k in range(s.pos.shape[1]):
        j = _shut_by(r, k, p, s)
        # (not from a holder itself shut in: one level, the same whatever the order)
        if j >= 0 and _shut_by(r, j, p, s) < 0 and s.since[r, j] < s.since[r, k]:
            s.since[r, k] = s.since[r, j]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _shut_by(r, k, p, s):
    """The robot holding the station whose pocket robot k of run r stands in, when k
    patrols, queues or homes and is not that robot; -1 otherwise."""
    m = s.mode[r, k]
    if m != PATROL and m != QUEUED and m != HOMING:
        return -1
    h = p.pocket_of[s.pos[r, k]]
    if h < 0:
        return -1
    j = s.reserved[r, h]
    return j if j != k else -1


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def begin(r, t, p, s, w):
    """battery.begin: the charging countdown, robots that need a station join the
    queue, and the queue is served (:func:`qpatrol.world.battery._assign_stations`: first
    come first served, ties by lower index; each the nearest free station it reaches)."""
    n_agents = s.pos.shape[1]
    mode, charge, order, key = s.mode, s.charge, w.order, w.key
    for k in range(n_agents):
        if mode[r, k] == CHARGING:
            s.rest[r, k] -= 1
            if s.rest[r, k] < 0:
                s.rest[r, k] = 0
                mode[r, k] = PATROL
                charge[r, k] = p.capacity
                s.depart_left[r, k] = 2 * p.depart_len[s.goal[r, k]]
                s.since[r, k] = t  # a new task: patrolling again
    any_queued = False
    for k in range(n_agents):
        if (
            mode[r, k] == PATROL
            and s.depart_left[r, k] == 0
            and charge[r, k] <= p.nearest[s.pos[r, k]] + p.margin + 1
        ):
            mode[r, k] = QUEUED
            s.queued_since[r, k] = t
            s.since[r, k] = t  # a new task: reaching a station
        if mode[r, k] == QUEUED:
            any_queued = True
    if not any_queued:
        return
    for k in range(n_agents):
        order[k] = k
        if mode[r, k] == QUEUED:
            key[k] = s.queued_since[r, k] * n_agents + k
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
        for h in range(p.homes.shape[0]):
            dist = p.home_dist[h, s.pos[r, k]]
            if (
                s.reserved[r, h] < 0
                and dist <= charge[r, k]
                and dist < best_d
                and not shut_junction(r, h, p, s)
            ):
                best_d = dist
                best_h = h
        if best_h >= 0:
            s.reserved[r, best_h] = k
            s.goal[r, k] = best_h
            mode[r, k] = HOMING


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def ask(r, p, s, w):
    """``w.ask`` of the robots homing (battery.homing_ask: along the station's
    shortest paths, held back from an occupied pocket, yielding inside it) and queued
    (battery.queued_ask: out of another robot's pocket); ``w.held_back`` and
    ``w.yielding`` say which were held back or yield."""
    n_agents = s.pos.shape[1]
    pos, occ_r, reserved = s.pos, s.occ[r], s.reserved
    nbrs, pocket_of, pocket_depth, pocket_entry = (
        p.nbrs,
        p.pocket_of,
        p.pocket_depth,
        p.pocket_entry,
    )
    for k in range(n_agents):
        c = pos[r, k]
        if s.mode[r, k] == HOMING:
            gk = max(s.goal[r, k], 0)
            direction = p.home_dir[gk, c]
            entry = pocket_entry[gk]
            if entry >= 0:
                depth_others = -1
                for j2 in range(n_agents):
                    if j2 != k and pocket_of[pos[r, j2]] == gk and s.mode[r, j2] != GONE:
                        depth_others = max(depth_others, pocket_depth[pos[r, j2]])
                occupied = depth_others >= 0
                my_depth = pocket_depth[c] if pocket_of[c] == gk else 0
                at_entry = c == entry
                nxt = nbrs[c, max(direction, 0)]
                entering = direction >= 0 and my_depth == 0 and not at_entry and nxt == entry
                held = occupied and entering
                yld = occupied and (at_entry or (depth_others > my_depth and my_depth > 0))
                out = way_out(nbrs, pocket_of, pocket_depth, pocket_entry, occ_r, c, gk)
                if held:
                    direction = -1
                elif yld:
                    direction = out
                w.held_back[k] = held
                w.yielding[k] = yld and out >= 0
            w.ask[k] = direction
        elif s.mode[r, k] == PATROL and (w.choosing[k] or (p.travels and w.travel[k] >= 0)):
            # a held pocket is closed: no robot but its holder moves deeper into it
            d = w.ask[k]
            if d >= 0 and closed(r, k, c, nbrs[c, d], True, pocket_of, pocket_depth, reserved):
                w.ask[k] = -1
        elif s.mode[r, k] == QUEUED or s.mode[r, k] == PATROL:
            # queued, or patrolling and shut in a held pocket (battery.shut_in)
            station = -1
            hp = pocket_of[c]
            if hp >= 0:
                holder = reserved[r, hp]
                if holder >= 0 and holder != k:
                    station = hp
            w.ask[k] = way_out(nbrs, pocket_of, pocket_depth, pocket_entry, occ_r, c, station)
            if w.ask[k] >= 0:
                w.yielding[k] = True


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def pay(r, p, s, w):
    """A move costs one unit of charge; yielding (pushed aside, or out of a pocket) is
    free, and a robot homing or queued that was pushed is credited the detour
    (battery.credit_detour)."""
    charge, mode = s.charge, s.mode
    for k in range(s.pos.shape[1]):
        if not w.moved[k]:
            continue
        if w.as_asked[k] and not w.yielding[k]:
            charge[r, k] -= 1
        elif mode[r, k] == HOMING or mode[r, k] == QUEUED:
            gk = max(s.goal[r, k], 0)
            if mode[r, k] == HOMING:
                d_before = p.home_dist[gk, w.prev_pos[k]]
                d_after = p.home_dist[gk, s.pos[r, k]]
            else:
                d_before = p.nearest[w.prev_pos[k]]
                d_after = p.nearest[s.pos[r, k]]
            credit = max(d_after - d_before, 0)
            charge[r, k] = min(charge[r, k] + credit, p.capacity)


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def end(r, p, s, w):
    """battery.end: departed robots release their stations, arrivals start charging
    (or, with no charging time, are full at once and depart)."""
    n_agents = s.pos.shape[1]
    mode, goal, depart_left = s.mode, s.goal, s.depart_left
    for k in range(n_agents):
        if depart_left[r, k] > 0:
            depart_left[r, k] -= 1
            if depart_left[r, k] == 0 or w.ask[k] < 0:
                s.reserved[r, goal[r, k]] = -1
                goal[r, k] = -1
                depart_left[r, k] = 0
    for k in range(n_agents):
        if mode[r, k] == HOMING and s.pos[r, k] == p.homes[max(goal[r, k], 0)]:
            if p.charge_steps > 0:
                mode[r, k] = CHARGING
                s.rest[r, k] = p.charge_steps
            else:
                mode[r, k] = PATROL
                s.charge[r, k] = p.capacity
                depart_left[r, k] = 2 * p.depart_len[goal[r, k]]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def lowest_charge(r, s, min_charge):
    """The run's lowest charge so far (``min_charge`` ``[R]``) takes this step's."""
    low = s.charge[r, 0]
    for k in range(1, s.charge.shape[1]):
        low = min(low, s.charge[r, k])
    min_charge[r] = min(min_charge[r], low)
