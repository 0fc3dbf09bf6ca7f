"""Checks of a config against its map and the machine, before any work starts.

* ``record.watch`` must name states of the map.
* The memory a run needs is estimated from the world's and the strategy's arrays
  (:func:`bytes_per_run`: for Q-learning agents x cells x D x D Q-values and visit counts;
  dot maps, visit counts, the trajectory buffer, the Q-update log), plus what a batch
  needs whatever its runs (:func:`batch_bytes`: the stations' rows of moves, and the
  strategy's ``[C, C]`` distance table for the strategies that keep one).
* The strategies that keep that table (:data:`TABLE_POLICIES`) are refused on maps of
  more than :data:`qpatrol.maps.core.TABLE_CELLS` cells; ``cyclic`` there reads rows of
  moves searched per robot instead, and nothing else needs a table.
  :func:`qpatrol.run.simulate` computes the runs in consecutive batches of at most
  :func:`batch_runs` runs, so that a batch stays under ``memory.limit_gib``; a config
  whose batch still needs more than the machine has available is refused with one
  line naming runs, steps and map, instead of failing with a traceback (or swapping)
  later.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from qpatrol.config import Config, ConfigError
from qpatrol.maps import Map, core

#: Strategies that keep the map's ``[C, C]`` distance table (or build one for their walks
#: or regions): refused above ``TABLE_CELLS`` cells.
TABLE_POLICIES = (
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
#: Strategies that read distances per robot on a large map (rows of moves to a goal).
ROW_POLICIES = ("cyclic",)

#: Memory of the Python process before any array (interpreter, numpy, pandas).
BASE_BYTES = 200 * 2**20
#: Bytes per Q-update row kept in memory by ``record.transitions`` (columns and tables).
ROW_BYTES = 17 * 8 * 2


#: ``learning.table: auto`` keeps Q-tables lazily when one run's dense tables (``q``
#: float64 and ``n`` int32) would take more bytes than this.
LAZY_BYTES = 256 * 2**20


def table_rows(cfg: Config, n_cells: int, n_agents: int, n_ports: int) -> int:
    """The rows of each ``qlearning`` robot's table: ``C`` (dense), or, kept lazily
    (``learning.table``), ``steps + 2`` when fewer: a robot stands in at most one new
    cell a step, and in one before the first."""
    mode = cfg["learning.table"]
    dense_bytes = n_agents * n_cells * n_ports * n_ports * 12
    if mode == "dense" or (mode == "auto" and dense_bytes <= LAZY_BYTES):
        return n_cells
    return min(n_cells, int(cfg["steps"]) + 2)


def q_table_bytes(cfg: Config, m: Map, entry_bytes: int) -> int:
    """Bytes of one run's ``qlearning`` tables at ``entry_bytes`` a value: the rows of
    :func:`table_rows` and, kept lazily, each robot's int32 row of every cell."""
    k, c, d = cfg["agents"], m.n_cells, m.n_ports
    rows = table_rows(cfg, c, k, d)
    return k * rows * d * d * entry_bytes + (k * (c + 1) * 4 if rows < c else 0)


@dataclass(frozen=True)
class Estimate:
    """Bytes a batch needs: ``total``, and the part taken by the distance table."""

    total: int
    distances: int


def bytes_per_run(cfg: Config, m: Map) -> int:
    """Estimated bytes one run adds to a batch of ``cfg`` on ``m``: the world state, the
    strategy's tables (Q-learning: ``q`` float64 and ``n`` int32, ``[agents, rows, D,
    D]``, D = 4 on a grid, :func:`table_rows`), the measures (the intruder measures'
    per-cell counts among them) and the recorders (trajectory ring, timeline, Q-update
    rows)."""
    k, c, d = cfg["agents"], m.n_cells, m.n_ports
    g = 1 if cfg["team.communication"] else k
    policy = cfg["policy"]
    strategy = {
        "qlearning": q_table_bytes(cfg, m, 8 + 4),  # q float64 and n int32
        "conscientious": k * c * 8,  # each robot's memory
        "evap": 2 * g * c * 8,  # pheromone and its time stamp
        # q float64 and n int32 (one table, or one per robot), its own last-visit and
        # dot maps
        "qlearning-idleness": k * c * d**3 * (8 + 4) + g * c * 9,
    }.get(policy, 0)
    if policy in ROW_POLICIES and c > core.TABLE_CELLS:  # each robot's row, the run's queue
        strategy += (k + 1) * c * 8 * 2  # the numpy and the compiled copy
    rows = cfg["steps"] * k if cfg["record.transitions"] else 0
    intruders = intruder_bytes(cfg, m)
    timeline = 0
    if cfg["record.timeline"]:  # one row per window, and the window's accumulators
        timeline = (cfg["steps"] // cfg["record.timeline"] + 1) * 6 * 8 + c * 8
    return (
        strategy
        + g * c * (1 + 8 + 1 + d)  # dots, last visit, cells and states seen this episode
        + 2 * c * 8  # cell occupancy, measures' last visits
        + 2 * c * 8  # measures' interval sums and counts by target
        + 2 * k * c * 8  # visits, window visits
        + (12 * k + 31) * 8  # positions, headings, battery, episode and measure counters
        + 512 * k * 2 * 8  # block of uniforms
        + cfg["record.trajectory"] * k * 8
        + timeline
        + intruders
        + rows * ROW_BYTES
    )


def intruder_bytes(cfg: Config, m: Map) -> int:
    """Bytes of one run's intruder measures: per cell, when it emptied (or the robots
    on it), its departures by gap bucket and, near the horizon, per duration; per run
    the empty stretches by gap bucket and the random intruders missed (``auto``: 5
    durations)."""
    setting = cfg["security.attack_steps"]
    a = 5 if setting == "auto" else len(setting)
    return (8 * m.n_cells + 4 * m.n_cells * (3 * a + 1) + 8 * (4 * a + 2)) if a else 0


def batch_bytes(cfg: Config, m: Map) -> int:
    """Estimated bytes of a batch that do not grow with its runs: the distance table (of
    the strategies that keep one, and its compiled copy), the stations' rows, and the
    compiled engine's block of uniforms (up to 16 MiB)."""
    return table_bytes(cfg, m) + 2 * len(m.homes) * m.n_cells * 8 + 16 * 2**20


def table_bytes(cfg: Config, m: Map) -> int:
    """Bytes of the ``[C, C]`` distance table a strategy keeps (0 for the others)."""
    keeps = cfg["policy"] in TABLE_POLICIES or (
        cfg["policy"] in ROW_POLICIES and m.n_cells <= core.TABLE_CELLS
    )
    return 2 * m.n_cells * m.n_cells * 8 if keeps else 0


def batch_runs(cfg: Config, m: Map) -> int:
    """Most runs of ``cfg`` per batch whose estimate (:func:`batch_bytes` + runs x
    :func:`bytes_per_run`) stays under ``memory.limit_gib`` (at least 1)."""
    limit = cfg["memory.limit_gib"] * 2**30
    return max(1, int((limit - batch_bytes(cfg, m)) // bytes_per_run(cfg, m)))


def kept_bytes_per_run(cfg: Config, m: Map) -> int:
    """Estimated bytes of one run's results kept until its folder is written, whatever
    the batches: the learner's tables (``n`` also as the int64 written to
    ``q_table.npz``), visit counts, recorded rows and the summary."""
    k, c, d = cfg["agents"], m.n_cells, m.n_ports
    tables = {
        "qlearning": q_table_bytes(cfg, m, 8 + 4 + 8),
        "qlearning-idleness": k * c * d**3 * (8 + 4 + 8),
    }.get(cfg["policy"], 0)
    rows = cfg["steps"] * k if cfg["record.transitions"] else 0
    intruders = intruder_bytes(cfg, m)
    windows = cfg["steps"] // cfg["record.timeline"] + 1 if cfg["record.timeline"] else 0
    return (
        tables
        + k * c * 8  # visits
        + 2 * c * 8  # the measures' interval sums and counts by target
        + intruders
        + cfg["record.trajectory"] * k * 6 * 8
        + windows * 6 * 8
        + rows * ROW_BYTES
        + 4096  # summary
    )


def estimate_memory(cfg: Config, m: Map) -> Estimate:
    """Estimated peak memory (bytes) of simulating ``cfg`` on ``m`` in batches of at most
    :func:`batch_runs` runs: one batch's arrays and the results of all runs."""
    r = min(cfg["runs"], batch_runs(cfg, m))
    dist = table_bytes(cfg, m)
    total = (
        BASE_BYTES
        + batch_bytes(cfg, m)
        + r * bytes_per_run(cfg, m)
        + cfg["runs"] * kept_bytes_per_run(cfg, m)
    )
    return Estimate(total, dist)


def available_memory() -> int | None:
    """Bytes of memory available to a new process (MemAvailable), or None if unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _gib(x: float) -> str:
    return f"{x / 2**30:.3g} GiB"


def check_config_on_map(cfg: Config, m: Map, available: int | None = None) -> None:
    """Raise :class:`ConfigError` (one line) if ``cfg`` does not fit ``m`` or the machine."""
    bad = [s for s in cfg["record.watch"] if s >= m.n_cells]
    if bad:
        raise ConfigError(
            f"record.watch: got {bad}; allowed: states 0 to {m.n_cells - 1} of map {m.name} "
            "(`qpatrol maps show` numbers them)"
        )
    if cfg["policy"] in TABLE_POLICIES and m.n_cells > core.TABLE_CELLS:
        raise ConfigError(
            f"policy: {cfg['policy']} keeps a cells x cells table of distances, and map "
            f"{m.name} has {m.n_cells:,} cells (allowed: at most {core.TABLE_CELLS:,}); on larger "
            "maps use cyclic, qlearning, qlearning-idleness, conscientious, "
            "shared-conscientious, evap or random, or a map of fewer cells (a larger --cell "
            "or --edge-step when importing)"
        )
    need = estimate_memory(cfg, m)
    have = available if available is not None else available_memory()
    if have is not None and need.total > have:
        why = ""
        if need.distances > need.total / 2:
            why = f", mostly the distance table of its {m.n_cells:,} cells"
        raise ConfigError(
            f"memory: runs={cfg['runs']}, steps={cfg['steps']}, agents={cfg['agents']} on map "
            f"{m.name} ({m.n_cells:,} cells) need about {_gib(need.total)}{why}; this machine "
            f"has {_gib(have)} available; lower runs (a sweep can split them) or use a "
            "smaller map"
        )


def cores() -> int:
    """CPU cores this process may use (what ``--jobs -1`` means)."""
    try:
        from joblib import cpu_count

        return max(1, int(cpu_count()))
    except Exception:  # joblib missing or confused: fall back to the OS count
        return max(1, os.cpu_count() or 1)


def check_jobs(jobs: object, label: str = "jobs") -> int:
    """Validate a worker count: -1 (all cores) or 1 to the number of cores; returns it."""
    n = cores()
    if isinstance(jobs, bool) or not isinstance(jobs, int) or not (jobs == -1 or 1 <= jobs <= n):
        raise ConfigError(
            f"{label}: got {jobs!r}; allowed: -1 (all cores) or an integer from 1 to {n} "
            "(the cores of this machine)"
        )
    return jobs
