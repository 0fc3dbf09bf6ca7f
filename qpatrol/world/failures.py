"""Robot failures: at the end of team step ``failures.at``, ``failures.robots`` robots of
every run leave the map for good.

Which robots fail is drawn once per run, before its first step, from a stream of its
own derived from the run's: ``SeedSequence(seed, spawn_key=(point, run, FAILURE_KEY))``
(the run's stream is ``spawn_key=(point, run)``, :mod:`qpatrol.world.rng`), so the choice
depends only on the seed, the point and the run (never on the batch, ``--jobs``, the
engine), and no other draw of the run changes: with ``failures.robots: 0`` every number
is what it was without failures.

A robot that fails (:func:`apply`, at the end of the step, after its moves, stations,
waits, right of way, episodes and learning) takes mode
:data:`~qpatrol.world.battery.GONE`: it never chooses, asks or waits again; it gives up
the right of way (the token goes to nobody this step) and any station it holds or is
on its way to; it leaves the station queue; and its cell is emptied (``occ``), so
traffic never sees it again: no one is blocked or pushed by it. ``pos`` keeps its last
cell. The compiled engine's twin is :mod:`qpatrol.engines.compiled.fail`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from qpatrol.world.battery import GONE
from qpatrol.world.rng import RunKey, Seed

if TYPE_CHECKING:
    from qpatrol.world import Params, State

#: The last entry of the spawn key of a run's failure stream (the run's own stream has
#: the key ``(point, run)``).
FAILURE_KEY = 1


def failure_sequence(seed: Seed) -> np.random.SeedSequence:
    """The SeedSequence that chooses the failed robots of the run whose stream is
    ``seed`` (a SeedSequence or a :class:`~qpatrol.world.rng.RunKey`): its spawn key with
    :data:`FAILURE_KEY` appended."""
    seq = seed.sequence() if isinstance(seed, RunKey) else seed
    return np.random.SeedSequence(
        seq.entropy, spawn_key=(*seq.spawn_key, FAILURE_KEY), pool_size=seq.pool_size
    )


def choose(seeds: Sequence[Seed], n_agents: int, n_failures: int) -> np.ndarray:
    """int ``[R, F]``: the robots that fail in each run (``F = n_failures`` distinct
    indices below ``n_agents``, in increasing order), drawn from each run's failure
    stream (:func:`failure_sequence`); ``[R, 0]`` when ``n_failures`` is 0."""
    out = np.zeros((len(seeds), n_failures), dtype=np.int64)
    if n_failures:
        for i, seed in enumerate(seeds):
            rng = np.random.Generator(np.random.PCG64(failure_sequence(seed)))
            out[i] = np.sort(rng.choice(n_agents, size=n_failures, replace=False))
    return out


def apply(s: State, p: Params, rows: np.ndarray) -> np.ndarray:
    """The robots ``s.failed`` of runs ``rows`` (int ``[B]``, the runs that took this
    step) fail now, in place (see the module doc). Returns bool ``[R, K]``: the robots
    that failed."""
    del p  # (the rule reads nothing of the map)
    failing = np.zeros(s.pos.shape, dtype=bool)
    for r in np.asarray(rows).tolist():
        for k in s.failed[r].tolist():
            failing[r, k] = True
            s.mode[r, k] = GONE
            s.wait[r, k] = 0
            s.rest[r, k] = 0
            s.depart_left[r, k] = 0
            s.goal[r, k] = -1
            s.reserved[r, s.reserved[r] == k] = -1
            if s.token[r] == k:
                s.token[r] = -1
                s.token_held[r] = 0
            if s.occ[r, s.pos[r, k]] == k:
                s.occ[r, s.pos[r, k]] = -1
    return failing


def describe(s: State, p: Params) -> list[dict[str, object]]:
    """Per run, for ``summary.json``: ``failed_robots`` (the robots that failed, a list;
    empty for a run that stopped before step ``p.failures_at``) and ``failed_at``."""
    out = []
    for r in range(s.n_runs):
        reached = bool(p.failures_at) and int(s.steps_done[r]) >= p.failures_at
        robots = s.failed[r].tolist() if reached else []
        out.append({"failed_robots": robots, "failed_at": int(p.failures_at)})
    return out
