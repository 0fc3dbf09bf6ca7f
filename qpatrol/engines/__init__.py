"""Engines: how the time loop of a batch is computed (never what it computes).

* ``numpy``: the reference, :func:`qpatrol.engines.numpy_loop.advance` step by step (every strategy,
  every setting, every recorder, checkpoints at any step).
* ``numba``: the compiled loop of :mod:`qpatrol.engines.numba_core` (numba, a core
  dependency), for the configs :func:`compiled_gap` accepts; any other config
  runs on the numpy engine and says so (:func:`choose` returns the reason).

Config key ``engine``: ``auto`` (numba when installed, for batches the numpy engine
would take more than :data:`AUTO_NUMPY_SECONDS` on, unless the compiled loop the batch
needs is not in numba's cache yet and the numpy engine would finish sooner than
compiling it: :mod:`qpatrol.engines.coldstart`), ``numpy`` or ``numba``. Every engine
writes the same files to the bit; ``meta.json`` records which one ran, and why.
"""

from __future__ import annotations

import importlib.util

import numpy as np

from qpatrol.config import Config, ConfigError
from qpatrol.engines.sizes import EVAP_POWERS_MAX


def numba_installed() -> bool:
    """True when the optional numba package can be imported."""
    return importlib.util.find_spec("numba") is not None


#: The strategies the compiled engine covers (each a file of
#: :mod:`qpatrol.engines.compiled`, listed in its ``MODULES``; kept here too so that
#: choosing an engine does not import numba).
COMPILED_POLICIES = (
    "qlearning",
    "qlearning-idleness",
    "random",
    "conscientious",
    "shared-conscientious",
    "evap",
    "cyclic",
    "partition",
    "hcr",
    "cc",
    "gbs",
    "sebs",
    "dta-greedy",
    "dta-ssi",
    "dta-ssi-part",
    "cbls",
    "learned-tour",
    "hpcc",
    "gravitational",
)


def compiled_gap(cfg: Config) -> str | None:
    """Why the compiled engine cannot run ``cfg`` (None: it can)."""
    if cfg["policy"] not in COMPILED_POLICIES:
        return f"policy {cfg['policy']} (compiled: {', '.join(COMPILED_POLICIES)})"
    if cfg["policy"] == "evap" and cfg["steps"] > EVAP_POWERS_MAX:
        keep = 1.0 - float(cfg["evap.evaporation"])
        if (keep ** np.arange(EVAP_POWERS_MAX + 1, dtype=np.int64))[-1] > 0.0:
            return (
                f"evap with evaporation {cfg['evap.evaporation']} over {cfg['steps']:,} steps "
                f"(the compiled table of pheromone powers stops at {EVAP_POWERS_MAX:,})"
            )
    return None


#: ``engine: auto`` runs a batch on numpy when the numpy engine would take less than
#: this many seconds of CPU on it (:func:`qpatrol.engines.coldstart.numpy_seconds`):
#: loading a compiled loop from numba's cache costs a fresh process about 0.65 s (a
#: 50-step `conscientious` run on map_a: 1.73 s on numba against 1.08 s on numpy, wall,
#: median of five pairs). Counted in agent-steps, as before (20,000), the rule sent a
#: sweep's 4,000-step points of one and two robots (8,000 and 16,000 agent-steps; those
#: not batched with other points) to numpy, about 1.5 s each against 0.07 s compiled.
AUTO_NUMPY_SECONDS = 0.5


def choose(cfg: Config, rows: int | None = None) -> tuple[str, str]:
    """``(engine, note)``: the engine that runs ``cfg``, and why when it is not the one
    asked for (empty note otherwise). Raises ConfigError for ``engine: numba`` without
    numba installed.

    Under ``engine: auto`` a batch whose compiled loop is not in numba's cache yet runs
    on numpy when numpy would finish sooner than the compile (note ``auto: compiled
    loop ... not cached yet``; :func:`qpatrol.engines.coldstart.cold_note`): this reads
    numba's cache (and imports numba). ``rows``: the batch's runs when not
    ``cfg['runs']`` (points of a sweep sharing a batch). :func:`choose_by_config` is
    the choice from the config alone."""
    engine, note = choose_by_config(cfg, rows)
    if engine == "numba" and cfg["engine"] == "auto":
        from qpatrol.engines import coldstart

        loop = _loop_of(cfg)
        cold = coldstart.cold_note(cfg, loop, rows)
        if cold is not None:
            return "numpy", cold
    return engine, note


def choose_by_config(cfg: Config, rows: int | None = None) -> tuple[str, str]:
    """:func:`choose` from the config alone (numba's cache unread: every loop taken as
    cached)."""
    asked = cfg["engine"]
    if asked == "numpy":
        return "numpy", ""
    if asked == "auto":
        from qpatrol.engines.coldstart import numpy_seconds

        est = numpy_seconds(cfg, rows)
        if est < AUTO_NUMPY_SECONDS:
            return "numpy", (
                f"auto: a small batch (numpy about {est:.2f} s < {AUTO_NUMPY_SECONDS} s)"
            )
    if not numba_installed():
        if asked == "numba":
            raise ConfigError(
                "engine: numba is not installed; allowed: engine=numpy or auto, or install "
                "numba (pip install numba)"
            )
        return "numpy", "numba not installed"
    gap = compiled_gap(cfg)
    if gap is not None:
        return "numpy", f"fallback from numba: {gap}"
    return "numba", ""


def compiled_loop(cfg: Config) -> str | None:
    """Which of the compiled engine's loops runs ``cfg``, each its own machine code,
    compiled on its first use (and then kept in numba's on-disk cache): ``"any"`` (any
    strategy, battery, timeline) or ``"qlearning"`` (Q-learning without battery or
    timeline, with Q-update recorders), ``"qlearning-solo"`` or ``"qlearning-team"``
    (without them); None when the numpy engine runs it. The choice
    :class:`qpatrol.engines.numba_core.Loop` makes from the prepared batch, read from
    the config (a test checks that they agree), so that a pool of workers can compile
    different loops at once (:mod:`qpatrol.study.sweep`).
    Read from the config alone (:func:`choose_by_config`: whether the loop is cached
    does not change which one it is)."""
    if choose_by_config(cfg)[0] != "numba":
        return None
    return _loop_of(cfg)


def _loop_of(cfg: Config) -> str:
    """:func:`compiled_loop` of a config the compiled engine runs."""
    if cfg["policy"] != "qlearning" or cfg["battery.enabled"] or cfg["record.timeline"]:
        return "any"
    if cfg["failures.robots"]:
        return "any"
    if cfg["record.transitions"] or cfg["record.watch"]:
        return "qlearning"
    return "qlearning-solo" if cfg["agents"] == 1 else "qlearning-team"
