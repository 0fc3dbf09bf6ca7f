"""Run an experiment: config -> map -> world + strategy -> measures and records -> files.

The Python API behind ``qpatrol train``::

    from qpatrol.config import load_config
    from qpatrol.run import simulate, write_run

    cfg = load_config("configs/paper.yaml", ["runs=4"])
    result = simulate(cfg)            # all runs of the config as one batch
    result.summary[0]["avg_idleness"]
    write_run(result, "results/runs/demo")
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qpatrol import engines, measures, strategies, world
from qpatrol.config import Config, ConfigError
from qpatrol.engines import coldstart, numpy_loop
from qpatrol.engines import threads as engine_threads
from qpatrol.maps import Map, get_map
from qpatrol.measures.records import Recorder, Tail, to_csv_text
from qpatrol.measures.timeline import Timeline
from qpatrol.run import outputs
from qpatrol.run.checkpoint import DEFAULT_EVERY, Checkpointer
from qpatrol.strategies.base import Strategy
from qpatrol.util import atomic, manifest, provenance
from qpatrol.world import failures, limits
from qpatrol.world.rng import Seed, Streams, run_keys

Progress = Callable[[int, int], None]


@dataclass
class RunResult:
    """Everything one batch of runs produced.

    Attributes:
        config: the resolved config.
        map: the map it ran on.
        params: the world's parameters.
        state: the final world state.
        strategy: the strategy after the run (a learner's tables in ``tables()``).
        measures: the measure accumulators (visit counts and the rest).
        run_ids: int ``[R]``, the run number of each batch row.
        episodes: one row per ended episode.
        transitions: one row per Q-update (None unless ``record.transitions``).
        watch: Q-updates of the watched states (None unless ``record.watch``).
        trajectory: agents' cells over each run's last steps (None unless
            ``record.trajectory``).
        timeline: idleness in windows of each run (None unless ``record.timeline``).
        summary: one dict of measures per run.
        engine: the engine that ran the time loop (``numpy`` or ``numba``).
        engine_note: why it is not the one the config asked for ("" when it is).
        loop: the loop of that engine that ran: on numba the compiled loop's name
            (:func:`qpatrol.engines.compiled_loop`: ``any``, ``qlearning``,
            ``qlearning-solo``, ``qlearning-team``), on numpy ``general`` (its one step,
            :mod:`qpatrol.engines.numpy_loop`).
    """

    config: Config
    map: Map
    params: world.Params
    state: world.State
    strategy: Strategy
    measures: measures.Measures
    run_ids: np.ndarray
    episodes: pd.DataFrame
    transitions: pd.DataFrame | None
    watch: pd.DataFrame | None
    trajectory: pd.DataFrame | None
    timeline: pd.DataFrame | None
    summary: list[dict[str, Any]]
    engine: str = "numpy"
    engine_note: str = ""
    loop: str = ""


#: Most Q-update rows ``record.transitions`` may keep in memory for one batch.
MAX_TRANSITION_ROWS = 20_000_000


def prepare(cfg: Config) -> tuple[Map, world.Params]:
    """Load the map and build the parameters; raises ConfigError/MapError on bad input."""
    rows = cfg["steps"] * cfg["runs"] * cfg["agents"]
    if cfg["record.transitions"] and rows > MAX_TRANSITION_ROWS:
        raise ConfigError(
            f"record.transitions: up to {rows:,} rows (steps x runs x agents) would not fit; "
            f"allowed: at most {MAX_TRANSITION_ROWS:,} (lower steps or runs, or trace cells "
            "with record.watch)"
        )
    m = get_map(cfg["map"])
    limits.check_config_on_map(cfg, m)  # before anything large is allocated
    return m, world.make_params(cfg, m)


def simulate(
    cfg: Config,
    point: int = 0,
    runs: range | None = None,
    progress: Progress | None = None,
    prepared: tuple[Map, world.Params] | None = None,
    checkpoint: Checkpointer | None = None,
) -> RunResult:
    """Run ``runs`` (default: all of ``cfg['runs']``) of one config as one batch.

    Run r draws from ``SeedSequence(cfg['seed'], spawn_key=(point, r))``; the result
    of a run does not depend on which other runs share the batch. ``progress`` is
    called as ``progress(steps_done, steps_total)``. With a ``checkpoint``, the loop's
    whole mutable state (simulator state, random streams, recorders, step index) is
    saved as it decides (:mod:`qpatrol.run.checkpoint`), and a checkpoint it loaded is
    continued from instead of starting afresh: the result is the same to the bit.

    The time loop runs on the engine of config key ``engine`` (:mod:`qpatrol.engines`);
    the result does not depend on it. ``result.engine`` is the one that ran.

    Without a checkpointer the runs are computed in consecutive batches of at most
    :func:`qpatrol.world.limits.batch_runs` runs (config key ``memory.limit_gib``) and joined
    (:func:`join`): the same result, to the bit, as one batch.
    """
    m, p = prepared or prepare(cfg)
    idx = runs if runs is not None else range(cfg["runs"])
    size = limits.batch_runs(cfg, m)
    if checkpoint is not None or len(idx) <= size:
        return _simulate_batch(cfg, point, idx, progress, (m, p), checkpoint)
    parts = [idx[i : i + size] for i in range(0, len(idx), size)]
    results = []
    for b, part in enumerate(parts):
        tick = None if progress is None else _BatchProgress(progress, b, len(parts))
        results.append(_simulate_batch(cfg, point, part, tick, (m, p), None))
    return join(results)


@dataclass
class _BatchProgress:
    """``progress(done, total)`` of batch ``b`` of ``n``, as a share of all of them."""

    progress: Progress
    b: int
    n: int

    def __call__(self, done: int, total: int) -> None:
        self.progress((self.b * total + done) // self.n, total)


def _simulate_batch(
    cfg: Config,
    point: int,
    idx: range,
    progress: Progress | None,
    prepared: tuple[Map, world.Params],
    checkpoint: Checkpointer | None,
) -> RunResult:
    """The runs ``idx`` of ``cfg`` as one batch (see :func:`simulate`)."""
    seeds = run_keys(cfg["seed"], idx, point)
    return _batch(cfg, seeds, np.array(list(idx)), None, progress, prepared, checkpoint)


def simulate_rows(
    cfg: Config,
    seeds: Sequence[Seed],
    run_ids: np.ndarray,
    values: dict[str, np.ndarray] | None,
    prepared: tuple[Map, world.Params],
    progress: Progress | None = None,
) -> RunResult:
    """One batch whose rows may differ in per-run values (:mod:`qpatrol.run.batching`).

    Args:
        cfg: the config of every row, but for ``values``.
        seeds: each row's SeedSequence or :class:`~qpatrol.world.rng.RunKey` (its random
            stream).
        run_ids: int ``[R]``, the run number written for each row in the tables.
        values: config key -> float64 ``[R]``, each row's value of the per-run keys that
            differ between rows (reward weights, and the keys the strategy names in
            ``RUN_KEYS``); None when they are all ``cfg``'s.
        prepared: the map and ``cfg``'s parameters.

    A row's numbers are those it would have in a batch of its own config and seed.
    """
    return _batch(cfg, seeds, np.asarray(run_ids), values, progress, prepared, None)


def _batch(
    cfg: Config,
    seeds: Sequence[Seed],
    run_ids: np.ndarray,
    values: dict[str, np.ndarray] | None,
    progress: Progress | None,
    prepared: tuple[Map, world.Params],
    checkpoint: Checkpointer | None,
) -> RunResult:
    """One batch of rows (see :func:`simulate` and :func:`simulate_rows`)."""
    m, p = prepared
    p = world.with_run_values(p, values)
    engine, note = engines.choose(cfg, len(seeds))
    if engine == "numpy" and note.startswith(coldstart.COLD):
        coldstart.warm_in_background(cfg, engines.compiled_loop(cfg))
    resumed = checkpoint.resumed if checkpoint is not None else None
    if resumed is None:
        streams, state, watch, rec, tail, timeline = new_batch(cfg, m, p, seeds, run_ids)
        starts = state.pos.copy()
        strategy = strategies.make(cfg["policy"], cfg, m, p, starts)
        if values:
            strategy.use_run_values(values)
        first = 0
    else:
        (state, strategy, watch, streams, rec, tail, timeline) = resumed.payload
        first = resumed.position
    total = cfg["steps"]
    args = (state, p, strategy, watch, streams, rec, tail, timeline, first, total, progress)
    if engine == "numba":
        compiling = coldstart.Compiling(engines.compiled_loop(cfg))
        try:
            threads = engine_threads.resolve(cfg["threads"])
            loop = _compiled_loop(*args, checkpoint, threads, compiling.done)
            compiling.done()
        finally:
            compiling.release()
    else:
        loop = numpy_loop.run(*args, checkpoint)
    if progress is not None:
        progress(total, total)
    return result_of(cfg, m, p, state, strategy, watch, rec, tail, timeline, engine, note, loop)


def new_batch(
    cfg: Config, m: Map, p: world.Params, seeds: Sequence[Seed], run_ids: np.ndarray
) -> tuple[Streams, world.State, measures.Measures, Recorder, Tail, Timeline]:
    """A batch before its first step: each row's random stream (``seeds``), the robots
    placed from it, the world (with the robots that will fail), the measures, the
    recorders (rows named ``run_ids``), the trajectory and the timeline."""
    # blocks of uniforms no longer than the run (the same numbers for any block)
    block = max(1, min(Streams.BLOCK, cfg["steps"]))
    streams = Streams(seeds, p.n_agents, block)
    starts = np.stack([world.place_agents(p, m, g) for g in streams.generators])
    failed = failures.choose(seeds, p.n_agents, cfg["failures.robots"])
    state = world.init_state(p, starts, failed)
    # with failures, every measure's window starts at the failure
    watch = measures.Measures(
        state.n_runs,
        p.n_agents,
        p.n_cells,
        max(cfg["record.warmup"], p.failures_at),
        p.target,
        measures.attack_steps(cfg["security.attack_steps"], p.n_targets),
        cfg["steps"],
        state.pos,
    )
    rec = Recorder(run_ids, transitions=cfg["record.transitions"], watch=cfg["record.watch"])
    tail = Tail(cfg["record.trajectory"], state)
    timeline = Timeline(state.n_runs, p.n_cells, cfg["record.timeline"], p.target)
    return streams, state, watch, rec, tail, timeline


def result_of(
    cfg: Config,
    m: Map,
    p: world.Params,
    state: world.State,
    strategy: Strategy,
    watch: measures.Measures,
    rec: Recorder,
    tail: Tail,
    timeline: Timeline,
    engine: str,
    note: str,
    loop: str,
) -> RunResult:
    """The :class:`RunResult` of a batch whose time loop has run (here, or stepped from
    outside by :class:`qpatrol.envs.PatrolVectorEnv`): the tables, the summaries (with
    the failures' and the strategy's facts) and the objects."""
    episodes = rec.episode_table()
    bound = measures.stall_bound(p, strategy.planned_wait())
    summary = measures.summarize(watch, episodes, rec.run_ids, state.steps_done, bound)
    if p.failures_at:
        for row, facts in zip(summary, failures.describe(state, p), strict=True):
            row.update(facts)
    run_facts = getattr(strategy, "run_facts", None)
    if run_facts is not None:
        for row, facts in zip(summary, run_facts(), strict=True):
            row.update(facts)
    return RunResult(
        config=cfg,
        map=m,
        params=p,
        state=state,
        strategy=strategy,
        measures=watch,
        run_ids=rec.run_ids,
        episodes=episodes,
        transitions=rec.transition_table(),
        watch=rec.watch_table(),
        trajectory=tail.table(state, rec.run_ids, m.coords),
        timeline=timeline.table(rec.run_ids, state.steps_done),
        summary=summary,
        engine=engine,
        engine_note=note,
        loop=loop,
    )


def _joined(objs: list[Any], rows: list[int]) -> Any:
    """A shallow copy of ``objs[0]`` whose per-run arrays (first axis: the batch's runs)
    are those of all ``objs``, concatenated in order."""
    out = copy.copy(objs[0])
    for name, v in vars(objs[0]).items():
        if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == rows[0]:
            parts = [vars(o)[name] for o in objs]
            if all(x.shape[0] == n for x, n in zip(parts, rows, strict=True)):
                setattr(out, name, np.concatenate(parts))
    return out


def _table(parts: list[pd.DataFrame | None]) -> pd.DataFrame | None:
    """Consecutive batches' tables as one (each table is ordered by run first)."""
    if parts[0] is None:
        return None
    return pd.concat(parts, ignore_index=True)


def join(results: list[RunResult]) -> RunResult:
    """One result of consecutive batches of the same config and point: their tables,
    summaries and per-run arrays (world state, strategy tables, measures) concatenated in
    batch order. Written with :func:`write_run`, it gives the same files as one batch."""
    if len(results) == 1:
        return results[0]
    first = results[0]
    rows = [r.state.n_runs for r in results]
    state = _joined([r.state for r in results], rows)
    state.t = max(r.state.t for r in results)
    return RunResult(
        config=first.config,
        map=first.map,
        params=first.params,
        state=state,
        strategy=_joined([r.strategy for r in results], rows),
        measures=_joined([r.measures for r in results], rows),
        run_ids=np.concatenate([r.run_ids for r in results]),
        episodes=_table([r.episodes for r in results]),
        transitions=_table([r.transitions for r in results]),
        watch=_table([r.watch for r in results]),
        trajectory=_table([r.trajectory for r in results]),
        timeline=_table([r.timeline for r in results]),
        summary=[s for r in results for s in r.summary],
        engine=first.engine,
        engine_note=first.engine_note,
        loop=first.loop,
    )


#: Agent-steps per call of the compiled loop: long enough to hide the call; and at
#: least COMPILED_MIN_STEPS team steps, so each run's tables stay in cache for a while.
COMPILED_BLOCK = 1 << 16
COMPILED_MIN_STEPS = 512
#: Large batches (more than COMPILED_BLOCK agent-steps in COMPILED_MIN_STEPS team steps)
#: are called COMPILED_RUN_STEPS team steps at a time: the loop advances one run after
#: the other, so a run's tables are loaded into cache once per 4,096 steps, not once per
#: 512.
COMPILED_RUN_STEPS = 4096
#: Longest a call of the compiled loop should take, in seconds: progress, a due
#: checkpoint and Ctrl-C wait for the end of a call. A batch so large that a call of its
#: block takes longer gets shorter blocks (halved down to COMPILED_MIN_STEPS team steps,
#: :func:`_next_block`); any block gives the same numbers.
COMPILED_CALL_SECONDS = 1.0


def compiled_schedule(
    n_runs: int, n_agents: int, wants_updates: bool, every_step: bool = False
) -> int:
    """The team steps of a call of the compiled loop, the same with or without a
    checkpointer, so that ``qpatrol train`` runs the loop as the Python API, ``sweep``,
    ``reproduce`` and ``bench`` do. ``every_step`` (a checkpointer that wants to see
    every team step, tests only): one team step per call."""
    R, K = n_runs, n_agents
    if every_step:
        return 1
    if wants_updates:  # the update buffers hold a row per agent-step of a block
        return max(1, (COMPILED_BLOCK // 8) // (R * K))
    if R * K * COMPILED_MIN_STEPS > COMPILED_BLOCK:
        return COMPILED_RUN_STEPS
    return max(COMPILED_MIN_STEPS, COMPILED_BLOCK // (R * K))


def _next_block(block: int, taken: int, seconds: float, largest: int) -> int:
    """The team steps of the next call, given that the last one took ``seconds`` for
    ``taken`` steps: the largest of ``largest``, ``largest // 2``, ... that fits in
    COMPILED_CALL_SECONDS at that speed, but not below COMPILED_MIN_STEPS (or
    ``largest`` when that is smaller). So the block shrinks when calls are slow (a very
    large batch, a slower strategy) and grows back after one slow call (the compile or
    the loading of the loop, which the first call pays)."""
    if taken <= 0 or seconds <= 0:
        return block
    fit = taken * COMPILED_CALL_SECONDS / seconds
    floor = min(largest, COMPILED_MIN_STEPS)
    b = largest
    while b > fit and b // 2 >= floor:
        b //= 2
    return b


def _compiled_loop(
    state: world.State,
    p: world.Params,
    strategy: Strategy,
    watch: measures.Measures,
    streams: Streams,
    rec: Recorder,
    tail: Tail,
    timeline: Timeline,
    first: int,
    total: int,
    progress: Progress | None,
    checkpoint: Checkpointer | None,
    threads: int = 1,
    compiled: Callable[[], None] | None = None,
) -> str:
    """Steps ``first..total`` on the compiled engine, in calls of blocks of team steps
    (same objects, same results as :func:`qpatrol.engines.numpy_loop.run`, for any
    block). The blocks are :func:`compiled_schedule`'s whether or not a checkpointer
    is given, shortened when a call would take more than COMPILED_CALL_SECONDS
    (:func:`_next_block`); ``progress`` is told and a checkpointer ticked after each
    call (after every team step when it asks for that: ``every_step``), so a due
    checkpoint or a Ctrl-C is served within about a second. With ``threads`` > 1 the
    runs of a call are cut into that many lanes, each advanced by its own thread
    (:mod:`qpatrol.engines.threads`): the same numbers. Returns the compiled loop's
    name (``numba_core.SPEC_NAMES``). ``compiled()`` is called once the first call of
    the loop returned (the loop is compiled, or loaded from numba's cache, then)."""
    import time

    from qpatrol.engines import numba_core

    R, K = state.n_runs, p.n_agents
    every_step = checkpoint is not None and checkpoint.every_step
    block = compiled_schedule(R, K, rec.wants_updates, every_step)
    largest = block = min(block, total)
    loop = numba_core.Loop(state, p, strategy, watch, tail, rec, block, streams.words, timeline)
    every = max(1, total // 200)  # progress of one-step calls
    i = first
    while i < total and state.active.any():
        began = time.perf_counter()
        streams.words()  # (the loop draws from them; a checkpoint caught the generators up)
        n = min(block, total - i)
        lanes = engine_threads.lanes(R, threads, R * K * n)
        taken, ends, up_int, up_float = loop.run(n, lanes)
        if compiled is not None:
            compiled()
            compiled = None
        rec.episode_rows(ends)
        rec.update_rows(up_int, up_float)
        i += taken
        seconds = time.perf_counter() - began
        if progress is not None and (block > 1 or i % every == 0):
            progress(i, total)
        if checkpoint is not None:
            checkpoint.tick(i, (state, strategy, watch, streams, rec, tail, timeline))
        if taken < n:
            break
        block = _next_block(block, taken, seconds, largest)
    return numba_core.SPEC_NAMES[loop.spec]


def check_finite(result: RunResult) -> None:
    """Raise :class:`ConfigError` if a Q-value became infinite or NaN during the run."""
    tables = result.strategy.tables()
    q = tables.get("q", np.zeros(0))
    if not np.isfinite(q).all():
        raise ConfigError(
            f"learning: {int((~np.isfinite(q)).sum()):,} Q-values became inf or NaN during the "
            "run; allowed: finite Q-values (lower learning.multiplier, learning.q_init.* or the "
            "reward.* values, or learning.gamma)"
        )


def write_run(
    result: RunResult, out: str | Path, replace: bool = False, meta: dict[str, Any] | None = None
) -> Path:
    """Write a run folder atomically: it appears complete or not at all.

    Files: ``config.yaml``, ``episodes.csv``, ``summary.json``, ``visits.npz``
    (``visits`` int64 ``[runs, agents, cells]``), for a learning strategy its tables
    (``q_table.npz``: ``q`` float64 and ``n`` int64, ``[runs, agents, cells, heading,
    action]``), ``meta.json`` (what
    made it: :mod:`qpatrol.util.provenance`, from ``meta`` or collected now), ``map.txt``
    (the map file used), and when recorded ``transitions.csv``, ``watch.csv`` and
    ``trajectory.csv`` and ``timeline.csv``, and last ``manifest.json`` (every file above
    with its size and hash, :mod:`qpatrol.util.manifest`). A run whose Q-values are not
    finite is not written (:func:`check_finite`). With ``replace`` an existing ``out`` is
    replaced only if qpatrol wrote it and it holds nothing else
    (:func:`qpatrol.run.outputs.check_replaceable`), and only its listed files are removed.
    """
    out = Path(out)
    check_finite(result)
    info = dict(meta) if meta is not None else provenance.collect()
    info["map"] = provenance.map_entry(result.map.text, result.map.name)
    info["engine"] = provenance.engine_entry(
        result.config["engine"], result.engine, result.loop, result.engine_note
    )
    config_text = result.config.to_yaml()

    def check(old: Path) -> None:  # once more, now that the run is done
        outputs.check_replaceable(old, ("run",), "--out", "run folder", shown=out)

    staged = atomic.staged_dir(out, replace=replace, check=check, discard=outputs.replace_written)
    with staged as tmp:
        (tmp / provenance.MAP_FILE).write_text(result.map.text, encoding="utf-8")
        (tmp / "config.yaml").write_text(config_text)
        (tmp / "episodes.csv").write_text(to_csv_text(result.episodes))
        summary = {
            "map": result.map.name,
            "cells": result.map.n_cells,
            "policy": result.config["policy"],
            "strategy": result.strategy.describe(),
            "runs": result.summary,
        }
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        tables = result.strategy.tables()
        if tables:
            _save_npz(tmp / "q_table.npz", **tables)
        _save_npz(tmp / "visits.npz", visits=result.measures.visits)
        if result.transitions is not None:
            (tmp / "transitions.csv").write_text(to_csv_text(result.transitions))
        if result.watch is not None:
            (tmp / "watch.csv").write_text(to_csv_text(result.watch))
        if result.trajectory is not None:
            (tmp / "trajectory.csv").write_text(to_csv_text(result.trajectory))
        if result.timeline is not None:
            (tmp / "timeline.csv").write_text(to_csv_text(result.timeline))
        (tmp / provenance.META_FILE).write_text(provenance.meta_text(info))
        digest = manifest.text_digest(config_text)
        manifest.seal(tmp, "run", config=digest, provenance=[provenance.META_FILE])
    return out


def train_checkpointer(
    cfg: Config,
    m: Map,
    folder: str | Path,
    every: float = DEFAULT_EVERY,
    info: dict[str, Any] | None = None,
) -> Checkpointer:
    """The checkpointer of ``qpatrol train``: saves in ``folder`` every ``every``
    seconds and on Ctrl-C/SIGTERM, and resumes only a checkpoint of the same resolved
    config, map file and qpatrol version."""
    from qpatrol import __version__

    key = {
        "config": cfg.digest(),
        "map": provenance.map_entry(m.text, m.name)["sha256"],
        "qpatrol": __version__,
    }
    return Checkpointer(folder, every=every, key=key, info=info)


def train(
    cfg: Config,
    out: str | Path,
    checkpoint: Checkpointer,
    prepared: tuple[Map, world.Params] | None = None,
    progress: Progress | None = None,
    meta: dict[str, Any] | None = None,
    replace: bool = False,
) -> RunResult:
    """What ``qpatrol train`` does once its arguments are checked (and ``qpatrol bench``
    times): :func:`simulate` with ``checkpoint`` (continued from the checkpoint it
    loaded, if any; SIGINT and SIGTERM make it save and stop), then :func:`write_run`
    to ``out``, then the checkpoint is discarded. The compiled loop runs in the blocks
    it runs in without a checkpointer (see :func:`compiled_schedule`).

    Raises:
        Interrupted: a signal stopped the run (the checkpoint is kept).
        ConfigError: the Q-values are not finite (nothing written, checkpoint gone);
        another error of the writing keeps the checkpoint.
    """
    with checkpoint.signals():
        result = simulate(cfg, progress=progress, prepared=prepared, checkpoint=checkpoint)
    try:
        write_run(result, out, replace=replace, meta=meta)
    except ConfigError:
        checkpoint.discard()  # resuming would give the same non-finite values
        raise
    checkpoint.discard()
    return result


def _save_npz(path: Path, **arrays: np.ndarray) -> None:
    """Uncompressed npz with fixed zip timestamps, so equal arrays give equal bytes."""
    import zipfile

    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.ascontiguousarray(arr), allow_pickle=False)


def default_out_dir(cfg: Config, config_path: str | Path | None = None) -> Path:
    """``results/runs/<config name>-<hash of the resolved config>``."""
    stem = Path(config_path).stem if config_path else "run"
    return Path("results") / "runs" / f"{stem}-{cfg.digest()}"
