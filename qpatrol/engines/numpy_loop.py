"""The numpy engine's time loop: a fast step where one applies, the general step elsewhere.

Each team step is computed either by :func:`qpatrol.run.advance` (the general step:
every strategy, setting and recorder) or by a fast step for the configs it covers
(:mod:`qpatrol.engines.numpy_solo`: lone Q-learners; :mod:`qpatrol.engines.numpy_team`:
Q-learning teams, battery off); a fast step declines a step it
does not cover (it then changes nothing) and the general step takes it, so the two
alternate freely and the results are the same to the bit. :data:`FAST` switches the
fast steps off (the equality tests run every config both ways).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from qpatrol.checkpoint import Checkpointer
from qpatrol.engines import numpy_solo, numpy_team
from qpatrol.measures import Measures
from qpatrol.records import Recorder, Tail
from qpatrol.rng import Streams
from qpatrol.timeline import Timeline
from qpatrol.world import Params, State

#: Use the fast steps where they apply (False: the general step on every step).
FAST = True


def fast_step(
    p: Params,
    s: State,
    strategy: Any,
    m: Measures,
    rec: Recorder,
    timeline: Timeline,
    defer: bool = True,
) -> numpy_solo.Solo | numpy_team.Team | None:
    """The fast step of this batch, or None where no fast step applies; ``defer``: it
    may defer writes until its ``deferred.sync()`` (:mod:`qpatrol.engines.deferred`)."""
    if not FAST:
        return None
    if numpy_solo.covers(p, strategy) and not rec.wants_updates and not timeline.window:
        return numpy_solo.Solo(p, s, strategy, m, defer)
    if numpy_team.covers(p, strategy):
        return numpy_team.Team(p, s, strategy, m, defer)
    return None


def run(
    state: State,
    p: Params,
    strategy: Any,
    watch: Measures,
    streams: Streams,
    rec: Recorder,
    tail: Tail,
    timeline: Timeline,
    first: int,
    total: int,
    progress: Callable[[int, int], None] | None,
    checkpoint: Checkpointer | None,
) -> str:
    """Team steps ``first..total`` of the batch, in place (stops early once no run is
    active); ``progress(done, total)`` about 200 times, ``checkpoint.tick`` every step.
    A fast step defers its writes with a checkpointer too (as without one): the
    checkpointer brings them up to date just before it saves (``before_save``).
    Returns the step that ran: ``fast-solo``, ``fast-team`` (the general step taking
    the steps it declines) or ``general``."""
    from qpatrol.run import advance  # run.py imports this module

    fast = fast_step(p, state, strategy, watch, rec, timeline)
    if checkpoint is not None and fast is not None:
        checkpoint.before_save = fast.deferred.sync
    quota = bool(p.episodes)  # only an episode quota makes runs inactive
    every = max(1, total // 200)
    try:
        for i in range(first, total):
            if quota and not state.active.any():
                break
            u = streams.next()
            if (
                fast is None
                or (quota and not state.active.all())
                or not fast.step(u, rec, tail, timeline)
            ):
                if fast is not None:
                    fast.deferred.sync()
                out = advance(state, p, strategy, u, rec)
                watch.observe(out, state.wait, state.charge if p.battery else None)
                tail.observe(state)
                timeline.observe(out)
            if progress is not None and (i + 1) % every == 0:
                progress(i + 1, total)
            if checkpoint is not None:
                checkpoint.tick(i + 1, (state, strategy, watch, streams, rec, tail, timeline))
    finally:
        if checkpoint is not None:
            checkpoint.before_save = None
    if fast is None:
        return "general"
    fast.deferred.sync()
    return "fast-solo" if isinstance(fast, numpy_solo.Solo) else "fast-team"
