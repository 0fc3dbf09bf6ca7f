"""Compiled strategies: one file per strategy, each with ``pack``, ``unpack``, ``act``
and ``learn``, dispatched by a code from the one compiled loop
(:mod:`qpatrol.engines.numba_core`).

A strategy's file mirrors its numpy twin in :mod:`qpatrol.strategies`, operation for
operation, so both engines give the same files to the bit (``tests/test_engines.py``).
To compile one more strategy: write its file, add it to :data:`MODULES` under a new
code and call it from :func:`act` and :func:`learn`.
"""

from __future__ import annotations

from numba import njit

from qpatrol.engines.compiled import qlearning, qlearning_idleness
from qpatrol.engines.compiled.pack import Pack

#: Strategy name -> (code, module).
MODULES = {
    "qlearning": (0, qlearning),
    "qlearning-idleness": (1, qlearning_idleness),
}
QLEARNING = 0
QLEARNING_IDLENESS = 1


def covers(name: str) -> bool:
    """True when the strategy ``name`` is compiled."""
    return name in MODULES


def pack(strategy) -> tuple[int, Pack]:
    """``(code, pack)`` of a numpy strategy object (its arrays, shared or copied)."""
    code, module = MODULES[strategy.name]
    return code, module.pack(strategy)


def unpack(strategy, p: Pack) -> None:
    """Copy what the compiled loop changed back into the numpy strategy object (for
    arrays the pack holds as copies)."""
    MODULES[strategy.name][1].unpack(p, strategy)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def act(
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
):
    """``ask[k]`` (int ``[K]``) for each robot of run ``r`` at team step ``t``, step
    ``i`` of the block (``u`` float ``[R, T, K, 2]``); -1 for robots not choosing.

    The world as the step starts: ``pos``, ``head`` int ``[R, K]``, ``last`` int
    ``[R, G, C]`` (the groups' last visits), ``reserved`` int ``[R, H]`` (stations'
    holders); ``open_mask``: bool ``[K, 4]``, the world's open moves (every legal move
    where none is open); ``sp``: the strategy's :class:`Pack`."""
    if code == QLEARNING:
        qlearning.act(r, i, u, pos, head, open_mask, choosing, ask, sp.fpar, sp.ipar, sp.q)
    elif code == QLEARNING_IDLENESS:
        qlearning_idleness.act(
            r, i, t, u, nbrs, dot_value, communication, pos, head, open_mask, choosing, ask, sp
        )


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def learn(
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
):
    """After the team step ``t`` of run ``r``: the strategy learns. Returns the number
    of Q-update rows written to ``up_int``/``up_float``.

    The outcome (:class:`qpatrol.world.Outcome` for one run): ``pos`` int ``[R, K]``
    after the step; per robot ``[K]``: ``prev_pos``, ``prev_head``, ``moved``, ``ask``
    (the move asked for, -1 none), ``as_asked`` (made it), ``choosing`` (the strategy
    chose it), ``reward``, ``eaten``, ``blocked_by`` (the robot in the way, -1 none);
    ``ended`` bool ``[G]``: the group's episode ended this step; ``active`` bool ``[R]``:
    the runs that go on after it (an episode quota may have stopped run ``r``)."""
    if code == QLEARNING:
        n_up = qlearning.learn(
            r,
            t,
            nbrs,
            wall_legal,
            prev_pos,
            prev_head,
            ask,
            as_asked,
            choosing,
            reward,
            eaten,
            sp.fpar,
            sp.ipar,
            sp.q,
            sp.n,
            record_all,
            watched,
            up_int,
            up_float,
            n_up,
        )
    elif code == QLEARNING_IDLENESS:
        n_up = qlearning_idleness.learn(
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
            eaten,
            ended,
            active,
            sp,
            record_all,
            watched,
            up_int,
            up_float,
            n_up,
        )
    return n_up
