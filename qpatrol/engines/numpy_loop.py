"""The numpy engine's time loop: :func:`qpatrol.run.advance` on every team step.

The reference engine, written once: each team step is the general step of
:mod:`qpatrol.world` (with :mod:`qpatrol.traffic` and :mod:`qpatrol.battery`) and the
strategy's ``act`` and ``learn``, for every strategy, setting and recorder, with a
checkpoint possible after any step. The compiled engine is the fast one
(:mod:`qpatrol.engines.numba_core`); it writes the same files to the bit.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from qpatrol.checkpoint import Checkpointer
from qpatrol.measures import Measures
from qpatrol.records import Recorder, Tail
from qpatrol.rng import Streams
from qpatrol.timeline import Timeline
from qpatrol.world import Params, State


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
    Returns the name of the step that ran, ``general`` (:func:`advance` on every step,
    the numpy engine's only step), for ``meta.json``'s ``engine.loop``."""
    from qpatrol.run import advance  # run.py imports this module

    quota = bool(p.episodes)  # only an episode quota makes runs inactive
    every = max(1, total // 200)
    for i in range(first, total):
        if quota and not state.active.any():
            break
        out = advance(state, p, strategy, streams.next(), rec)
        watch.observe(out, state.wait, state.charge if p.battery else None)
        tail.observe(state)
        timeline.observe(out)
        if progress is not None and (i + 1) % every == 0:
            progress(i + 1, total)
        if checkpoint is not None:
            checkpoint.tick(i + 1, (state, strategy, watch, streams, rec, tail, timeline))
    return "general"
