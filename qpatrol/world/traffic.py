"""Moves of a team in one step: never two robots in a cell, never a swap, and robots yield.

Every robot asks for at most one move (its strategy's choice, or the next step home),
and has a *task* (``State.aim``, ``State.since``: the goal it heads for, and the step
the task began); its *priority* is the task's age, ``t - since``, then a turn that
rotates with the step number. The moves are resolved in three parts:

1. **Right of way.** At most one robot per run holds the *token*. If the cell it asks
   for is taken, the robots in the way are pushed aside: a breadth-first search from
   that cell, not through the holder's own cell, through charging robots nor into the
   pocket of a station another robot holds (:mod:`qpatrol.world.battery`), finds the nearest
   empty cell, and every robot on that path moves one cell along it, away from the
   holder, which then takes its cell. If no such path exists the holder's task goes
   one cell on all the same: when both the holder and the robot in its way patrol,
   they *exchange tasks* (aims, ages, and the strategies' plans:
   :attr:`Resolution.swapped`), so the holder's task is now carried from the cell it
   asked for; otherwise the robot in its way *inherits* the holder's age when it is the
   older (the two exchange ages: the holder, whose way is full, takes the younger) and
   clears the way on its own task. Either way that robot is first for the token among
   equal ages (3).
2. **Everyone else**, in priority order, moves if the asked cell is empty at that
   moment: a robot may follow one that left its cell this step, but never enters a
   cell that is still occupied, so no two robots meet and no two swap.
3. **Passing the token** at the end of the step: to the robot with the oldest task
   among the blocked robots, the holder if it still pursues its task (asked a move and
   did not reach its aim) and the robot that received the holder's task or age (1);
   among equal ages that robot first, then the holder, then the turn.

The holder sees every legal move into a cell it can empty as open
(:func:`qpatrol.world.begin_step`), so it insists on its way instead of fleeing; the
oldest task carried by a blocked robot moves one cell towards its aim every step, and
so ends within ``diameter`` steps (docs/model.md, "What is proven"). Under the other
interactions (``team.interaction: interference`` or ``none``) none of this applies:
robots share cells and pass each other, and every asked move is made but a stopped
robot's (:mod:`qpatrol.world.interference`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from qpatrol.util.arrays import at, flat
from qpatrol.world import battery, interference

if TYPE_CHECKING:
    from qpatrol.world import Params, State


@dataclass
class Resolution:
    """Which robots moved; arrays ``[R, K]`` unless stated.

    Attributes:
        moved: bool, entered a new cell (as asked or pushed aside).
        as_asked: bool, made the move it asked for.
        push_failed: bool ``[R]``, the token holder could not make the move it asked for.
        handoff: int ``[R]``, the robot that received the failed holder's task or age
            (and takes the token), -1 if none.
        swapped: int ``[R, K]``, the robot each robot exchanged its task with, -1 if none.
    """

    moved: np.ndarray
    as_asked: np.ndarray
    push_failed: np.ndarray
    handoff: np.ndarray | None = None
    swapped: np.ndarray | None = None


def priority(s: State, t: int) -> np.ndarray:
    """int ``[R, K]``: larger goes first: the older task (``t - since``), then a turn that
    rotates with the step ``t`` (every robot alike, whatever it is doing: a fair right of
    way)."""
    R, K = s.pos.shape
    turn = (K - 1) - (np.arange(K) - t) % K
    age = np.clip(t - s.since, 0, 1 << 30)
    return (age * K + turn[None, :]).astype(np.int64)


def feasible_moves(s: State, p: Params, r: int, k: int, legal_open: np.ndarray) -> np.ndarray:
    """bool ``[D]``: the moves robot ``k`` of run ``r`` can make as the holder of the right
    of way: among ``legal_open`` (bool ``[D]``), those into an empty cell or into one a
    push empties (:func:`_push_path`: not through the holder's cell, charging robots nor
    held pockets). The world offers the holder these as its open moves, so a holder
    whose strategy chooses among open moves always makes the move it chose. (The world
    asks only for a holder with an open move into an occupied cell: one without makes
    every open move, :func:`qpatrol.world.begin_step`.)"""
    nbrs = _neighbour_lists(p)
    own = int(s.pos[r, k])
    occ = s.occ[r].tolist()
    may_move = (s.mode[r] != battery.CHARGING).tolist()
    out = _keep_out(s, p, r)
    ok = np.zeros(len(legal_open), dtype=bool)
    for d, cell in enumerate(nbrs[own]):
        if cell >= 0 and legal_open[d]:
            ok[d] = occ[cell] < 0 or _push_path(nbrs, occ, own, cell, may_move, out) is not None
    return ok


def _keep_out(s: State, p: Params, r: int) -> tuple[list[int], list[int], list[int]] | None:
    """What a push may not do in run ``r``: move a robot into a held pocket or deeper
    inside one (:func:`battery.in_held_pocket`); ``(reserved, pocket_of, pocket_depth)``
    as lists (a push may shift a robot out of a held pocket, towards its junction).
    None without the battery (no pocket is ever held)."""
    if not p.battery:
        return None
    return (
        s.reserved[r].tolist(),
        _cell_list(p, "pocket_of"),
        _cell_list(p, "pocket_depth"),
    )


def resolve(s: State, p: Params, want: np.ndarray, plans: bool = False) -> Resolution:
    """Move the robots of every active run (in place: ``s.pos``, ``s.occ``).

    Args:
        want: int ``[R, K]``, the cell each robot asks to enter, -1 for no move.
        plans: the strategy's robots' goals are tasks allocated to them
            (:attr:`qpatrol.strategies.base.Strategy.keeps_plans`; the engines pass it on
            patrol graphs with waypoints): a holder head on with one of them hands its
            task on rather than pushing (:func:`head_on`).
    """
    R, K = s.pos.shape
    moved = np.zeros((R, K), dtype=bool)
    as_asked = np.zeros((R, K), dtype=bool)
    push_failed = np.zeros(R, dtype=bool)
    handoff = np.full(R, -1, dtype=np.int64)
    swapped = np.full((R, K), -1, dtype=np.int64)
    want = np.where(s.active[:, None], want, -1)
    if not p.avoid_collisions:  # robots pass each other; a stopped one does not move
        go = (want >= 0) & ~interference.stopped(s, p)
        s.pos[go] = want[go]
        return Resolution(go, go.copy(), push_failed, handoff, swapped)

    # 1. the token holder pushes the robots in its way aside, or its task goes on
    res = Resolution(moved, as_asked, push_failed, handoff, swapped)
    holders = np.flatnonzero((s.token >= 0) & s.active)
    if holders.size:
        movable = s.mode != battery.CHARGING
        for r in holders.tolist():
            k = int(s.token[r])
            if want[r, k] >= 0:
                holder_step(s, p, r, k, want, movable[r], res, plans)

    # 2. everyone else, in priority order, into cells empty at that moment (not two
    # robots that exchanged tasks: their plans changed)
    want = np.where(swapped >= 0, -1, want)
    if K == 1:  # a lone robot goes first
        order = np.zeros((R, 1), dtype=np.int64)
    else:
        order = np.argsort(-priority(s, s.t), axis=1, kind="stable")
    rows_all = np.arange(R)
    robot0 = at((R, K), rows_all, 0)  # each run's robot 0, flat in [R, K], and cell 0 in occ
    cell0 = at(s.occ.shape, rows_all, 0)
    occ, pos, wants, done, asked = flat(s.occ), flat(s.pos), flat(want), flat(moved), flat(as_asked)
    progress = True
    while progress:
        progress = False
        for i in range(K):
            k = order[:, i]
            rk = robot0 + k  # each run's i-th robot
            w = wants[rk]
            ok = (w >= 0) & ~done[rk]
            ok &= occ[cell0 + np.maximum(w, 0)] < 0
            if ok.any():
                mover, ww = rk[ok], w[ok]
                occ[cell0[ok] + pos[mover]] = -1
                occ[cell0[ok] + ww] = k[ok]
                pos[mover] = ww
                done[mover] = asked[mover] = True
                # a robot that left its cell may have emptied the one another asks for
                progress = K > 1
    return res


def holder_step(
    s: State,
    p: Params,
    r: int,
    k: int,
    want: np.ndarray,
    movable: np.ndarray,
    res: Resolution,
    plans: bool = False,
) -> None:
    """Run ``r``'s token holder ``k`` takes its way (in place: ``s.pos``, ``s.occ`` and
    the rows r of ``res``): into the cell it asks for, pushing the robots in the way
    aside (:func:`_holder_move`); if it cannot, or (``plans``) if the robot in its way
    is a patrolling robot that asks for the holder's cell (:func:`head_on`), its task
    goes on through the robot in its way (:func:`hand_on`).

    Args:
        want: int ``[R, K]``, the cell each robot asks to enter (``want[r, k] >= 0``).
        movable: bool ``[K]``, the robots of run r that may be pushed.
    """
    b = int(s.occ[r, want[r, k]])
    if plans and b >= 0 and head_on(s, r, k, b, want):
        res.push_failed[r] = True
        hand_on(s, r, k, b, res)
        return
    cell, path = _holder_move(s, p, r, k, int(want[r, k]), movable)
    if cell < 0:
        res.push_failed[r] = True
        b = int(s.occ[r, want[r, k]])
        if b >= 0:
            hand_on(s, r, k, b, res)
        return
    for i in range(len(path) - 2, -1, -1):
        j = s.occ[r, path[i]]
        _move(s, r, j, path[i + 1])
        res.moved[r, j] = True
        res.as_asked[r, j] = want[r, j] == path[i + 1]
    _move(s, r, k, cell)
    res.moved[r, k] = True
    res.as_asked[r, k] = cell == want[r, k]
    res.push_failed[r] = not res.as_asked[r, k]


def _holder_move(
    s: State,
    p: Params,
    r: int,
    k: int,
    asked: int,
    movable: np.ndarray,
) -> tuple[int, list[int]]:
    """``(cell, push path)``: the cell the token holder asks for, if it is empty or a push
    empties it; ``(-1, [])`` if not."""
    if s.occ[r, asked] < 0:
        return asked, []
    nbrs = _neighbour_lists(p)
    keep_out = _keep_out(s, p, r)
    path = _push_path(nbrs, s.occ[r].tolist(), int(s.pos[r, k]), asked, movable.tolist(), keep_out)
    return (asked, path) if path is not None else (-1, [])


def head_on(s: State, r: int, k: int, b: int, want: np.ndarray) -> bool:
    """The holder k and robot b of run r, both patrolling, each ask for the other's
    cell: a push would only send b back the way it came, so robots whose goals are
    allocated tasks (``plans``) exchange tasks instead (:func:`hand_on`), as two
    insisting robots in a corridor must (token passing with swaps, Ma et al. 2017). The
    others are pushed: robots without a plan, or that choose a neighbouring target
    again after an exchange, would meet head on again, and robots that choose goals
    from their own records would carry goals their records did not choose."""
    return (
        int(want[r, b]) == int(s.pos[r, k])
        and s.mode[r, k] == battery.PATROL
        and s.mode[r, b] == battery.PATROL
    )


def hand_on(s: State, r: int, k: int, b: int, res: Resolution) -> None:
    """The holder k of run r could not enter robot b's cell: if both patrol, they
    exchange tasks (``aim`` and ``since``; ``res.swapped``), so the holder's task is
    carried on from b's cell; otherwise b inherits the holder's age if it is the older,
    and the holder takes b's (the two exchange ``since``, the older to b). Either way b
    is handed the task (``res.handoff``): first for the token among equal ages. The
    ages of a run are only ever permuted here, never made older."""
    if s.mode[r, k] == battery.PATROL and s.mode[r, b] == battery.PATROL:
        for a in (s.aim, s.since):
            a[r, k], a[r, b] = a[r, b], a[r, k]
        res.swapped[r, k], res.swapped[r, b] = b, k
    elif s.since[r, k] < s.since[r, b]:
        s.since[r, k], s.since[r, b] = s.since[r, b], s.since[r, k]
    res.handoff[r] = b


def exchange_plans(s: State, rr: np.ndarray, kk: np.ndarray, jj: np.ndarray) -> np.ndarray:
    """Robots ``kk`` and ``jj`` of runs ``rr`` (int ``[B]`` each, pairs) exchanged plans
    before the step, as two walk followers about to meet do (their cells entered are
    those of passing through each other): their tasks' ages go with the plans, as in
    :func:`hand_on`, and so does the right of way (``State.token``: the holder's task,
    carried on by the other, moves first); a task handed to the robot standing on its
    aim (``State.aim`` as of the step before) ends there (``since`` the step about to be
    taken). Returns bool ``[R, K]``, the robots whose task so ended."""
    since, aim, pos = s.since, s.aim, s.pos
    since[rr, kk], since[rr, jj] = since[rr, jj].copy(), since[rr, kk].copy()
    tok = s.token[rr]  # (a run's holder is in one pair at most; a run may have several)
    held_k, held_j = tok == kk, tok == jj
    s.token[rr[held_k]] = jj[held_k]
    s.token[rr[held_j]] = kk[held_j]
    ended = np.zeros(pos.shape, dtype=bool)
    ended[rr, kk], ended[rr, jj] = pos[rr, kk] == aim[rr, jj], pos[rr, jj] == aim[rr, kk]
    since[ended] = s.t + 1
    return ended


#: Neighbour lists of the maps seen (``id(neighbors) -> (neighbors, lists)``): the
#: searches of pushes run on Python lists, several times faster than on array items.
_LISTS: dict[int, tuple[np.ndarray, list[list[int]]]] = {}


def _neighbour_lists(p: Params) -> list[list[int]]:
    """``p.neighbors`` as Python lists (computed once per map)."""
    return _cell_list(p, "neighbors")


def _cell_list(p: Params, name: str) -> list:
    """The array ``p.<name>`` as Python lists (computed once per map)."""
    a = getattr(p, name)
    seen = _LISTS.get(id(a))
    if seen is None or seen[0] is not a:
        if len(_LISTS) > 64:
            _LISTS.clear()
        seen = _LISTS[id(a)] = (a, a.tolist())
    return seen[1]


def _move(s: State, r: int, k: int, cell: int) -> None:
    s.occ[r, s.pos[r, k]] = -1
    s.occ[r, cell] = k
    s.pos[r, k] = cell


def _push_path(
    nbrs: list[list[int]],
    occ: list[int],
    own: int,
    start: int,
    movable: list[bool],
    keep_out: tuple[list[int], list[int], list[int]] | None,
) -> list[int] | None:
    """Cells ``[start, ..., empty]`` along which the robots from ``start`` on can shift.

    Breadth-first from ``start`` (whose robot must be movable), never through the
    holder's own cell ``own``, through immovable robots, nor into a held pocket or
    deeper inside one (``keep_out``: the run's ``reserved``, ``pocket_of`` and
    ``pocket_depth``, each per cell; a step towards the pocket's junction is allowed,
    so a push may shift robots out of a held pocket); neighbours in N, E, S, W order.
    ``nbrs``: each cell's neighbours (-1: wall); ``occ``: the robot on each cell of the
    run (-1: none); ``movable``: per robot. None if no empty cell can be reached.
    """
    if not movable[occ[start]]:
        return None
    reserved, pocket_of, depth = keep_out if keep_out is not None else (None, None, None)
    parent = {start: -1}
    queue = deque([start])
    while queue:
        c = queue.popleft()
        for nb in nbrs[c]:
            if nb < 0 or nb == own or nb in parent:
                continue
            if reserved is not None and battery.in_held_pocket(nb, pocket_of, reserved):
                if pocket_of[nb] != pocket_of[c] or depth[nb] >= depth[c]:
                    continue
            j = occ[nb]
            if j >= 0 and not movable[j]:
                continue
            parent[nb] = c
            if j < 0:
                path = [nb]
                while path[-1] != start:
                    path.append(parent[path[-1]])
                return path[::-1]
            queue.append(nb)
    return None


def pass_token(
    s: State, p: Params, want: np.ndarray, res: Resolution, progressed: np.ndarray
) -> None:
    """Choose the robot that holds the right of way in the next step (see module doc).

    ``progressed``: bool ``[R, K]``, the robots whose task ended this step."""
    R, K = s.pos.shape
    if not p.avoid_collisions or K == 1:
        return
    rows = np.arange(R)
    tok = s.token
    blocked = s.active[:, None] & (want >= 0) & ~res.as_asked
    had = tok >= 0
    t0 = np.maximum(tok, 0)
    pursues = had & (want[rows, t0] >= 0) & ~progressed[rows, t0] & s.active
    handed = res.handoff >= 0
    candidates = blocked.copy()
    candidates[rows[pursues], tok[pursues]] = True
    candidates[rows[handed], res.handoff[handed]] = True
    # by age; among equals the robot handed the holder's task first, then the holder
    # (it keeps the token unless a strictly older task is blocked), then the turn
    age = np.clip(s.t + 1 - s.since, 0, 1 << 30)
    turn = (K - 1) - (np.arange(K) - (s.t + 1)) % K
    first = np.broadcast_to(turn[None, :], (R, K)).copy()
    first[rows[pursues], tok[pursues]] = K
    first[rows[handed], res.handoff[handed]] = K + 1
    key = np.where(candidates, age * (K + 2) + first, -1)
    new = np.where(key.max(axis=1) >= 0, key.argmax(axis=1), -1)
    s.token_held = np.where((new == tok) & (new >= 0), s.token_held + 1, 0)
    s.token = new


def direction_of(p: Params, before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """int ``[R, K]``: the port (direction) of the move ``before -> after``, the lowest
    port of ``before`` leading to ``after`` (0 if no move)."""
    nbrs = np.take(p.neighbors, before, axis=0)  # [R, K, D]
    out = np.zeros(before.shape, dtype=np.int64)
    for d in range(nbrs.shape[-1] - 1, -1, -1):  # the lowest port written last
        np.copyto(out, d, where=nbrs[..., d] == after)
    return out
