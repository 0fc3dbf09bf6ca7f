"""``cyclic`` and ``partition`` compiled: robots that follow closed walks.

The numpy twin is :class:`qpatrol.strategies.follow.WalkFollower` with its two
strategies, :mod:`qpatrol.strategies.cyclic` (one walk for the team, robots hold on
their slots until the team has gathered) and :mod:`qpatrol.strategies.partition` (one
walk per region). Per run, in the twin's order: (cyclic) release the hold once the team
has gathered or ``gather_until`` has passed; a robot on its target advances it unless
held or (spacing rule) the next patrolling robot's target ahead on its walk is nearer
than its spacing
(all decided on the targets before the advances); targets in another robot's held
station pocket are skipped; each choosing robot asks for the first move (lowest port: N,
E, S, W on a grid) of a shortest path to its target cell. Then (collisions avoided) two
robots each of whose next cell is the other's cell swap plans, advance, skip and ask
again. Robots whose tasks the world exchanged exchange plans (:func:`exchange`).

Pack: ``robot_i`` int64 ``[R, K, 6]`` = (``wid``, ``target``, ``hold`` as 0/1,
``spacing``, scratch, the goal of the robot's row) of each robot, copied
from the strategy and back by :func:`unpack` (not the last two); ``table_i`` = ``walk``
int64 ``[W, Lmax]``; ``row_i`` = ``length`` int64 ``[W]``; ``dist`` int64 ``[C, C]``
(the strategy's table) or, on a map of more than ``TABLE_CELLS`` cells (rows mode), int64
``[R (K + 1), C]``: each robot's row of moves to the goal it last searched, then its
run's search queue (as the numpy twin's ``goal_rows``: a robot next to its goal steps onto it,
one farther away searches from its goal when the goal changes); ``ipar = [gather (1:
cyclic), gather_until, Lmax, early exchanges on (collisions avoided), spacing rule
on, five slots learned-tour uses (0 here), rows mode]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from qpatrol.engines.compiled.pack import Pack, dummy_pack

#: Columns of ``robot_i``.
WID, TARGET, HOLD, SPACING, SCRATCH, ROWGOAL = 0, 1, 2, 3, 4, 5
GONE = 4  # battery.GONE


def pack(strategy) -> Pack:
    """The walks, distances and each robot's walk, target, hold and spacing."""
    scratch = np.zeros_like(strategy.target)
    robots = np.stack(
        [
            strategy.wid,
            strategy.target,
            strategy.hold,
            strategy.spacing,
            scratch,
            np.full_like(strategy.target, -1),
        ],
        axis=-1,
    ).astype(np.int64)
    by_rows = strategy.dist is None
    if by_rows:
        R, K = strategy.target.shape
        dist = np.zeros((R * (K + 1), strategy.params.n_cells), dtype=np.int64)
    else:
        dist = np.ascontiguousarray(strategy.dist, dtype=np.int64)
    gather = strategy.name == "cyclic"
    ipar = [
        int(gather),
        strategy.gather_until if gather else 0,
        int(strategy.length.max()),
        int(strategy.params.avoid_collisions and strategy.exchange_early),
        int(strategy.keep_spacing),
        *[0] * 5,  # learned-tour's parameters (compiled/tour.py)
        int(by_rows),
    ]
    return dummy_pack(
        ipar=np.array(ipar, dtype=np.int64),
        robot_i=np.ascontiguousarray(robots),
        table_i=np.ascontiguousarray(strategy.walk[0], dtype=np.int64),
        row_i=np.ascontiguousarray(strategy.length[0], dtype=np.int64),
        dist=dist,
    )


def unpack(p: Pack, strategy) -> None:
    """Copy each robot's walk, target, hold and spacing back into the strategy."""
    ri = p.robot_i
    strategy.wid = ri[..., WID].copy()
    strategy.target = ri[..., TARGET].copy()
    strategy.hold = ri[..., HOLD] != 0
    strategy.spacing = ri[..., SPACING].copy()


def sat_out(strategy, state) -> None:
    """What the numpy engine does to the runs that sat out steps after meeting their
    episode quota (their robots choose nothing; the compiled loop skips them): (cyclic)
    their hold ends if the team stands gathered or the last step is past
    ``gather_until``."""
    out = state.steps_done < state.t
    if not out.any():
        return
    if strategy.name == "cyclic":
        here = (state.pos == strategy.goal_cells()) | (state.mode == GONE)
        gathered = here.all(axis=1) | (state.t > strategy.gather_until)
        strategy.hold[out & gathered & strategy.hold.any(axis=1)] = False


@njit(cache=True, nogil=True, _nrt=False)
def _advance(ri, k, length):
    """Robot k's target, one index further along its walk."""
    ri[k, TARGET] = (ri[k, TARGET] + 1) % length[ri[k, WID]]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _on_target(r, k, pos, ri, walk):
    """Robot k of run r stands on its target cell."""
    return pos[r, k] == walk[ri[k, WID], ri[k, TARGET]]


@njit(cache=True, nogil=True, _nrt=False)
def _gap_ahead(r, k, pos, choosing, ri, walk, length):
    """Walk steps from robot k's target forward to the nearest target of another
    choosing robot on its walk; the walk's length if none. On a tie the robot standing
    on its target cell is ahead, and between two that both stand or both do not, the
    one of lower index."""
    L = length[ri[k, WID]]
    gap = L
    on_k = _on_target(r, k, pos, ri, walk)
    for j in range(choosing.shape[0]):
        if j == k or not choosing[j] or ri[j, WID] != ri[k, WID]:
            continue
        d = ri[j, TARGET] - ri[k, TARGET]
        if d < 0:
            d += L
        if d == 0:
            on_j = _on_target(r, j, pos, ri, walk)
            if not ((on_j and not on_k) or (on_j == on_k and j < k)):
                d = L
        if d < gap:
            gap = d
    return gap


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _advance_on_target(r, pos, target, choosing, mask, ipar, ri, walk, length):
    """Robots with ``mask[k] != 0`` standing on their target advance it, unless held or
    too near the target ahead (decided for all on the targets before the advances;
    ``mask`` is overwritten with the decisions); a robot waits only on a target cell
    (``target`` bool ``[C]``: on a graph's waypoint it travels on)."""
    n_agents = choosing.shape[0]
    for k in range(n_agents):
        go = mask[k] != 0 and choosing[k] and pos[r, k] == walk[ri[k, WID], ri[k, TARGET]]
        if go and target[pos[r, k]]:
            go = ri[k, HOLD] == 0
            if go and ipar[4] != 0:
                go = _gap_ahead(r, k, pos, choosing, ri, walk, length) >= ri[k, SPACING]
        mask[k] = 1 if go else 0
    for k in range(n_agents):
        if mask[k] != 0:
            _advance(ri, k, length)


@njit(cache=True, nogil=True, _nrt=False)
def _row_step(r, k, c, goal, nbrs, ri, dist):
    """Rows mode: the first move (lowest port) of a shortest path from c to goal, -1 on
    it: onto a neighbouring goal directly, else by robot k's row, searched from the goal
    (breadth-first, into ``dist``'s row of the robot, the run's last row the queue) when
    the goal is not its row's."""
    if c == goal:
        return -1
    for d in range(nbrs.shape[1]):
        if nbrs[c, d] == goal:
            return d
    n_agents = ri.shape[0]
    row = dist[r * (n_agents + 1) + k]
    if ri[k, ROWGOAL] != goal:
        queue = dist[r * (n_agents + 1) + n_agents]
        for x in range(row.shape[0]):
            row[x] = -1
        row[goal] = 0
        queue[0] = goal
        head, tail = 0, 1
        while head < tail:
            v = queue[head]
            head += 1
            for d in range(nbrs.shape[1]):
                x = nbrs[v, d]
                if x >= 0 and row[x] < 0:
                    row[x] = row[v] + 1
                    queue[tail] = x
                    tail += 1
        ri[k, ROWGOAL] = goal
    closer = row[c] - 1
    for d in range(nbrs.shape[1]):
        nb = nbrs[c, d]
        if nb >= 0 and row[nb] == closer:
            return d
    return -1


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _skip_and_ask(
    r, nbrs, battery, pocket_of, pos, reserved, choosing, ask, ipar, ri, walk, length, dist
):
    """Skip targets in another robot's held station pocket, then ``ask[k]``: the first
    move (N, E, S, W) of a shortest path to the target cell, -1 for robots not choosing
    (or on their target)."""
    n_agents = choosing.shape[0]
    if battery:  # skip targets in another robot's held station pocket
        for k in range(n_agents):
            if not choosing[k]:
                continue
            for _ in range(length[ri[k, WID]]):  # at most one lap (follow.py)
                h = pocket_of[walk[ri[k, WID], ri[k, TARGET]]]
                if h < 0 or reserved[r, h] < 0 or reserved[r, h] == k:
                    break
                _advance(ri, k, length)
    for k in range(n_agents):  # the first move of a shortest path, lowest port first
        ask[k] = -1
        if not choosing[k]:
            continue
        c = pos[r, k]
        goal = walk[ri[k, WID], ri[k, TARGET]]
        if ipar[10] != 0:
            ask[k] = _row_step(r, k, c, goal, nbrs, ri, dist)
            continue
        closer = dist[c, goal] - 1
        for d in range(nbrs.shape[1]):
            nb = nbrs[c, d]
            if nb >= 0 and dist[nb, goal] == closer:
                ask[k] = d
                break


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def act(
    r, t, nbrs, target, battery, pocket_of, pos, reserved, mode, aim, since, token, choosing,
    ask, ipar, robot_i, walk, length, dist,
):  # fmt: skip
    """``ask[k]`` for every robot of run ``r`` at step ``t``: towards its target, -1 for
    robots not choosing (or on their target). ``mode`` int ``[R, K]``: the robots' modes
    (a robot that failed, GONE, is not of the team that gathers); ``aim``, ``since`` int
    ``[R, K]``: the robots' tasks (``State.aim`` as of the step before, ``State.since``;
    robots that swap plans before they meet swap their ages and the right of way,
    ``token`` int ``[R]``, and a task handed to the robot standing on its aim ends:
    :func:`qpatrol.world.traffic.exchange_plans`); ``target`` bool ``[C]``: the map's
    targets, the cells a robot may wait on."""
    n_agents = choosing.shape[0]
    ri = robot_i[r]
    if ipar[0] != 0:  # cyclic: the team holds until it has gathered on its slots
        held = False
        for k in range(n_agents):
            held = held or ri[k, HOLD] != 0
        if held:
            gathered = True
            for k in range(n_agents):
                if pos[r, k] != walk[ri[k, WID], ri[k, TARGET]] and mode[r, k] != GONE:
                    gathered = False
            if gathered or t > ipar[1]:
                for k in range(n_agents):
                    ri[k, HOLD] = 0
    for k in range(n_agents):  # every robot is considered (ask serves as the mask)
        ask[k] = 1
    _advance_on_target(r, pos, target, choosing, ask, ipar, ri, walk, length)
    _skip_and_ask(
        r, nbrs, battery, pocket_of, pos, reserved, choosing, ask, ipar, ri, walk, length, dist
    )
    if ipar[3] == 0:
        return
    # robots each of whose next cell is the other's cell swap plans before they move: a
    # robot's next cell is the one it asks for or, waiting on its target, the walk's next
    for k in range(n_agents):
        nxt = -1
        if choosing[k]:
            c = pos[r, k]
            if ask[k] >= 0:
                nxt = nbrs[c, ask[k]]
            elif c == walk[ri[k, WID], ri[k, TARGET]]:
                nxt = walk[ri[k, WID], (ri[k, TARGET] + 1) % length[ri[k, WID]]]
        ri[k, SCRATCH] = nxt
    swapped = False
    for k in range(n_agents):
        if ri[k, SCRATCH] < 0:
            continue
        for j in range(k + 1, n_agents):
            same = ri[k, WID] == ri[j, WID] and ri[k, TARGET] == ri[j, TARGET]
            if ri[k, SCRATCH] == pos[r, j] and ri[j, SCRATCH] == pos[r, k] and not same:
                for col in (WID, TARGET, SPACING):
                    ri[k, col], ri[j, col] = ri[j, col], ri[k, col]
                # the tasks go with the plans (traffic.exchange_plans): the ages and the
                # right of way, and a task handed to the robot on its aim ends
                since[r, k], since[r, j] = since[r, j], since[r, k]
                if token[r] == k:
                    token[r] = j
                elif token[r] == j:
                    token[r] = k
                if pos[r, k] == aim[r, j]:
                    since[r, k] = t
                if pos[r, j] == aim[r, k]:
                    since[r, j] = t
                ri[k, SCRATCH] = -2  # swapped (a pair is never matched again)
                ri[j, SCRATCH] = -2
                swapped = True
                break
    if not swapped:
        return
    for k in range(n_agents):  # the robots that swapped advance, skip and ask again
        ask[k] = 1 if ri[k, SCRATCH] == -2 else 0
    _advance_on_target(r, pos, target, choosing, ask, ipar, ri, walk, length)
    _skip_and_ask(
        r, nbrs, battery, pocket_of, pos, reserved, choosing, ask, ipar, ri, walk, length, dist
    )


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def exchange(r, swapped, robot_i):
    """Robots of run ``r`` whose tasks the world exchanged (``swapped`` int ``[K]``, the
    partner, -1 none) exchange plans: walks, targets and spacings
    (:meth:`qpatrol.strategies.follow.WalkFollower.exchange`)."""
    for k in range(swapped.shape[0]):
        j = swapped[k]
        if j > k:
            for col in (WID, TARGET, SPACING):
                robot_i[r, k, col], robot_i[r, j, col] = robot_i[r, j, col], robot_i[r, k, col]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def aims(r, robot_i, walk, aim):
    """Each robot's aim (``aim`` int ``[K]``): the cell of its target on its walk."""
    for k in range(aim.shape[0]):
        aim[k] = walk[robot_i[r, k, WID], robot_i[r, k, TARGET]]
