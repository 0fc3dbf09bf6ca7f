"""Figure data: experiment folders in, one tidy table per figure out.

Each ``*_data`` function reads run folders (as written by :func:`qpatrol.run.write_run`)
or sweep folders (``sweep.json``, ``points/<id>/``, ``results.csv``) and returns the
``pandas.DataFrame`` that is written as CSV beside the figure; the plotting functions
of :mod:`qpatrol.study.plots` read only that CSV. :func:`trajectory` is the one piece that
simulates instead of reading: the positions of Fig. 5 are not kept in run folders.

Conventions of the figure tables: directions (``heading``, ``action``) are written as
letters N, E, S, W; ``heading`` is the direction of the move that brought the agent
to the cell (the Q-table's state is ``(cell, heading)``). Intervals are two-sided
95% Student-t intervals of the mean over runs, ``mean +- t(0.975, n-1) * sd / sqrt(n)``
(:func:`mean_ci`); with one run they are NaN.

Which heading the Q-value figures follow (Fig. 2, 3, 4)
    The paper plots "Q values for west and east options in state 34" as one series, but
    the Q-table has one row per arrival heading, and the rows evolve independently. We
    follow the row of the *east* heading, the orientation the paper names ("when each
    state is reached with east orientation", §4; also how docs/model.md states the
    map facts): there West goes back one way and East on the other way, the W/E choice the
    paper discusses. If that row has fewer than the requested updates, we fall back
    to the heading with the most updates (for Fig. 2, the one whose fewest updates
    over the multipliers is largest, so all panels follow the same row). The chosen
    heading is a column of the table.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from qpatrol import strategies, world
from qpatrol.config import Config, from_mapping, load_config
from qpatrol.engines.numpy_loop import advance
from qpatrol.maps import DIR_LETTERS, EAST, Map, get_map, parse_map
from qpatrol.maps.tours import dot_walk_lower_bound, dot_walk_tour
from qpatrol.measures import FIELD_MEASURES
from qpatrol.run import prepare
from qpatrol.strategies.qlearning import dense_tables
from qpatrol.study.sweep import FIELD_INTERACTIONS
from qpatrol.util.csvio import read_csv
from qpatrol.util.provenance import MAP_FILE, read_meta
from qpatrol.world.battery import MODE_NAMES
from qpatrol.world.rng import Streams, run_seeds

__all__ = [
    "figure2_data",
    "figure34_data",
    "figure5_data",
    "figure6_data",
    "folder_map",
    "gamma_data",
    "mean_ci",
    "read_sweep",
    "t_quantile",
    "team_size_data",
    "trajectory",
]


# --- statistics ---------------------------------------------------------------------


def _betacf(a: float, b: float, x: float) -> float:
    """Continued fraction of the incomplete beta function (modified Lentz)."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 500):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return h


def _betainc(a: float, b: float, x: float) -> float:
    """Regularized incomplete beta ``I_x(a, b)``."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    ln = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x)
    ln += b * math.log1p(-x)
    front = math.exp(ln)
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _betacf(a, b, x) / a
    return 1.0 - front * _betacf(b, a, 1.0 - x) / b


def _t_cdf(t: float, df: float) -> float:
    tail = 0.5 * _betainc(df / 2.0, 0.5, df / (df + t * t))
    return 1.0 - tail if t >= 0 else tail


@functools.lru_cache(maxsize=1024)
def t_quantile(p: float, df: float) -> float:
    """Quantile of Student's t distribution (bisection on the CDF; no SciPy needed;
    remembered, as a figure asks the same few thousands of times)."""
    if not 0.0 < p < 1.0 or df <= 0:
        raise ValueError(f"t_quantile: need 0 < p < 1 and df > 0, got p={p}, df={df}")
    if p < 0.5:
        return -t_quantile(1.0 - p, df)
    lo, hi = 0.0, 1.0
    while _t_cdf(hi, df) < p:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _t_cdf(mid, df) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-12 * max(1.0, hi):
            break
    return 0.5 * (lo + hi)


def mean_ci(values: Iterable[float], level: float = 0.95) -> dict[str, float]:
    """``{mean, lo, hi, n}``: Student-t interval of the mean of the finite values.

    ``lo, hi = mean -+ t((1 + level) / 2, n - 1) * sd / sqrt(n)`` with the sample sd
    (ddof 1); NaN bounds for n < 2, all NaN for n = 0.
    """
    x = np.asarray([v for v in values if v is not None], dtype=np.float64)
    x = x[np.isfinite(x)]
    n = int(x.size)
    if n == 0:
        return {"mean": math.nan, "lo": math.nan, "hi": math.nan, "n": 0}
    mean = float(x.mean())
    if n < 2:
        return {"mean": mean, "lo": math.nan, "hi": math.nan, "n": n}
    half = t_quantile((1.0 + level) / 2.0, n - 1) * float(x.std(ddof=1)) / math.sqrt(n)
    return {"mean": mean, "lo": mean - half, "hi": mean + half, "n": n}


# --- reading experiment folders ----------------------------------------------------


def read_sweep(sweep_dir: str | Path) -> pd.DataFrame:
    """One row per sweep point: ``index``, ``id``, ``path``, ``overrides``, ``config``.

    ``config`` is the point's resolved :class:`~qpatrol.config.Config`: its
    ``config.yaml`` if the point folder exists, else ``sweep.json``'s base with the
    point's overrides.
    """
    d = Path(sweep_dir)
    spec_path = d / "sweep.json"
    if not spec_path.is_file():
        raise FileNotFoundError(f"{d}: no sweep.json (not a sweep folder)")
    spec = json.loads(spec_path.read_text())
    base = from_mapping(spec.get("base") or {})
    rows = []
    for pt in spec["points"]:
        path = d / "points" / pt["id"]
        overrides = pt.get("overrides") or {}
        if (path / "config.yaml").is_file():
            cfg = load_config(path / "config.yaml")
        else:
            cfg = base.replace(**overrides)
        rows.append(
            {
                "index": int(pt["index"]),
                "id": pt["id"],
                "path": path,
                "overrides": overrides,
                "config": cfg,
            }
        )
    return pd.DataFrame(rows).sort_values("index", kind="stable").reset_index(drop=True)


def _read_csv(path: Path, what: str) -> pd.DataFrame:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing ({what})")
    return read_csv(path)


def _run_config(run_dir: Path) -> Config:
    return load_config(Path(run_dir) / "config.yaml")


def folder_map(folder: str | Path, cfg: Config | None = None) -> Map:
    """The map a run folder was made on: its copy ``map.txt`` (named as ``meta.json``
    says), or, for a folder written before qpatrol kept that copy, the map its config
    names, looked up now."""
    d = Path(folder)
    copy = d / MAP_FILE
    if copy.is_file():
        m = parse_map(copy.read_text(encoding="utf-8"), source=str(copy))
        name = ((read_meta(d) or {}).get("map") or {}).get("name")
        return dataclasses.replace(m, name=name) if name else m
    return get_map((cfg if cfg is not None else _run_config(d))["map"])


def _heading_index(heading: int | str) -> int:
    if isinstance(heading, str):
        h = heading.strip().upper()[:1]
        if h not in DIR_LETTERS:
            raise ValueError(f"heading: {heading!r} is not one of N, E, S, W")
        return DIR_LETTERS.index(h)
    return int(heading)


def choose_heading(counts: list[dict[int, int]], wanted: int, prefer: int = EAST) -> int:
    """The heading to follow, given update counts per heading of one or more series.

    ``prefer`` if every series has at least ``wanted`` updates there; otherwise the
    heading whose smallest count over the series is largest (ties: ``prefer``, then
    N, E, S, W).
    """

    def low(h: int) -> int:
        return min(c.get(h, 0) for c in counts) if counts else 0

    if counts and low(prefer) >= wanted:
        return prefer
    order = [prefer] + [h for h in range(4) if h != prefer]
    return max(order, key=lambda h: (low(h), -order.index(h)))


def _watched(run_dir: Path, cell: int, run: int, agent: int) -> tuple[pd.DataFrame, Config]:
    cfg = _run_config(run_dir)
    w = _read_csv(run_dir / "watch.csv", f"Q-updates of watched states; set record.watch: [{cell}]")
    if cell not in cfg["record.watch"] and not cfg["record.transitions"]:
        raise ValueError(f"{run_dir}: state {cell} was not watched (record.watch)")
    w = w[(w["cell"] == cell) & (w["run"] == run) & (w["agent"] == agent)]
    return w.sort_values("step", kind="stable"), cfg


def _first_updates(w: pd.DataFrame, heading: int, n: int) -> pd.DataFrame:
    out = w[w["heading"] == heading].head(n).reset_index(drop=True)
    out.insert(0, "update", np.arange(1, len(out) + 1))
    return out


def _letters(x: pd.Series) -> pd.Series:
    return x.astype(int).map(lambda i: DIR_LETTERS[i])


# --- Fig. 2 --------------------------------------------------------------------------


def figure2_data(
    sweep_dir: str | Path,
    cell: int = 34,
    n_updates: int = 100,
    heading: int | str = "auto",
    run: int = 0,
    agent: int = 0,
    key: str = "learning.multiplier",
) -> pd.DataFrame:
    """Fig. 2: Q(cell, West) and Q(cell, East) over the first updates, per multiplier.

    From a sweep over ``key`` (multiplier 1, 10, 100, 1000 on map B, one agent,
    ``record.watch: [34]``): for each point, the first ``n_updates`` Q-updates of state
    ``cell`` at one heading (module docstring; ``"auto"`` = east, else the best
    common fallback) in run ``run``. ``q_west``/``q_east`` are the Q-row *after* each
    update. Columns: multiplier, update, step, heading, action, reward, q_west, q_east,
    q_north, q_south, run, cell, map.
    """
    points = read_sweep(sweep_dir)
    series = []
    for _, pt in points.iterrows():
        w, cfg = _watched(pt["path"], cell, run, agent)
        series.append((cfg, w, folder_map(pt["path"], cfg).name))
    if heading == "auto":
        counts = [w.groupby("heading").size().to_dict() for _, w, _ in series]
        h = choose_heading(counts, n_updates)
    else:
        h = _heading_index(heading)
    parts = []
    for cfg, w, map_name in series:
        f = _first_updates(w, h, n_updates)
        f.insert(0, "multiplier", cfg[key])
        f["map"] = map_name
        parts.append(f)
    df = pd.concat(parts, ignore_index=True)
    df["heading"] = _letters(df["heading"])
    df["action"] = _letters(df["action"])
    cols = [
        "multiplier",
        "update",
        "step",
        "heading",
        "action",
        "reward",
        "q_west",
        "q_east",
        "q_north",
        "q_south",
        "run",
        "cell",
        "map",
    ]
    return df[cols].sort_values(["multiplier", "update"], kind="stable").reset_index(drop=True)


# --- Fig. 3 and 4 --------------------------------------------------------------------


def figure34_data(
    run_dir: str | Path,
    cell: int,
    n_updates: int = 100,
    heading: int | str = "auto",
    run: int = 0,
    agent: int = 0,
) -> pd.DataFrame:
    """Fig. 3 (state 13, map A) / Fig. 4 (state 34, map B): r, gamma max Q(s',.), Q W/E.

    The first ``n_updates`` Q-updates of state ``cell`` at one heading (module
    docstring) in run ``run`` of a run folder with ``record.watch`` holding ``cell``.
    ``bootstrap`` is ``gamma * max_a Q(s', a)`` over the legal actions of s';
    ``q_west``/``q_east`` are the Q-row after the update; ``dot`` is 1 where a dot was
    eaten on entering s'. Columns: update, step, heading, action, reward, dot,
    bootstrap, q_west, q_east, next_cell, alpha, run, cell, map, gamma.
    """
    w, cfg = _watched(Path(run_dir), cell, run, agent)
    if heading == "auto":
        h = choose_heading([w.groupby("heading").size().to_dict()], n_updates)
    else:
        h = _heading_index(heading)
    f = _first_updates(w, h, n_updates)
    f["heading"] = _letters(f["heading"])
    f["action"] = _letters(f["action"])
    f["map"] = folder_map(run_dir, cfg).name
    f["gamma"] = cfg["learning.gamma"]
    cols = [
        "update",
        "step",
        "heading",
        "action",
        "reward",
        "dot",
        "bootstrap",
        "q_west",
        "q_east",
        "next_cell",
        "alpha",
        "run",
        "cell",
        "map",
        "gamma",
    ]
    return f[cols]


# --- gamma (§4) ------------------------------------------------------------------------


def _first_episodes(run_dir: Path) -> pd.DataFrame:
    """Per run, the first ended episode of group 0 (agent 0's dot map)."""
    ep = _read_csv(run_dir / "episodes.csv", "episodes")
    ep = ep[ep["group"] == 0].sort_values(["run", "episode"], kind="stable")
    return ep.groupby("run", sort=True).head(1).set_index("run")


def gamma_data(
    sweep_dir: str | Path,
    map: str | Map | None = None,
    key: str = "learning.gamma",
    level: float = 0.95,
) -> pd.DataFrame:
    """§4 gamma: the first episode per gamma against the shortest dot-eating walk.

    For each point of a sweep over ``key`` (one agent on map A, gamma 0.1..0.9), over
    its runs: the mean and 95% Student-t interval (:func:`mean_ci`) of the first
    episode's ``steps`` (team steps until every dot is eaten), ``distinct_states``
    ((cell, heading) pairs entered) and ``distinct_cells``. Only *complete* first
    episodes enter the ``steps`` statistics (``n`` of them; a truncated one is only a
    lower bound), while the exploration counts are over every ended first episode,
    truncated ones included; ``truncated`` counts first episodes cut by
    ``max_episode_steps`` and ``unfinished`` the runs (of the config's ``runs``) with no
    ended first episode (they stopped before it ended, or are missing).
    ``lower_bound`` and ``tour`` (:mod:`qpatrol.maps.tours`) bracket the shortest walk
    eating every dot from the map's start cell 0 (``map`` overrides the points'
    map). ``cells``, ``states`` and ``dots`` count the map's free cells,
    its (cell, arrival heading) pairs and its dot cells;
    ``steps_min``/``steps_median`` are over the complete first episodes too.
    """
    points = read_sweep(sweep_dir)
    refs: dict[str, tuple[Map, int, int]] = {}

    def reference(name: str | Map) -> tuple[Map, int, int]:
        m = name if isinstance(name, Map) else get_map(name)
        if m.name not in refs:
            start = int(m.starts[0]) if m.starts.size else 0
            tour, _ = dot_walk_tour(m, start)
            refs[m.name] = (m, dot_walk_lower_bound(m, start, upper=tour), tour)
        return refs[m.name]

    rows = []
    for _, pt in points.iterrows():
        cfg = pt["config"]
        first = _first_episodes(pt["path"])
        runs = int(cfg["runs"])
        done = first[first["complete"] == 1]
        m, lb, tour = reference(map if map is not None else folder_map(pt["path"], cfg))
        row: dict[str, Any] = {key.split(".")[-1]: cfg[key], "runs": runs}
        for col in ("steps", "distinct_states", "distinct_cells"):
            ci = mean_ci((done if col == "steps" else first)[col], level)
            row.update({f"{col}_mean": ci["mean"], f"{col}_lo": ci["lo"], f"{col}_hi": ci["hi"]})
        row.update(
            {
                "n": len(done),
                "truncated": int((first["complete"] == 0).sum()),
                "unfinished": runs - len(first),
                "max_episode_steps": cfg["max_episode_steps"] or math.nan,
                "steps_min": float(done["steps"].min()) if len(done) else math.nan,
                "steps_median": float(done["steps"].median()) if len(done) else math.nan,
                "lower_bound": lb,
                "tour": tour,
                "cells": m.n_cells,
                "states": int(m.degree.sum()),
                "dots": int((m.dot_kind > 0).sum()),
                "map": m.name,
            }
        )
        rows.append(row)
    return pd.DataFrame(rows)


# --- team size and communication ---------------------------------------------------------

TEAM_MEASURES = (
    "mean_steps_per_episode",
    "division_of_labour",
    "avg_idleness",
    "worst_idleness",
    "max_wait",
)
STRATEGY_MEASURES = ("avg_idleness", "worst_idleness", "mean_interval", "max_wait")


def team_size_data(
    sweep_dir: str | Path, level: float = 0.95, measures: Iterable[str] = TEAM_MEASURES
) -> pd.DataFrame:
    """Team size x communication: mean and 95% t-interval over runs of each measure.

    From a sweep over ``agents`` (and ``team.communication``), read ``results.csv``
    (one row per point and run). Points that share agents, communication and every
    other swept key are pooled. Columns: agents, communication, (other swept keys),
    runs, ``frozen`` (runs whose ``max_stall`` exceeds ``stall_bound``), and per measure
    ``<measure>_mean``, ``_lo``, ``_hi``, ``_n`` (runs with a value:
    ``mean_steps_per_episode`` is empty for a run without a complete episode),
    ``max_wait_max``, ``max_stall_max``, map. Without communication each agent has its own dot
    map, so an episode is one agent eating all of its private dots.
    """
    keys = {"agents": int, "communication": bool}
    return grouped_data(sweep_dir, keys, measures, level)


def strategies_data(
    sweep_dir: str | Path, level: float = 0.95, measures: Iterable[str] = STRATEGY_MEASURES
) -> pd.DataFrame:
    """Strategy x team size: mean and 95% t-interval over runs of each measure.

    As :func:`team_size_data`, grouped by ``policy`` and ``agents``, plus
    ``walk_length`` and ``walk_lower_bound`` (the cyclic strategy's closed walk L and a
    proven lower bound on any closed walk through every cell) and ``bound_per_robot``
    = L / K, the idleness interval of K robots evenly spaced on that walk.
    """
    df = grouped_data(sweep_dir, {"policy": str, "agents": int}, measures, level)
    walks = _walks(read_sweep(Path(sweep_dir)))
    walk, bound = next(iter(walks.values()), (None, None))
    df["walk_length"] = walk
    df["walk_lower_bound"] = bound
    df["bound_per_robot"] = [walk / k if walk else None for k in df["agents"]]
    return df


def _walks(sw: pd.DataFrame, names: list[str] | None = None) -> dict[str, tuple[Any, Any]]:
    """Map name -> (walk_length, walk_lower_bound) of the cyclic strategy's closed walk,
    from the summary of the first cyclic point on each map of a sweep (``names``: the
    map name of each point, if already known)."""
    names = names or [folder_map(p, c).name for p, c in zip(sw["path"], sw["config"], strict=True)]
    walks: dict[str, tuple[Any, Any]] = {}
    for path, cfg, name in zip(sw["path"], sw["config"], names, strict=True):
        summary = Path(path) / "summary.json"
        if cfg["policy"] == "cyclic" and name not in walks and summary.is_file():
            info = json.loads(summary.read_text()).get("strategy", {})
            walks[name] = (info.get("walk_length"), info.get("walk_lower_bound"))
    return walks


POLICY_MEASURES = (
    "avg_idleness",
    "worst_idleness",
    "mean_interval",
    "max_wait",
    "coverage",
    "episodes_truncated",
)


def policies_data(
    sweep_dir: str | Path,
    level: float = 0.95,
    measures: Iterable[str] = POLICY_MEASURES,
    by_interaction: bool = False,
) -> pd.DataFrame:
    """Map x strategy x team size: mean and 95% t-interval over runs of each measure.

    As :func:`strategies_data`, grouped by ``map``, ``policy`` and ``agents`` (and
    ``interaction``, how robots meet, with ``by_interaction``), with each map's closed
    walk: ``walk_length`` L and ``walk_lower_bound`` (from the cyclic strategy's summary
    on that map) and ``bound_per_robot`` = L / K. Also ``warmup`` and ``window`` (team
    steps measured) of each group, and ``learns`` (the strategy learns as it patrols).
    """
    keys: dict[str, type] = {"policy": str, "agents": int}
    if by_interaction:
        keys["interaction"] = str
    df = grouped_data(sweep_dir, keys, measures, level)
    sw = read_sweep(Path(sweep_dir))
    names = [folder_map(p, c).name for p, c in zip(sw["path"], sw["config"], strict=True)]
    walks = _walks(sw, names)
    steps = {
        (name, cfg["policy"], int(cfg["agents"])): (
            int(cfg["record.warmup"]),
            int(cfg["steps"]) - int(cfg["record.warmup"]),
        )
        for name, cfg in zip(names, sw["config"], strict=True)
    }
    df["walk_length"] = [walks.get(m, (None, None))[0] for m in df["map"]]
    df["walk_lower_bound"] = [walks.get(m, (None, None))[1] for m in df["map"]]
    df["bound_per_robot"] = [
        w / k if w else None for w, k in zip(df["walk_length"], df["agents"], strict=True)
    ]
    key = list(zip(df["map"], df["policy"], df["agents"], strict=True))
    df["warmup"] = [steps[k][0] for k in key]
    df["window"] = [steps[k][1] for k in key]
    df["learns"] = [strategies.learns(p) for p in df["policy"]]
    order = {m: i for i, m in enumerate(dict.fromkeys(names))}
    df["_order"] = [order.get(m, len(order)) for m in df["map"]]
    names = {n: i for i, n in enumerate(strategies.NAMES)}
    df["_policy"] = [names.get(p, len(names)) for p in df["policy"]]
    by = ["_order", "agents", "_policy"]
    if by_interaction:  # the field's interactions in the sweep's order
        ways = {how: i for i, how in enumerate(FIELD_INTERACTIONS)}
        df["_how"] = [ways.get(h, len(ways)) for h in df["interaction"]]
        by = ["_how", *by]
    df = df.sort_values(by, kind="stable")
    return df.drop(columns=[c for c in df.columns if c.startswith("_")]).reset_index(drop=True)


#: The field's benchmark: the policies study's measures and the patrolling field's.
FIELD_STUDY_MEASURES = (
    "avg_idleness",
    "worst_idleness",
    "mean_interval",
    "max_interval",
    *FIELD_MEASURES,
    "max_wait",
    "coverage",
)


def field_data(sweep_dir: str | Path, level: float = 0.95) -> pd.DataFrame:
    """The field's benchmark: interaction x graph x strategy x team size, the mean and 95%
    t-interval over runs of each of :data:`FIELD_STUDY_MEASURES`, with each graph's
    closed walk, as :func:`policies_data`."""
    return policies_data(sweep_dir, level, FIELD_STUDY_MEASURES, by_interaction=True)


#: A run *went wrong* in the field's benchmark when a target stayed unvisited for its
#: whole window (coverage below 1) or its robots were blocked (a move asked and not
#: made) in more than this share of their robot-steps.
BLOCKED_SHARE = 0.5


def bad_runs(res: pd.DataFrame) -> pd.DataFrame:
    """The runs of a sweep's ``results.csv`` (``res``) that went wrong: a target never
    visited in the window (``unvisited``) or blocked in more than :data:`BLOCKED_SHARE`
    of their robot-steps (``blocked``); columns of ``res`` plus ``blocked_share``,
    ``unvisited`` and ``blocked``."""
    window = pd.to_numeric(res["steps"]) - pd.to_numeric(res["record.warmup"])
    share = pd.to_numeric(res["interferences"]) / (pd.to_numeric(res["agents"]) * window)
    out = res.assign(
        blocked_share=share,
        unvisited=pd.to_numeric(res["coverage"]) < 1,
        blocked=share > BLOCKED_SHARE,
    )
    return out[out["unvisited"] | out["blocked"]]


def field_models_data(sweep_dir: str | Path) -> pd.DataFrame:
    """Does the ranking of strategies depend on how robots meet? One row per graph,
    interaction, team size and strategy: ``avg_idleness_mean`` and ``qmi_mean`` over
    runs, ``rank`` of the strategy by average idleness among those of its graph,
    interaction and team size (1: lowest; ties share the lower rank), ``runs`` and
    ``bad_runs`` (:func:`bad_runs`: a vertex never visited in the window or blocked in
    more than half the robot-steps), ``unvisited`` and ``blocked`` among them."""
    df = field_data(sweep_dir)
    res = _read_csv(Path(sweep_dir) / "results.csv", "per-run results of the sweep")
    res = res.assign(_map=[m.split("/")[-1].removesuffix(".txt") for m in res["map"].astype(str)])
    bad = bad_runs(res)
    keys = ["_map", "team.interaction", "agents", "policy"]
    counts = {
        key: (len(g), int(g["unvisited"].sum()), int(g["blocked"].sum()))
        for key, g in bad.groupby(keys, sort=False)
    }
    out = df[["map", "interaction", "agents", "policy", "runs"]].copy()
    out["avg_idleness_mean"] = df["avg_idleness_mean"]
    out["qmi_mean"] = df["qmi_mean"]
    out["rank"] = (
        df.groupby(["map", "interaction", "agents"])["avg_idleness_mean"]
        .rank(method="min")
        .astype("Int64")
    )
    got = [
        counts.get((m, h, k, p), (0, 0, 0))
        for m, h, k, p in zip(
            out["map"], out["interaction"], out["agents"], out["policy"], strict=True
        )
    ]
    out["bad_runs"] = [g[0] for g in got]
    out["unvisited"] = [g[1] for g in got]
    out["blocked"] = [g[2] for g in got]
    return out.reset_index(drop=True)


def learning_data(sweep_dir: str | Path, level: float = 0.95) -> pd.DataFrame:
    """Idleness in windows along each strategy's run (from ``timeline.csv``).

    One row per strategy and window: policy, learns, window, first_step, last_step,
    ``avg_idleness_mean/_lo/_hi`` and ``worst_idleness_mean/_lo/_hi`` over runs (95%
    t-interval), runs, map, agents; for ``learned-tour`` also ``tour_ratio_mean/_lo/_hi``,
    its route's length at the window's end over the closed walk ``cyclic`` uses.
    """
    d = Path(sweep_dir)
    sw = read_sweep(d)
    rows = []
    for path, cfg in zip(sw["path"], sw["config"], strict=True):
        tl = Path(path) / "timeline.csv"
        if not tl.is_file():
            raise FileNotFoundError(f"{tl}: missing; the learning figure needs record.timeline")
        t = _read_csv(tl, "idleness in windows")
        name = folder_map(path, cfg).name
        tours = _tour_runs(Path(path))
        for (w, first, last), g in t.groupby(["window", "first_step", "last_step"], sort=True):
            row: dict[str, Any] = {
                "policy": cfg["policy"],
                "learns": strategies.learns(cfg["policy"]),
                "window": int(w),
                "first_step": int(first),
                "last_step": int(last),
                "runs": len(g),
            }
            for col in ("avg_idleness", "worst_idleness"):
                ci = mean_ci(pd.to_numeric(g[col]), level)
                row.update({f"{col}_{k}": ci[k] for k in ("mean", "lo", "hi")})
            if tours is not None:
                ci = mean_ci(pd.Series([tour_ratio_at(run, int(last)) for run in tours]), level)
                row.update({f"tour_ratio_{k}": ci[k] for k in ("mean", "lo", "hi")})
            row["map"] = name
            row["agents"] = int(cfg["agents"])
            rows.append(row)
    return pd.DataFrame(rows)


def _tour_runs(folder: Path) -> list[dict[str, Any]] | None:
    """The runs of a ``learned-tour`` run folder as dicts with ``tour_changes``,
    ``tour_lengths`` and ``reference`` (the closed walk ``cyclic`` uses); None for a
    strategy that does not learn a route."""
    summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    ref = summary.get("strategy", {}).get("reference_walk_length")
    if ref is None:
        return None
    return [{**r, "reference": ref} for r in summary["runs"]]


def tour_ratio_at(run: dict[str, Any], step: int) -> float:
    """A run's route length after team step ``step`` over the reference walk's: its last
    change made in a step up to ``step`` (a change made in step ``t + 1`` is recorded
    as ``t``, the steps taken before it)."""
    n = run["tour_lengths"][0]
    for t, length in zip(run["tour_changes"], run["tour_lengths"], strict=True):
        if t < step:
            n = length
    return n / run["reference"]


#: Columns of the figures' tables named for a config key: ``communication``,
#: ``interaction``.
SHORT_KEYS = {"communication": "team.communication", "interaction": "team.interaction"}


def grouped_data(
    sweep_dir: str | Path,
    keys: dict[str, type],
    measures: Iterable[str],
    level: float = 0.95,
) -> pd.DataFrame:
    """Per-run results of a sweep pooled by ``keys`` (a config key, or a short name of
    :data:`SHORT_KEYS`)."""
    d = Path(sweep_dir)
    points = read_sweep(d)
    res = _read_csv(d / "results.csv", "per-run results of the sweep")
    config_key = {k: SHORT_KEYS.get(k, k) for k in keys}
    swept: list[str] = []
    for ov in points["overrides"]:
        swept += [k for k in ov if k not in swept and k not in config_key.values()]
    keyed = pd.DataFrame(
        {
            "point": points["index"],
            **{k: [cast(c[config_key[k]]) for c in points["config"]] for k, cast in keys.items()},
            "map": [
                folder_map(p, c).name for p, c in zip(points["path"], points["config"], strict=True)
            ],
            # a swept map is grouped by the map's name (above), not by its path
            **{k: [c[k] for c in points["config"]] for k in swept if k != "map"},
        }
    )
    res = res.drop(columns=[c for c in keyed.columns if c != "point" and c in res.columns])
    res = res.merge(keyed, on="point", how="inner")
    group = [*keys, *swept]
    rows = []
    # a key some points leave unset (None: ``tour.learn_steps`` outside learned-tour) is
    # a group value like any other, not a reason to drop the points
    for values, g in res.groupby(group, sort=True, dropna=False):
        row: dict[str, Any] = dict(zip(group, values, strict=True))
        row["runs"] = len(g)
        row["map"] = ",".join(sorted(set(g["map"])))
        if "max_stall" in g.columns and "stall_bound" in g.columns:
            stalls = pd.to_numeric(g["max_stall"], errors="coerce")
            row["max_wait_max"] = float(pd.to_numeric(g["max_wait"], errors="coerce").max())
            row["max_stall_max"] = float(stalls.max())
            row["stall_bound"] = float(pd.to_numeric(g["stall_bound"]).max())
            row["frozen"] = int((stalls > pd.to_numeric(g["stall_bound"])).sum())
        for col in measures:
            ci = mean_ci(pd.to_numeric(g[col], errors="coerce"), level)
            row.update({f"{col}_{k}": ci[k] for k in ("mean", "lo", "hi", "n")})
        rows.append(row)
    return pd.DataFrame(rows)


# --- Fig. 6 -----------------------------------------------------------------------------------


def figure6_data(run_dir: str | Path, agent: int = 0, run: int = 0) -> pd.DataFrame:
    """Fig. 6: agent ``agent``'s greedy action per cell and its visit map.

    For each free cell: the heading with which the agent most often left it while
    patrolling (argmax over headings of N(cell, heading, .) summed over actions; ties
    N, E, S, W), since that is the Q-row the agent actually uses there; the greedy
    action of that row over the legal (non-wall) moves (ties N, E, S, W); its Q-value;
    ``heading_share``, that heading's share of the agent's decisions at the cell;
    ``updates``, those decisions (0: never learnt there; the action is then just the
    initial preference); visits of the agent and of the whole team (cell entries,
    homing included) and the agent's share. Columns: cell, row, col, heading,
    heading_share, action, q, updates, visits_agent, visits_all, share, map, agents,
    episodes (complete episodes of the run).
    """
    d = Path(run_dir)
    cfg = _run_config(d)
    m = folder_map(d, cfg)
    with np.load(d / "q_table.npz") as z:
        q, n = dense_tables(z, run, agent)  # [C, 4 heading, 4 action] each
    with np.load(d / "visits.npz") as z:
        visits = z["visits"][run]  # [K, C]
    per_heading = n.sum(axis=2)  # [C, 4]
    head = per_heading.argmax(axis=1)
    updates = per_heading.sum(axis=1)
    cells = np.arange(m.n_cells)
    qrow = q[cells, head]  # [C, 4]
    masked = np.where(m.neighbors >= 0, qrow, -np.inf)
    action = masked.argmax(axis=1)
    share_h = np.divide(
        per_heading[cells, head], updates, out=np.full(m.n_cells, np.nan), where=updates > 0
    )
    total = visits.sum(axis=0)
    ep = _read_csv(d / "episodes.csv", "episodes")
    episodes = int(((ep["run"] == run) & (ep["complete"] == 1) & (ep["group"] == 0)).sum())
    df = pd.DataFrame(
        {
            "cell": cells,
            "row": m.coords[:, 0],
            "col": m.coords[:, 1],
            "heading": [DIR_LETTERS[h] for h in head],
            "heading_share": share_h,
            "action": [DIR_LETTERS[a] for a in action],
            "q": masked[cells, action],
            "updates": updates,
            "visits_agent": visits[agent],
            "visits_all": total,
            "share": np.divide(
                visits[agent], total, out=np.full(m.n_cells, np.nan), where=total > 0
            ),
        }
    )
    df["map"] = m.name
    df["agents"] = int(cfg["agents"])
    df["episodes"] = episodes
    return df


# --- Fig. 5 ---------------------------------------------------------------------------------


def figure5_data(run_dir: str | Path, run: int = 0) -> pd.DataFrame:
    """Fig. 5 from a run folder: its ``trajectory.csv`` (``record.trajectory: N``, the
    last N team steps of each run) for run ``run``, with the map's name added.

    Columns: step, agent, cell, row, col, map (and mode when recorded). Use
    :func:`trajectory` instead to simulate any stretch of a run without a run folder.
    """
    d = Path(run_dir)
    cfg = _run_config(d)
    tr = _read_csv(d / "trajectory.csv", "agents' cells; set record.trajectory: N")
    if "run" in tr.columns:
        tr = tr[tr["run"] == run].drop(columns="run")
    if tr.empty:
        raise ValueError(f"{d}/trajectory.csv: no rows for run {run}")
    tr = tr.sort_values(["step", "agent"], kind="stable").reset_index(drop=True)
    tr["map"] = cfg["map"]
    return tr


def trajectory(
    cfg: Config, steps: int, run: int = 0, point: int = 0, skip: int = 0
) -> pd.DataFrame:
    """Fig. 5: every agent's cell at every team step of run ``run`` of ``cfg``.

    Drives the world and the strategy with :func:`qpatrol.engines.numpy_loop.advance` and the same
    random streams as :func:`qpatrol.run.simulate` (``SeedSequence(seed, spawn_key=
    (point, run))``, agents placed before the first step), so the positions are those
    of ``simulate(cfg, point)`` for that run. The first ``skip`` steps are simulated but
    not kept (to show a team that has learnt); then ``steps`` more are kept, plus the
    positions before them. Stops early when the run is done (``episodes``). Columns:
    step (team step; 0 = start), agent, cell, row, col, mode (patrol, homing, queued,
    charging), map.
    """
    m, p = prepare(cfg)
    streams = Streams(run_seeds(cfg["seed"], range(run, run + 1), point), p.n_agents)
    starts = np.stack([world.place_agents(p, m, g) for g in streams.generators])
    state = world.init_state(p, starts)
    strategy = strategies.make(cfg["policy"], cfg, m, p, starts)
    k = p.n_agents
    steps_kept, cells, modes = [], [], []

    def keep() -> None:
        steps_kept.append(state.t)
        cells.append(state.pos[0].copy())
        modes.append(state.mode[0].copy())

    if skip == 0:
        keep()
    for i in range(skip + steps):
        if not state.active.any():
            break
        advance(state, p, strategy, streams.next())
        if i + 1 >= skip:
            keep()
    cell = np.concatenate(cells)
    df = pd.DataFrame(
        {
            "step": np.repeat(steps_kept, k),
            "agent": np.tile(np.arange(k), len(steps_kept)),
            "cell": cell,
            "row": m.coords[cell, 0],
            "col": m.coords[cell, 1],
            "mode": [MODE_NAMES[x] for x in np.concatenate(modes)],
        }
    )
    df["map"] = cfg["map"]
    return df


# --- the security study -------------------------------------------------------------

#: The intruders of the security figure: summary key stem -> label.
INTRUDERS = {"capture_random": "random", "capture_observer": "observer"}
#: A run's worst idleness has settled after a failure once a timeline window's worst
#: idleness comes within these factors of its level over the last half of the run after
#: the failure (:func:`settle_steps`).
SETTLE_BAND = (0.8, 1.25)


def _security_points(sweep_dir: Path) -> pd.DataFrame:
    """The security sweep's points with map name, policy, team size, robots failing,
    failure step (``failures.at``; for a point without failure, where its robots would
    have failed), warm-up and steps."""
    sw = read_sweep(sweep_dir)
    rows = []
    for idx, path, cfg in zip(sw["index"], sw["path"], sw["config"], strict=True):
        failed = int(cfg["failures.robots"])
        warm = int(cfg["record.warmup"])
        rows.append(
            {
                "point": int(idx),
                "path": Path(path),
                "map": folder_map(path, cfg).name,
                "policy": cfg["policy"],
                "agents": int(cfg["agents"]),
                "failures": failed,
                "at": int(cfg["failures.at"]),
                "warmup": warm,
                "steps": int(cfg["steps"]),
            }
        )
    return pd.DataFrame(rows)


def _order_rows(df: pd.DataFrame, maps: list[str]) -> pd.DataFrame:
    order = {m: i for i, m in enumerate(maps)}
    names = {n: i for i, n in enumerate(strategies.NAMES)}
    df["_m"] = [order.get(m, len(order)) for m in df["map"]]
    df["_p"] = [names.get(p, len(names)) for p in df["policy"]]
    keys = ["_m", "agents", "_p", *[c for c in ("intruder", "attack_steps") if c in df]]
    df = df.sort_values(keys, kind="stable")
    return df.drop(columns=["_m", "_p"]).reset_index(drop=True)


def security_data(sweep_dir: str | Path, level: float = 0.95) -> pd.DataFrame:
    """How often each strategy catches an intruder (the security sweep's points without
    failure): one row per map, team size, strategy, intruder (``random``: any target at
    any step; ``observer``: strikes as a robot leaves, at the target where that works
    best) and attack duration ``attack_steps`` D, with D over the map's targets
    (``d_over_targets``), the mean and 95% t-interval over runs of the share caught
    (``capture_mean/_lo/_hi``, ``runs``), the worst run's share (``capture_min``) and,
    for the observer, the target of the worst run (``cell_of_min``)."""
    d = Path(sweep_dir)
    pts = _security_points(d)
    res = _read_csv(d / "results.csv", "per-run results of the sweep")
    rows = []
    for p in pts[pts["failures"] == 0].itertuples():
        runs = res[res["point"] == p.point]
        n_targets = folder_map(p.path).n_targets
        durations = sorted(
            int(c.rsplit("_d", 1)[1])
            for c in runs.columns
            if c.startswith("capture_random_d") and runs[c].notna().any()
        )
        for stem, label in INTRUDERS.items():
            for dur in durations:
                vals = pd.to_numeric(runs[f"{stem}_d{dur}"], errors="coerce")
                ci = mean_ci(vals, level)
                row = {
                    "map": p.map,
                    "agents": p.agents,
                    "policy": p.policy,
                    "intruder": label,
                    "attack_steps": dur,
                    "d_over_targets": dur / n_targets,
                    "capture_mean": ci["mean"],
                    "capture_lo": ci["lo"],
                    "capture_hi": ci["hi"],
                    "runs": ci["n"],
                    "capture_min": float(vals.min()),
                    "cell_of_min": None,
                }
                if label == "observer" and vals.notna().any():
                    worst = runs.loc[vals.idxmin(), f"capture_observer_cell_d{dur}"]
                    row["cell_of_min"] = int(worst)
                rows.append(row)
    return _order_rows(pd.DataFrame(rows), list(dict.fromkeys(pts["map"])))


def settle_steps(first: np.ndarray, last: np.ndarray, worst: np.ndarray, at: int) -> int | None:
    """Team steps after the failure at step ``at`` until a run's worst idleness reaches
    its new level: of the timeline's windows (``first``, ``last`` their first and last
    steps, ``worst`` their worst idleness, in order) those that start after ``at``; the
    level is the median worst idleness of the last half of them, and the value is the
    last step of the first of them within :data:`SETTLE_BAND` of it, minus ``at``
    (None: no window starts after ``at``, or none is within the band)."""
    after = first > at
    lst, w = last[after], worst[after]
    if lst.size == 0:
        return None
    level = float(np.median(w[lst.size // 2 :]))
    lo, hi = SETTLE_BAND
    inside = np.flatnonzero((w >= lo * level) & (w <= hi * level))
    return int(lst[inside[0]] - at) if inside.size else None


def _security_timelines(sweep_dir: Path):
    """Each security point (:func:`_security_points`) with its per-run results and its
    timeline from the end of the warm-up on."""
    pts = _security_points(sweep_dir)
    res = _read_csv(sweep_dir / "results.csv", "per-run results of the sweep")
    for p in pts.itertuples():
        tl_path = p.path / "timeline.csv"
        if not tl_path.is_file():
            raise FileNotFoundError(f"{tl_path}: missing; the security study needs record.timeline")
        tl = _read_csv(tl_path, "idleness in windows")
        yield p, res[res["point"] == p.point], tl[tl["first_step"] > p.warmup]


def security_failures_data(sweep_dir: str | Path, level: float = 0.95) -> pd.DataFrame:
    """Worst idleness around the failure (the timeline of every security point): one row
    per map, team size, strategy, robots failing (0: the same team without failure) and
    timeline window from the end of the warm-up on: ``since_failure`` (the window's last
    step minus the failure step; without failure, where it would have been) and the mean
    and 95% t-interval over ``runs`` of the window's ``worst_idleness``."""
    rows = []
    maps = []
    for p, _, tl in _security_timelines(Path(sweep_dir)):
        maps.append(p.map)
        for last, g in tl.groupby("last_step", sort=True):
            ci = mean_ci(pd.to_numeric(g["worst_idleness"]), level)
            rows.append(
                {
                    "map": p.map,
                    "agents": p.agents,
                    "policy": p.policy,
                    "failures": p.failures,
                    "since_failure": int(last) - p.at,
                    **{f"worst_idleness_{k}": ci[k] for k in ("mean", "lo", "hi")},
                    "runs": ci["n"],
                }
            )
    # (rows are in point order, failures and windows ascending: a stable sort keeps it)
    return _order_rows(pd.DataFrame(rows), list(dict.fromkeys(maps)))


def security_recovery_data(sweep_dir: str | Path) -> pd.DataFrame:
    """How each team takes a failure: one row per map, team size, strategy and robots
    failing (0: the same team without failure), with the runs' average and worst
    idleness before the failure (``avg_before``, ``worst_before``: over the timeline's
    windows between the warm-up and the failure, each run's mean and largest, then the
    mean over runs) and after it (``avg_after``, ``worst_after``: the summary's, whose
    window starts at the failure; without failure, at the end of the warm-up), their
    ratio ``worst_ratio``, the median and largest of the runs' :func:`settle_steps`
    (``unsettled``: runs without one), ``uncovered``, the runs that left a target
    unvisited for the whole measured window (``coverage`` < 1), ``not_live``, the runs
    not live (a stretch without progress above ``stall_bound``, or a target unvisited
    in the window), and ``runs``."""
    rows = []
    maps = []
    for p, runs, tl in _security_timelines(Path(sweep_dir)):
        maps.append(p.map)
        before = tl[tl["last_step"] <= p.at].groupby("run")
        settle = [
            settle_steps(
                g["first_step"].to_numpy(),
                g["last_step"].to_numpy(),
                g["worst_idleness"].to_numpy(),
                p.at,
            )
            for _, g in tl.groupby("run", sort=True)
        ]
        settled = [x for x in settle if x is not None]
        worst_before = float(before["worst_idleness"].max().mean())
        worst_after = float(pd.to_numeric(runs["worst_idleness"]).mean())
        rows.append(
            {
                "map": p.map,
                "agents": p.agents,
                "policy": p.policy,
                "failures": p.failures,
                "failure_step": p.at,
                "avg_before": float(before["avg_idleness"].mean().mean()),
                "worst_before": worst_before,
                "avg_after": float(pd.to_numeric(runs["avg_idleness"]).mean()),
                "worst_after": worst_after,
                "worst_ratio": worst_after / worst_before if worst_before else None,
                "settle_median": float(np.median(settled)) if settled else None,
                "settle_max": max(settled) if settled else None,
                "unsettled": len(settle) - len(settled),
                "uncovered": int((pd.to_numeric(runs["coverage"]) < 1).sum()),
                "not_live": int((~runs["live"].astype(bool)).sum()),
                "runs": len(runs),
            }
        )
    return _order_rows(pd.DataFrame(rows), list(dict.fromkeys(maps)))


def neural_data(sweep_dir: str | Path) -> pd.DataFrame:
    """The neural policy's study (``qpatrol sweep neural``) and its training, one table:

    * ``kind`` = ``study``: one row per map, robots failing (``failures``), strategy and,
      for ``neural``, training ``seed`` (-1 for the others): ``runs``,
      ``avg_idleness_mean`` and ``worst_idleness_mean`` over runs, the run of the
      highest average idleness (``worst_run``, its ``worst_run_avg_idleness``), the
      lowest ``coverage``;
    * ``kind`` = ``baseline``: cyclic and SEBS in the training's setting (ps_cumberland,
      1,000-step runs measured after 200 steps): ``avg_idleness_mean``;
    * ``kind`` = ``curve``: each training seed's curve as its learner wrote it beside
      the shipped weights (``team_steps`` trained, ``avg_idleness`` of a batch of runs).
    """
    from qpatrol.strategies import neural
    from qpatrol.study.sweep import NEURAL_TEAM, NEURAL_TRAIN_STEPS

    res = _read_csv(Path(sweep_dir) / "results.csv", "per-run results of the sweep")
    res = res.assign(map=[m.split("/")[-1].removesuffix(".txt") for m in res["map"].astype(str)])
    weights = res["neural.weights"] if "neural.weights" in res.columns else None
    seeds = [
        int(str(w).split("seed")[-1].split(".")[0]) if p == "neural" and isinstance(w, str) else -1
        for p, w in zip(
            res["policy"], weights if weights is not None else [None] * len(res), strict=True
        )
    ]
    res = res.assign(seed=seeds, failures=pd.to_numeric(res["failures.robots"]).astype(int))
    train = pd.to_numeric(res["steps"]) == NEURAL_TRAIN_STEPS
    rows = []
    for (m, f, pol, seed), g in res[~train].groupby(
        ["map", "failures", "policy", "seed"], sort=False
    ):
        worst = g.loc[pd.to_numeric(g["avg_idleness"]).idxmax()]
        rows.append(
            {
                "kind": "study",
                "map": m,
                "failures": f,
                "policy": pol,
                "seed": seed,
                "runs": len(g),
                "avg_idleness_mean": float(pd.to_numeric(g["avg_idleness"]).mean()),
                "worst_idleness_mean": float(pd.to_numeric(g["worst_idleness"]).mean()),
                "worst_run": int(worst["run"]),
                "worst_run_avg_idleness": float(worst["avg_idleness"]),
                "coverage_min": float(pd.to_numeric(g["coverage"]).min()),
            }
        )
    for pol, g in res[train].groupby("policy", sort=False):
        rows.append(
            {
                "kind": "baseline",
                "map": "ps_cumberland",
                "policy": pol,
                "runs": len(g),
                "avg_idleness_mean": float(pd.to_numeric(g["avg_idleness"]).mean()),
            }
        )
    for path in sorted(neural.WEIGHTS_DIR.glob(f"ps_cumberland_{NEURAL_TEAM}_seed*.curve.csv")):
        seed = int(path.name.split("seed")[-1].split(".")[0])
        curve = read_csv(path)
        for _, r in curve.iterrows():
            rows.append(
                {
                    "kind": "curve",
                    "map": "ps_cumberland",
                    "policy": "neural",
                    "seed": seed,
                    "team_steps": int(r["team_steps"]),
                    "seconds": float(r["seconds"]),
                    "avg_idleness_mean": float(r["avg_idleness"]),
                }
            )
    return pd.DataFrame(rows)
