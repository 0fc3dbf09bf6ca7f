"""``qpatrol bench``: agent-steps per second of a workload, next to a plain-Python loop.

Both run in the same process, the reference loop just before and just after the core,
so the ratio is meaningful on a noisy machine even when the absolute numbers are not
(and ``qpatrol bench`` says when the machine's speed changed under it). The workload
is ``runs`` runs of ``policy: qlearning`` teams of ``agents`` robots for ``steps`` team
steps on ``map`` (battery off unless ``--set battery.enabled=on``); the reference is
:func:`qpatrol.run.reference.run` on one run of the same map and team.
"""

from __future__ import annotations

import gc
import resource
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from qpatrol import engines, world
from qpatrol.config import Config, from_flat
from qpatrol.engines import threads as engine_threads
from qpatrol.maps import DIRECTIONS
from qpatrol.run import RunResult, prepare, reference, simulate
from qpatrol.world import limits
from qpatrol.world.rng import Streams, run_seeds

#: Most agent-steps the reference loop is timed over (it does ~0.3 M per second).
REFERENCE_BUDGET = 300_000


def default_steps(runs: int, agents: int, engine: str = "auto") -> int:
    """Team steps of a workload that takes about a second on the compiled engine, so
    that setting up the runs and writing their summaries weigh little: 20 M agent-steps
    there (1,000 to 20,000,000 steps), 1 M on numpy (400 to 20,000 steps), which
    ``auto`` takes when numba is missing. The numpy engine,
    :func:`qpatrol.engines.numpy_loop.advance` on every step, takes 0.6 to 9 s of CPU
    for that here: 0.7 s at 2,048 lone robots (488 steps), 4 s for one lone robot
    (20,000 steps, about 200 us a team step), 8.5 s for one team of 4 (about 430 us a
    team step)."""
    size = max(1, runs * agents)
    if engine == "numpy" or (engine == "auto" and not engines.numba_installed()):
        return min(20_000, max(400, 1_000_000 // size))
    return min(20_000_000, max(1_000, 20_000_000 // size))


def workload(
    runs: int,
    agents: int,
    steps: int,
    engine: str = "auto",
    map_name: str = "map_a",
    extra: dict[str, Any] | None = None,
    threads: int = 0,
) -> Config:
    """The config a bench runs (qlearning, battery off, no episode limit)."""
    flat = {
        "map": map_name,
        "agents": agents,
        "runs": runs,
        "steps": steps,
        "policy": "qlearning",
        "battery.enabled": False,
        "engine": engine,
        "threads": threads,
        "seed": 0,
    }
    flat.update(extra or {})
    return from_flat(flat)


def array_bytes_per_run(result: RunResult) -> int:
    """Bytes of the per-run arrays (world state, learner tables, measures) per run, as
    allocated (the part of :func:`qpatrol.world.limits.bytes_per_run` that is measurable)."""
    total = 0
    for obj in (result.state, result.strategy, result.measures):
        for v in vars(obj).values():
            if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == result.state.n_runs:
                total += v.nbytes
    return total // result.state.n_runs


@contextmanager
def no_gc() -> Iterator[None]:
    """Python's cyclic garbage collector off inside, as ``timeit`` times code: a full
    collection walks every object of the process (numba, pandas and matplotlib bring
    ~140,000), and when one happens depends on what the process did before, not on the
    code timed. Measured here: the reference loop's 300,000 agent-steps took 1.73 s with
    it on, 253 ms of which in six full collections, and 1.44 s with it off."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def time_core(cfg: Config) -> tuple[float, RunResult]:
    """``(seconds, result)`` of one :func:`qpatrol.run.simulate` of ``cfg`` (the map is
    loaded and the compiled engine warmed up beforehand, outside the timing)."""
    prepared = prepare(cfg)
    # the warm-up runs on the engine the workload will run on (under ``engine: auto``
    # its few steps alone would take the numpy engine, and the compiled loop would be
    # loaded from numba's cache, about 0.4 s, inside the timing)
    engine, _ = engines.choose(cfg)
    warm = cfg.replace(runs=1, steps=min(cfg["steps"], 50), engine=engine)
    simulate(warm, prepared=prepare(warm))
    with no_gc():
        t = time.perf_counter()
        result = simulate(cfg, prepared=prepared)
        seconds = time.perf_counter() - t
    return seconds, result


def time_train(cfg: Config) -> float:
    """Seconds of ``cfg`` end to end through ``qpatrol train``'s path
    (:func:`qpatrol.run.train`: the map loaded, the loop run with train's checkpointer,
    which saves every 60 s and on Ctrl-C, the run folder written into a temporary
    folder, the checkpoint discarded), with the garbage collector as train has it (on).
    The engine is warm (:func:`time_core` ran first)."""
    import shutil
    import tempfile
    from pathlib import Path

    from qpatrol.run import train, train_checkpointer
    from qpatrol.run.checkpoint import location

    tmp = Path(tempfile.mkdtemp(prefix="qpatrol-bench-"))
    try:
        out = tmp / "run"
        t = time.perf_counter()
        prepared = prepare(cfg)
        train(cfg, out, train_checkpointer(cfg, prepared[0], location(out)), prepared)
        return time.perf_counter() - t
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def time_reference(cfg: Config) -> tuple[float, int]:
    """``(seconds, agent-steps)`` of the plain-Python loop on run 0 of ``cfg``."""
    m, p = prepare(cfg)
    k = cfg["agents"]
    steps = max(1, min(cfg["steps"], REFERENCE_BUDGET // k))
    streams = Streams(run_seeds(cfg["seed"], 1), k)
    starts = world.place_agents(p, m, streams.generators[0]).tolist()
    u = streams.take(steps)[0]
    q_init = [cfg[f"learning.q_init.{d}"] * cfg["learning.multiplier"] for d in DIRECTIONS]
    use_heading = cfg["learning.state_space"] == "cell_heading"
    with no_gc():
        t = time.perf_counter()
        reference.run(
            p, starts, u, q_init, cfg["learning.gamma"], cfg["learning.epsilon"], use_heading
        )
        seconds = time.perf_counter() - t
    return seconds, steps * k


#: Largest change of the reference loop's speed between its two timings (before and
#: after the core) that :func:`report` takes in silence.
DRIFT_WARN = 0.2


def bench(cfg: Config) -> dict[str, Any]:
    """Time ``cfg`` and the reference loop; the numbers ``qpatrol bench`` prints.

    The reference loop is timed just before the core and just after it, and its rate is
    that of both timings together, so that a machine whose speed drifts (a shared one)
    weighs the same on both sides of the ratio; ``reference_drift`` is the relative
    change of its rate from the first timing to the second. Then the same workload is
    timed end to end as ``qpatrol train`` runs it (:func:`time_train`):
    ``train_seconds``, ``train_agent_steps_per_s`` and ``train_overhead`` (its time
    over the core's, minus 1: checkpointer, progress, map loading and the writing of
    the run folder). ``peak_rss_bytes`` is read before that timing (the core's)."""
    ref_before, ref_steps = time_reference(cfg)
    seconds, result = time_core(cfg)
    ref_after, _ = time_reference(cfg)
    agent_steps = int(result.state.steps_done.sum()) * cfg["agents"]
    rate = agent_steps / seconds
    ref_rate = 2 * ref_steps / (ref_before + ref_after)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    peak_bytes = peak if sys.platform == "darwin" else peak * 1024
    out = {
        "runs": cfg["runs"],
        "agents": cfg["agents"],
        "steps": cfg["steps"],
        "map": result.map.name,
        "engine": result.engine,
        "engine_note": result.engine_note,
        "loop": result.loop,
        "threads": used_threads(cfg, result),
        "seconds": seconds,
        "agent_steps": agent_steps,
        "agent_steps_per_s": rate,
        "reference_agent_steps_per_s": ref_rate,
        "reference_drift": ref_before / ref_after - 1.0,
        "gc_during_timings": False,
        "ratio": rate / ref_rate,
        "bytes_per_run": limits.bytes_per_run(cfg, result.map),
        "array_bytes_per_run": array_bytes_per_run(result),
        "batch_runs": min(cfg["runs"], limits.batch_runs(cfg, result.map)),
        "memory_limit_gib": cfg["memory.limit_gib"],
        "peak_rss_bytes": peak_bytes,
    }
    del result  # the train below allocates its own batch
    train_seconds = time_train(cfg)
    out["train_seconds"] = train_seconds
    out["train_agent_steps_per_s"] = agent_steps / train_seconds
    out["train_overhead"] = train_seconds / seconds - 1.0
    return out


def used_threads(cfg: Config, result: RunResult) -> int:
    """Threads the workload's batches could use: the compiled engine's lanes
    (:func:`qpatrol.engines.threads.resolve`, at most one per run), 1 on numpy."""
    if result.engine != "numba":
        return 1
    batch = min(cfg["runs"], limits.batch_runs(cfg, result.map))
    return min(engine_threads.resolve(cfg["threads"]), batch)


def report(b: dict[str, Any]) -> str:
    """The human-readable lines of a :func:`bench` result."""
    path = b["engine"] + (f" ({b['engine_note']})" if b["engine_note"] else "")
    loop = f" (loop {b['loop']})" if b.get("loop") else ""
    return "\n".join(
        [
            f"workload   {b['runs']} runs x {b['agents']} agents x {b['steps']} steps on "
            f"{b['map']}, engine {path}, {b['threads']} thread{'s' if b['threads'] > 1 else ''}"
            + loop,
            f"core       {b['agent_steps_per_s'] / 1e6:10.3f} M agent-steps/s "
            f"({b['seconds']:.2f} s)",
            f"reference  {b['reference_agent_steps_per_s'] / 1e6:10.3f} M agent-steps/s "
            "(plain Python, qpatrol/run/reference.py; before and after: "
            f"{b['reference_drift']:+.0%})",
            *(
                [
                    f"train      {b['train_agent_steps_per_s'] / 1e6:10.3f} M agent-steps/s "
                    f"({b['train_seconds']:.2f} s end to end as qpatrol train runs it, files "
                    f"written: {b['train_overhead']:+.0%} on the core)"
                ]
                if "train_seconds" in b
                else []
            ),
            f"ratio      {b['ratio']:10.2f} x"
            + ("" if b.get("gc_during_timings", True) else "  (both timed with gc off, as timeit)"),
            *(
                [
                    "warning    the machine's speed changed during the bench: the ratio is "
                    "uncertain, run it again"
                ]
                if abs(b["reference_drift"]) > DRIFT_WARN
                else []
            ),
            f"memory     {b['bytes_per_run']:,} bytes per run (estimate; arrays "
            f"{b['array_bytes_per_run']:,}), batches of {b['batch_runs']:,} runs under "
            f"{b['memory_limit_gib']:g} GiB; peak RSS {b['peak_rss_bytes'] / 2**20:,.0f} MiB",
        ]
    )
