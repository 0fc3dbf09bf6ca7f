"""The numpy engine's time loop: :func:`advance` on every team step.

The reference engine, written once: each team step is the general step of
:mod:`qpatrol.world` (with :mod:`qpatrol.world.traffic` and :mod:`qpatrol.world.battery`)
and the strategy's ``act`` and ``learn``, for every strategy, setting and recorder, with a
checkpoint possible after any step. The compiled engine is the fast one
(:mod:`qpatrol.engines.numba_core`); it writes the same files to the bit.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from qpatrol.measures import Measures, stalls
from qpatrol.measures.records import Recorder, Tail
from qpatrol.measures.timeline import Timeline
from qpatrol.world import Outcome, Params, State, begin_step, failures
from qpatrol.world import step as world_step
from qpatrol.world.rng import Streams

if TYPE_CHECKING:
    from qpatrol.run.checkpoint import Checkpointer
    from qpatrol.strategies.base import Strategy


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
    quota = bool(p.episodes)  # only an episode quota makes runs inactive
    every = max(1, total // 200)
    for i in range(first, total):
        if quota and not state.active.any():
            break
        out = advance(state, p, strategy, streams.next(), rec)
        measure(state, p, out, watch, tail, timeline)
        if progress is not None and (i + 1) % every == 0:
            progress(i + 1, total)
        if checkpoint is not None:
            checkpoint.tick(i + 1, (state, strategy, watch, streams, rec, tail, timeline))
    return "general"


def measure(
    state: State, p: Params, out: Outcome, watch: Measures, tail: Tail, timeline: Timeline
) -> None:
    """After the world's step ``out``: robots fail if it is their step (at the end of the
    step, before it is measured), then the measures, the trajectory and the timeline
    take the step in."""
    failing = None
    if out.t == p.failures_at:
        failing = failures.apply(state, p, np.flatnonzero(out.active))
    stall = stalls(state, out.t)
    watch.observe(out, state.wait, state.charge if p.battery else None, failing, stall)
    tail.observe(state)
    timeline.observe(out)


def advance(
    state: State,
    p: Params,
    strategy: Strategy,
    u: np.ndarray,
    rec: Recorder | None = None,
) -> Outcome:
    """One team step: the strategy chooses, the world moves, the strategy learns.

    ``u``: float ``[R, K, 2]``, this step's uniforms of every run.
    """
    obs = begin_step(state, p)
    ask = strategy.act(obs, u)
    out = world_step(
        state,
        p,
        obs,
        ask,
        strategy.aims(obs),
        strategy.plans_on_edges,
        strategy.keeps_plans and p.ahead is not None,
    )
    if out.swapped is not None and (out.swapped >= 0).any():
        strategy.exchange(out.swapped)
    strategy.learn(out, rec)
    if rec is not None:
        rec.episodes(out.t, out.episodes)
    return out
