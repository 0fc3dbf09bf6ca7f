"""Compiled strategies: one file per strategy, each with ``pack``, ``unpack``, ``act``
and ``learn``, dispatched by a code from the one compiled loop
(:mod:`qpatrol.engines.numba_core`).

A strategy's file mirrors its numpy twin in :mod:`qpatrol.strategies`, operation for
operation, so both engines give the same files to the bit (``tests/test_engines.py``).
To compile one more strategy: write its file, add it to :data:`MODULES` under a new
code (and its name to :data:`qpatrol.engines.COMPILED_POLICIES`, which names them
without importing numba) and call it from :func:`act` and :func:`learn`.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from numba import njit

from qpatrol.engines import cachelock
from qpatrol.engines.compiled import (
    cbls,
    conscientious,
    dta,
    evap,
    follow,
    goals,
    gravitational,
    hpcc,
    qlearning,
    qlearning_idleness,
    random,
    shared_conscientious,
    tour,
)
from qpatrol.engines.compiled.choice import ports_of
from qpatrol.engines.compiled.pack import Pack

# a sweep's worker processes compile different loops (signatures of one function) side
# by side on a fresh machine: their saves to numba's on-disk cache must not interleave
cachelock.install()

QLEARNING = 0
QLEARNING_IDLENESS = 1
RANDOM, CONSCIENTIOUS, SHARED_CONSCIENTIOUS, EVAP, CYCLIC, PARTITION = 2, 3, 4, 5, 6, 7
HCR, CC, GBS, SEBS = 8, 9, 10, 11  # the goal followers (compiled/goals.py)
DTA_GREEDY, DTA_SSI, DTA_SSI_PART = 12, 13, 14  # goal followers with any target (compiled/dta.py)
CBLS = 15  # the learning goal follower (compiled/cbls.py)
LEARNED_TOUR = 16  # a walk follower that learns its walk (compiled/tour.py)
HPCC = 17  # a goal follower along idleness-reweighted routes (compiled/hpcc.py)
GRAVITATIONAL = 18  # robots pulled by idle targets' masses (compiled/gravitational.py)

#: Strategy name -> (code, module).
MODULES = {
    "qlearning": (QLEARNING, qlearning),
    "qlearning-idleness": (QLEARNING_IDLENESS, qlearning_idleness),
    "random": (RANDOM, random),
    "conscientious": (CONSCIENTIOUS, conscientious),
    "shared-conscientious": (SHARED_CONSCIENTIOUS, shared_conscientious),
    "evap": (EVAP, evap),
    "cyclic": (CYCLIC, follow),
    "partition": (PARTITION, follow),
    "hcr": (HCR, goals),
    "cc": (CC, goals),
    "gbs": (GBS, goals),
    "sebs": (SEBS, goals),
    "dta-greedy": (DTA_GREEDY, dta),
    "dta-ssi": (DTA_SSI, dta),
    "dta-ssi-part": (DTA_SSI_PART, dta),
    "cbls": (CBLS, cbls),
    "learned-tour": (LEARNED_TOUR, tour),
    "hpcc": (HPCC, hpcc),
    "gravitational": (GRAVITATIONAL, gravitational),
}


def key_cache(dispatcher, *files: str) -> None:
    """Key numba's on-disk cache of ``dispatcher`` (``njit(cache=True)``) on its own
    source file, ``files`` and every file of this package, not on its own file alone:
    the loop inlines the strategies' code, and numba would otherwise load a loop
    compiled before a strategy's file changed (after an edit, or an upgrade that left
    the cache in ``__pycache__``). Uses numba's private cache object; without it (another
    numba version), nothing changes."""
    cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
    if cache_file is None or not hasattr(cache_file, "_source_stamp"):
        return
    digest = hashlib.sha256()
    for path in [*map(Path, files), *sorted(Path(__file__).parent.glob("*.py"))]:
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    cache_file._source_stamp = ("qpatrol", digest.hexdigest())


def pack(strategy) -> tuple[int, Pack]:
    """``(code, pack)`` of a numpy strategy object (its arrays, shared or copied)."""
    code, module = MODULES[strategy.name]
    return code, module.pack(strategy)


def unpack(strategy, p: Pack, state=None) -> None:
    """Copy what the compiled loop changed back into the numpy strategy object (for
    arrays the pack holds as copies). With the world's ``state``, a module's
    ``sat_out(strategy, state)`` (if it has one) then does what the numpy engine's
    strategy does in the steps that runs sit out after their episode quota (the
    compiled loop skips them)."""
    module = MODULES[strategy.name][1]
    module.unpack(p, strategy)
    sat_out = getattr(module, "sat_out", None)
    if sat_out is not None and state is not None:
        sat_out(strategy, state)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def act(code, r, t, ur, battery, p, s, w, sp):
    """``w.ask[k]`` (int ``[K]``) for each robot of run ``r`` at team step ``t`` (``ur``
    float ``[K, 2]``: each robot's two uniforms of the step); -1 for robots not choosing
    (``w.choosing``).

    ``p``, ``s``, ``w``: the loop's ``Params``, ``World`` (the world as the step
    starts) and ``Work`` (:mod:`qpatrol.engines.compiled.bundles`), ``w.open_mask`` bool
    ``[K, D]`` the world's open moves (every legal move where none is open); ``sp``:
    the strategy's :class:`Pack`."""
    nbrs, pos, open_mask, choosing, ask = p.nbrs, s.pos, w.open_mask, w.choosing, w.ask
    if code == QLEARNING:
        _, epsilon, use_heading, q_f, _ = qlearning.tables(sp, r)
        nd = ports_of(p.entry, nbrs.shape[1])
        slot_r = qlearning.slots(sp, r)
        qlearning.act(
            ur, pos[r], s.head[r], open_mask, choosing, ask, epsilon, use_heading, q_f,
            slot_r, nd,
        )  # fmt: skip
    elif code == QLEARNING_IDLENESS:
        qlearning_idleness.act(
            r,
            t,
            ur,
            p.far,
            p.dot_value,
            p.communication,
            pos,
            s.head,
            open_mask,
            choosing,
            ask,
            sp,
            w.score,
        )
    elif code == RANDOM:
        random.act(ur, open_mask, choosing, ask)
    elif code == CONSCIENTIOUS:
        conscientious.act(r, ur, p.far, pos, open_mask, choosing, ask, sp.cell_i, w.score)
    elif code == SHARED_CONSCIENTIOUS:
        shared_conscientious.act(
            r, ur, p.far, p.communication, pos, s.last, open_mask, choosing, ask, w.score
        )
    elif code == EVAP:
        evap.act(
            r, t, ur, p.far, p.communication, pos, open_mask, choosing, ask, sp.cell_f,
            sp.cell_i, sp.fpar, w.score,
        )  # fmt: skip
    elif walk_follower(code):
        walk, length = sp.table_i, sp.row_i
        if p.travels:  # a walk follower keeps its plan on a graph's waypoints too
            for k in range(choosing.shape[0]):
                choosing[k] = choosing[k] or w.travel[k] >= 0
        if code == LEARNED_TOUR:  # learned routes: each run's own
            tour.learn_routes(
                r, t, ur, nbrs, choosing, sp.ipar, sp.robot_i, sp.cell_i, sp.table_i, sp.dist
            )
            walk, length = tour.routes(sp.cell_i, r, sp.ipar)
        follow.act(
            r, t, nbrs, p.target, battery, p.pocket_of, pos, s.reserved, s.mode, s.aim,
            s.since, s.token, choosing, ask, sp.ipar, sp.robot_i, walk, length, sp.dist,
        )  # fmt: skip
        follow.aims(r, sp.robot_i, walk, w.aim)
        if p.travels:  # (base.walking: the world's choosing again)
            for k in range(choosing.shape[0]):
                choosing[k] = choosing[k] and w.travel[k] < 0
    elif code >= HCR and code <= SEBS:
        goals.act(
            r, t, ur, battery, p, s, w, sp.ipar, sp.fpar, sp.robot_i, sp.table_i, sp.row_i,
            sp.dist, sp.cell_i, sp.row_f,
        )  # fmt: skip
        _goal_aims(r, sp.robot_i, w.aim)
    elif code >= DTA_GREEDY and code <= DTA_SSI_PART:
        dta.act(
            r, t, ur, battery, p, s, w, sp.ipar, sp.fpar, sp.robot_i, sp.cell_i, sp.row_i,
            sp.dist, sp.row_f,
        )  # fmt: skip
        _goal_aims(r, sp.robot_i, w.aim)
    elif code == HPCC:
        hpcc.act(
            r, t, ur, battery, p, s, w, sp.ipar, sp.fpar, sp.robot_i, sp.cell_i, sp.table_i,
            sp.row_i, sp.dist, sp.cell_f, sp.cell_b,
        )  # fmt: skip
        _goal_aims(r, sp.robot_i, w.aim)  # its goal (hpcc.Strategy.aims)
    elif code == CBLS:
        cbls.act(
            r, t, ur, battery, p, s, w, sp.robot_i, sp.q, sp.cell_i, sp.cell_f, sp.row_f,
            sp.table_i, sp.row_i, sp.dist,
        )  # fmt: skip
        _goal_aims(r, sp.robot_i, w.aim)
    elif code == GRAVITATIONAL:
        gravitational.act(
            r, t, ur, p, s, w, sp.ipar, sp.fpar, sp.robot_i, sp.table_i, sp.row_i, sp.dist,
            sp.cell_f,
        )  # fmt: skip


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def walk_follower(code):
    """The strategy follows closed walks (``cyclic``, ``partition``, ``learned-tour``:
    :mod:`~qpatrol.engines.compiled.follow`); it keeps its plan on a graph's waypoints
    too (:attr:`qpatrol.strategies.base.Strategy.plans_on_edges`)."""
    return code == CYCLIC or code == PARTITION or code == LEARNED_TOUR


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def keeps_plans(code):
    """The strategy's robots' goals are tasks allocated to them (``dta-*``;
    :attr:`qpatrol.strategies.base.Strategy.keeps_plans`)."""
    return code >= DTA_GREEDY and code <= DTA_SSI_PART


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _goal_aims(r, robot_i, aim):
    """A goal follower's aims (``aim`` int ``[K]``): each robot's goal (``robot_i[r, k,
    0]``; :meth:`qpatrol.strategies.goals.GoalFollower.aims`)."""
    for k in range(aim.shape[0]):
        aim[k] = robot_i[r, k, 0]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def exchange(code, r, w, sp):
    """Robots of run ``r`` whose tasks the world exchanged (``w.swapped``) exchange their
    plans (the strategies' :meth:`~qpatrol.strategies.base.Strategy.exchange`): a walk
    follower's walk, target and spacing; a goal follower's goal (``hpcc``: its hop and
    route too; ``gravitational``: the goal it announced)."""
    if walk_follower(code):
        follow.exchange(r, w.swapped, sp.robot_i)
    elif (code >= HCR and code <= CBLS) or code == HPCC or code == GRAVITATIONAL:
        n_cells = sp.cell_i.shape[2]
        for k in range(w.swapped.shape[0]):
            j = w.swapped[k]
            if j <= k:
                continue
            ri = sp.robot_i[r]
            ri[k, 0], ri[j, 0] = ri[j, 0], ri[k, 0]
            if code == HPCC:
                ri[k, 1], ri[j, 1] = ri[j, 1], ri[k, 1]
                route = sp.cell_i[r]
                for x in range(n_cells):
                    route[k, x], route[j, x] = route[j, x], route[k, x]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def learn(code, r, t, p, s, w, sp, o, n_up):
    """After the team step ``t`` of run ``r``: the strategy learns. Returns the number
    of Q-update rows written to ``o.up_int``/``o.up_float``.

    The outcome (:class:`qpatrol.world.Outcome` for one run) is ``s.pos`` after the
    step and ``w``'s per-robot arrays ``[K]``: ``prev_pos``, ``prev_head``, ``moved``,
    ``ask`` (the move asked for, -1 none), ``as_asked`` (made it), ``choosing`` (the
    strategy chose it), ``reward``, ``eaten``, ``blocked_by`` (the robot in the way, -1
    none); ``w.ended`` bool ``[G]``: the group's episode ended this step; ``s.active``
    bool ``[R]``: the runs that go on after it (an episode quota may have stopped run
    ``r``)."""
    if code == QLEARNING:
        gamma, _, use_heading, q_f, n_f = qlearning.tables(sp, r)
        slot_r = qlearning.slots(sp, r)
        if p.travels:  # decisions at a graph's vertices, completed at the next vertex
            n_up = qlearning.learn_pending(
                r, t, p, s, w, o, n_up, gamma, use_heading, q_f, n_f, sp.robot_i[r], slot_r
            )
        else:
            n_up = qlearning.learn(r, t, p, w, o, n_up, gamma, use_heading, q_f, n_f, slot_r)
    elif code == QLEARNING_IDLENESS:
        n_up = qlearning_idleness.learn(r, t, p, s, w, sp, o, n_up)
    elif code == CONSCIENTIOUS:
        conscientious.learn(r, t, s.pos, w.moved, sp.cell_i)
    elif code == EVAP:
        evap.learn(r, t, p.communication, s.pos, w.moved, p.target, sp.cell_f, sp.cell_i, sp.fpar)
    elif code >= HCR and code <= SEBS:
        goals.learn(r, t, sp.ipar, s.pos, w.moved, w.swapped, sp.robot_i, sp.cell_i)
    elif code == HPCC:
        hpcc.learn(r, t, s.pos, w.moved, w.swapped, sp.robot_i, sp.cell_i)
    elif code == CBLS:
        cbls.learn(r, t, p.communication, s.pos, w.moved, sp.row_i, sp.cell_i, sp.cell_f)
    return n_up
