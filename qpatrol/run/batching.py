"""Several sweep points in one batch: group them, run their runs together, split the result.

Points of a sweep whose resolved configs differ only in *per-run* keys
(:data:`PER_RUN_KEYS`: the seed, the learner's gamma, epsilon, multiplier and initial
Q values, the reward's weights) run as the rows of shared batches: a gamma sweep of 9
points x 30 runs is one batch of 270 rows, not 9 batches of 30. Row ``(p, r)`` (point
index p, run r) draws from ``SeedSequence(seed_p, spawn_key=(p, r))`` and reads its own
point's values (:func:`qpatrol.run.simulate_rows`), so its numbers are those it has when
its point runs alone; the batch's result is cut back into one
:class:`~qpatrol.run.RunResult` per point (:func:`split`, an inverse of
:func:`qpatrol.run.join`) and each point's folder is written as before, byte for byte.

Only points of a strategy that names its per-run arrays (``Strategy.per_run``: the
Q-learners) are grouped; points of other strategies run one at a time.

Rows of a group run in batches of at most :func:`qpatrol.world.limits.batch_runs` rows, point
after point (a point is written as soon as its last row is done). A group is one task
of the sweep's pool, cut by points into smaller tasks (:func:`tasks`) while its cost is
above the fair share ``total cost / workers``, so that ``jobs`` workers stay busy.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd

from qpatrol import world
from qpatrol.config import Config
from qpatrol.maps import Map
from qpatrol.run import RunResult, join, simulate_rows
from qpatrol.strategies import qlearning
from qpatrol.world import limits
from qpatrol.world.rng import RunKey

#: Config keys whose value may differ between the rows of one batch.
PER_RUN_KEYS: tuple[str, ...] = (
    "seed",
    *qlearning.Strategy.RUN_KEYS,
    *world.RUN_VALUE_FIELDS,
)


def group_key(cfg: Config) -> str | None:
    """What points must share to run in one batch: every config value but the per-run
    keys (as JSON); None for a strategy that cannot share a batch with another point."""
    from qpatrol.strategies import strategy_class

    if strategy_class(cfg["policy"]).per_run is None:
        return None
    rest = {k: v for k, v in cfg.values.items() if k not in PER_RUN_KEYS}
    return json.dumps(rest, sort_keys=True, default=str)


def groups(configs: Sequence[Config], tags: Sequence[Hashable] | None = None) -> list[list[int]]:
    """Indices of ``configs`` grouped by :func:`group_key` (and ``tags``: configs of
    different tags are never grouped), in order of first appearance; a config that
    cannot be grouped is a group of its own."""
    out: dict[Hashable, list[int]] = {}
    for i, cfg in enumerate(configs):
        key = group_key(cfg)
        tag = None if tags is None else tags[i]
        out.setdefault(("alone", i) if key is None else (tag, key), []).append(i)
    return list(out.values())


def tasks(grouped: list[list[int]], workers: int, cost: Sequence[float]) -> list[list[int]]:
    """The groups (indices, ``cost[i]`` each) cut, by points, into tasks for ``workers``
    workers: while a task of more than one point costs more than the fair share
    ``total / workers``, the costliest such task is cut in two halves (the first one
    the larger). One worker: the groups as they are."""
    out = [list(g) for g in grouped if g]
    if workers <= 1:
        return out
    fair = sum(cost[i] for g in out for i in g) / workers

    def total(t: list[int]) -> float:
        return sum(cost[i] for i in t)

    while True:
        big = [t for t in out if len(t) > 1 and total(t) > fair]
        if not big:
            return out
        t = max(big, key=total)
        i = out.index(t)
        half = (len(t) + 1) // 2
        out[i : i + 1] = [t[:half], t[half:]]


def row_values(cfgs: Sequence[Config]) -> dict[str, np.ndarray]:
    """float64 ``[R]`` per-run key -> each row's value, for the keys (but the seed) whose
    value differs between rows ``cfgs``."""
    out = {}
    for key in PER_RUN_KEYS[1:]:
        vals = [c[key] for c in cfgs]
        if any(v != vals[0] for v in vals):
            out[key] = np.array([float(v) for v in vals], dtype=np.float64)
    return out


@dataclass
class Piece:
    """Consecutive rows ``lo..hi-1`` of a batch that belong to one point."""

    cfg: Config
    lo: int
    hi: int
    runs: np.ndarray  # int [hi - lo], the point's run number of each row


def split(result: RunResult, pieces: Sequence[Piece]) -> list[RunResult]:
    """One result per piece of a batch (run with ``run_ids = 0..R-1``): its rows of the
    per-run arrays (world state, measures, the strategy's ``per_run`` arrays), of the
    tables and the summary, with the point's config and run numbers. The inverse of
    :func:`qpatrol.run.join`: written with :func:`qpatrol.run.write_run`, a piece gives
    the files its point's own batch of the same runs gives."""
    n = result.state.n_runs
    out = []
    for pc in pieces:
        rows = slice(pc.lo, pc.hi)
        out.append(
            RunResult(
                config=pc.cfg,
                map=result.map,
                params=_own_params(result.params, pc.cfg),
                state=_cut(result.state, n, rows),
                strategy=_cut_strategy(result.strategy, n, rows, pc.cfg),
                measures=_cut(result.measures, n, rows),
                run_ids=pc.runs.copy(),
                episodes=_table_rows(result.episodes, pc),
                transitions=_table_rows(result.transitions, pc),
                watch=_table_rows(result.watch, pc),
                trajectory=_table_rows(result.trajectory, pc),
                timeline=_table_rows(result.timeline, pc),
                summary=[
                    {**s, "run": int(pc.runs[s["run"] - pc.lo])}
                    for s in result.summary
                    if pc.lo <= s["run"] < pc.hi
                ],
                engine=result.engine,
                engine_note=result.engine_note,
                loop=result.loop,
            )
        )
    return out


def _own_params(p: world.Params, cfg: Config) -> world.Params:
    """``p`` with one point's reward weights (floats, as :func:`world.make_params`)."""
    return replace(p, **{name: float(cfg[key]) for key, name in world.RUN_VALUE_FIELDS.items()})


def _cut(obj: Any, n: int, rows: slice) -> Any:
    """A shallow copy of ``obj`` with rows ``rows`` of each array attribute whose first
    axis is the batch's ``n`` runs (every array of the world state and of the measures
    is per run)."""
    out = copy.copy(obj)
    for name, v in vars(obj).items():
        if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == n:
            setattr(out, name, v[rows])
    return out


def _cut_strategy(strategy: Any, n: int, rows: slice, cfg: Config) -> Any:
    """A shallow copy of ``strategy`` with rows ``rows`` of the arrays it names per run
    (``per_run``), and the point's ``cfg`` and per-run values."""
    out = copy.copy(strategy)
    out.cfg = cfg
    out.n_runs = rows.stop - rows.start
    out.use_run_values(None, table=False)
    for name in strategy.per_run or ():
        setattr(out, name, getattr(strategy, name)[rows])
    return out


def _table_rows(df: pd.DataFrame | None, pc: Piece) -> pd.DataFrame | None:
    """The rows of a table whose ``run`` (a batch row) is in the piece, renumbered to
    the point's runs (the order is kept: tables are ordered by run first)."""
    if df is None:
        return None
    run = df["run"].to_numpy()
    keep = (run >= pc.lo) & (run < pc.hi)
    out = df.loc[keep].reset_index(drop=True)
    out["run"] = pc.runs[run[keep] - pc.lo]
    return out


Write = Callable[[Any, RunResult], None]
Progress = Callable[[Any, int, int], None]


def run_group(
    items: Sequence[tuple[Any, int, Config]],
    m: Map,
    write: Write,
    progress: Progress | None = None,
) -> list[Any]:
    """Run the points of one group as shared batches and hand each finished point to
    ``write(point, result)``.

    Args:
        items: ``(point, point index p, config)`` of each point (same :func:`group_key`).
        m: the map.
        write: called once per point, with its whole result, as soon as its last run
            is done (points finish in order).
        progress: ``progress(point, steps done, steps total)`` of each point's runs.

    Returns the points written (all of them, unless a batch raised: the exception
    propagates, and the points not returned were not written).
    """
    rows = [(j, r) for j, (_, _, cfg) in enumerate(items) for r in range(cfg["runs"])]
    size = limits.batch_runs(items[0][2], m)
    parts: list[list[RunResult]] = [[] for _ in items]
    done_rows = [0] * len(items)
    written = []
    for lo in range(0, len(rows), size):
        chunk = rows[lo : lo + size]
        cfgs = [items[j][2] for j, _ in chunk]
        seeds = [RunKey(items[j][2]["seed"], items[j][1], r) for j, r in chunk]
        pieces, owners = [], []
        for i, (j, r) in enumerate(chunk):
            if not owners or owners[-1] != j:
                owners.append(j)
                pieces.append([i, i, []])
            pieces[-1][1] = i + 1
            pieces[-1][2].append(r)
        tick = None
        if progress is not None:
            tick = _ChunkProgress(progress, items, owners, pieces, done_rows)
        result = simulate_rows(
            cfgs[0],
            seeds,
            np.arange(len(chunk)),
            row_values(cfgs),
            (m, world.make_params(cfgs[0], m)),
            tick,
        )
        cut = split(
            result,
            [
                Piece(items[j][2], a, b, np.array(rs, dtype=np.int64))
                for j, (a, b, rs) in zip(owners, pieces, strict=True)
            ],
        )
        del result
        for j, part in zip(owners, cut, strict=True):
            parts[j].append(part)
            done_rows[j] += part.state.n_runs
            if done_rows[j] == items[j][2]["runs"]:
                write(items[j][0], join(parts[j]))
                parts[j] = []
                written.append(items[j][0])
    return written


@dataclass
class _ChunkProgress:
    """``progress(done, total)`` of one batch, told to each point with rows in it as
    the share of all its runs' steps done."""

    progress: Progress
    items: Sequence[tuple[Any, int, Config]]
    owners: list[int]
    pieces: list[list[Any]]
    done_rows: list[int]

    def __call__(self, done: int, total: int) -> None:
        for j, (a, b, _) in zip(self.owners, self.pieces, strict=True):
            point, _, cfg = self.items[j]
            self.progress(point, self.done_rows[j] * total + (b - a) * done, cfg["runs"] * total)
