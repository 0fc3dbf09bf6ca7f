"""Parallel, resumable parameter sweeps.

A sweep runs one base config at several *points*, each a set of overridden keys.
Run r of point p draws from ``SeedSequence(seed, spawn_key=(p, r))`` and every point
writes its own run folder, so the numbers never depend on ``jobs``, on the backend, on
batching or on which points ran earlier. Points that differ only in per-run values
(seed, gamma, epsilon, multiplier, initial Q, reward weights) run their runs together
in shared batches (:mod:`qpatrol.run.batching`; ``batch_points=False``: each point's runs
as a batch of their own); the files are the same either way::

    from qpatrol.config import load_config
    from qpatrol.study.sweep import points_for, run_sweep, load_results

    base = load_config("configs/gamma.yaml")
    res = run_sweep(base, points_for("learning.gamma", [0.1, 0.5, 0.9]), "results/sweeps/g",
                    jobs=4)
    df = load_results("results/sweeps/g")

Layout of ``out``::

    sweep.json               base config tree and the list of points (written first)
    manifest.json            what the sweep wrote (qpatrol.util.manifest), kept up to date
    points/<id>/             a complete run folder per finished point (see run.write_run)
    points/<id>.failed.json  error type, message and traceback of a point that raised
    results.csv              one row per (point, run), rebuilt from every summary.json

A point folder appears atomically (temp dir + rename), so a folder that exists is
complete: a rerun skips it, redoes the others (failed ones included) and removes the
temp dirs a killed sweep left behind.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import os
import re
import shutil
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import pandas as pd

from qpatrol import __version__
from qpatrol.config import FIELDS, Config, ConfigError, check_value, parse_assignment
from qpatrol.engines import coldstart, compiled_loop
from qpatrol.engines import threads as engine_threads
from qpatrol.maps import MapError, resolve_map
from qpatrol.measures.records import to_csv_text
from qpatrol.run import outputs
from qpatrol.strategies import NAMES as STRATEGY_NAMES
from qpatrol.util import atomic, manifest, provenance
from qpatrol.util.csvio import read_csv
from qpatrol.world import limits

Progress = Callable[[int, int], None]

BACKENDS = ("joblib", "dask")
SWEEP_FILE = "sweep.json"
RESULTS_FILE = "results.csv"
POINTS_DIR = "points"
LOCK_FILE = ".sweep.lock"
FAILED_SUFFIX = ".failed.json"
PROGRESS_SUFFIX = ".progress.tmp"  # .<id>.progress.tmp: "steps_done steps_total" of a point
_FORMAT = "qpatrol-sweep/1"
_MAX_ID = 160  # characters; longer ids are cut and get a hash suffix


# --------------------------------------------------------------------------- points


def _fmt_value(v: Any) -> str:
    """A value as written in a point id: ``true``, ``0.4``, ``100``, ``null``, ``13+34``."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if v is None:
        return "null"
    if isinstance(v, float):
        return str(int(v)) if v.is_integer() and abs(v) < 1e16 else repr(v)
    if isinstance(v, list | tuple):
        return "+".join(_fmt_value(x) for x in v)
    return str(v)


_UNSAFE = re.compile(r"[^A-Za-z0-9._+=,-]")


@dataclass(frozen=True)
class Point:
    """One point of a sweep.

    Attributes:
        index: the point number p; run r of this point draws from
            ``SeedSequence(seed, spawn_key=(p, r))``.
        overrides: dotted config key -> value applied on top of the base config.
    """

    index: int
    overrides: dict[str, Any] = field(default_factory=dict)

    @property
    def id(self) -> str:
        """Stable, filesystem-safe name, e.g. ``003-learning.gamma=0.4``."""
        body = ",".join(f"{k}={_fmt_value(v)}" for k, v in self.overrides.items())
        text = f"{self.index:03d}-{body}" if body else f"{self.index:03d}"
        text = _UNSAFE.sub("_", text)
        if len(text) > _MAX_ID:
            digest = hashlib.sha256(text.encode()).hexdigest()[:8]
            text = f"{text[: _MAX_ID - 9]}~{digest}"
        return text

    def __hash__(self) -> int:
        return hash((self.index, self.id))

    def describe(self) -> dict[str, Any]:
        """``{"index", "id", "overrides"}``, as stored in ``sweep.json``."""
        return {"index": self.index, "id": self.id, "overrides": dict(self.overrides)}


def points_for(param: str, values: Sequence[Any]) -> list[Point]:
    """One point per value of one key: ``Point(i, {param: values[i]})``.

    Values are validated and normalised by the config schema; a bad one raises
    :class:`ConfigError` naming the key.
    """
    return grid_points({param: list(values)})


def grid_points(grid: Mapping[str, Sequence[Any]]) -> list[Point]:
    """The cartesian product of ``{key: values}``, first key slowest, numbered from 0."""
    if not grid:
        raise ConfigError("a sweep needs at least one key with values")
    checked: dict[str, list[Any]] = {}
    for key, values in grid.items():
        if isinstance(values, str | bytes) or not isinstance(values, Sequence):
            raise ConfigError(f"{key}: sweep values must be a list, got {values!r}")
        if not values:
            raise ConfigError(f"{key}: no values to sweep")
        checked[key] = [check_value(key, v) for v in values]
    keys = list(checked)
    return [
        Point(i, dict(zip(keys, combo, strict=True)))
        for i, combo in enumerate(itertools.product(*checked.values()))
    ]


def parse_values(key: str, text: str) -> list[Any]:
    """Parse a comma list of values for ``key`` (``"0.1,0.5,0.9"``, ``"on,off"``, ``"1e-3"``).

    Each item is read as YAML like ``--set KEY=VALUE`` and validated by the schema; a
    number PyYAML reads as text (``1e-3``) is accepted for int and float keys.
    """
    items = [s.strip() for s in str(text).split(",")]
    if not any(items):
        raise ConfigError(f"{key}: no values given")
    out = []
    for item in items:
        if not item:
            raise ConfigError(f"{key}: empty value in {text!r}")
        k, v = parse_assignment(f"{key}={item}")
        if isinstance(v, str) and FIELDS[k].kind in ("int", "float"):
            with contextlib.suppress(ValueError):
                v = float(v)
        v = check_value(k, v)
        if any(json.dumps(v, default=str) == json.dumps(w, default=str) for w in out):
            raise ConfigError(
                f"{key}: the value {_fmt_value(v)} is given twice; allowed: distinct values"
            )
        out.append(v)
    return out


def listed_points(overrides: Sequence[Mapping[str, Any]]) -> list[Point]:
    """One point per mapping of ``{key: value}`` overrides, numbered from 0, validated."""
    if not overrides:
        raise ConfigError("a sweep needs at least one point")
    return [
        Point(i, {k: check_value(k, v) for k, v in ov.items()}) for i, ov in enumerate(overrides)
    ]


class NamedSweep(NamedTuple):
    """A built-in sweep: ``config`` (path relative to the repo root), ``param`` (one key,
    a grid ``{key: values}``, or a function giving each point's overrides) and ``values``
    (None unless ``param`` is one key)."""

    config: str
    param: str | dict[str, list[Any]] | Callable[[bool], list[dict[str, Any]]]
    values: list[Any] | None

    def points(self, quick: bool = False) -> list[Point]:
        """The sweep's points (``quick``: the smaller set of ``qpatrol reproduce --quick``,
        for a sweep whose points set their own steps)."""
        if isinstance(self.param, str):
            return points_for(self.param, self.values or [])
        if callable(self.param):
            return listed_points(self.param(quick))
        return grid_points(self.param)


#: The maps and team sizes of the policies study (``qpatrol sweep policies``).
POLICY_MAPS = ("map_a", "map_b", "pacman", "facility")
POLICY_TEAMS = (1, 2, 4, 8)
#: Team steps every point of the policies study measures, after its warm-up.
POLICY_WINDOW = 3_000
#: Warm-up of a strategy that does not learn: the cyclic robots gather on their slots,
#: the conscientious ones spread out; their idleness is flat after that.
POLICY_WARMUP = 1_000
#: Warm-up of a learner: the paper's learner keeps improving for 100,000 steps and more
#: (the learning-over-time figure; on the compiled engine that costs seconds), and
#: ``learned-tour``'s route is within a few percent of cyclic's walk by then; any other
#: learner (``qlearning-idleness`` settles within 2,000 steps) gets the default.
LEARNER_WARMUPS = {"qlearning": 100_000, "learned-tour": 100_000}
POLICY_LEARNER_WARMUP = 5_000
#: Team steps of each run in the learning-over-time experiment: the paper's learner,
#: other learners, and the strategies that do not learn.
LEARNING_STEPS = {"qlearning": 200_000, "learned-tour": 200_000}
LEARNING_LEARNER_STEPS = 25_000
LEARNING_OTHERS_STEPS = 10_000


def policy_warmup(name: str) -> int:
    """Team steps before the policies study measures strategy ``name``."""
    from qpatrol.strategies import learns

    if not learns(name):
        return POLICY_WARMUP
    return LEARNER_WARMUPS.get(name, POLICY_LEARNER_WARMUP)


def learning_steps(name: str) -> int:
    """Team steps of strategy ``name``'s runs in the learning-over-time experiment."""
    from qpatrol.strategies import learns

    if not learns(name):
        return LEARNING_OTHERS_STEPS
    return LEARNING_STEPS.get(name, LEARNING_LEARNER_STEPS)


def _every_strategy(
    maps: tuple[str, ...], teams: tuple[int, ...], window: int, quick: bool
) -> list[dict[str, Any]]:
    """Every strategy x map x team size, strategy first (a new strategy adds points at
    the end), each measuring ``window`` steps after the policies study's warm-up
    (``quick``: 1,000 steps for a learner, 200 for the others); ``learned-tour`` learns
    during the first 9/10 of the warm-up (``tour.learn_steps``): a change of route
    disorders the team for a lap or two, and the last tenth lets it settle."""
    from qpatrol.strategies import learns

    points = []
    for name in STRATEGY_NAMES:
        warm = (1000 if learns(name) else 200) if quick else policy_warmup(name)
        for m in maps:
            for k in teams:
                point = {
                    "map": m,
                    "policy": name,
                    "agents": k,
                    "steps": warm + window,
                    "record.warmup": warm,
                }
                if name == "learned-tour":  # learns in 9/10 of the warm-up, then settles
                    point["tour.learn_steps"] = warm * 9 // 10
                points.append(point)
    return points


def policies_overrides(quick: bool = False) -> list[dict[str, Any]]:
    """Every strategy x map x team size, the learners with their longer warm-up.

    ``quick``: two maps, K = 1 and 4, and short runs (a smoke test, not a result).
    """
    maps, teams = (("map_b", "pacman"), (1, 4)) if quick else (POLICY_MAPS, POLICY_TEAMS)
    return _every_strategy(maps, teams, 500 if quick else POLICY_WINDOW, quick)


#: The field's benchmark (``qpatrol sweep field``): patrolling_sim's graphs, its team sizes,
#: and how robots meet: patrolling_sim's physical robots first (the default), then robots
#: that ignore each other (SimPatrol, SimplePatrol) and the paper's exclusive cells.
FIELD_MAPS = ("ps_grid", "ps_example", "ps_cumberland", "ps_diag_floor1")
FIELD_TEAMS = (1, 2, 4, 6, 8, 12)
FIELD_INTERACTIONS = ("interference", "none", "exclusive")


def field_overrides(quick: bool = False) -> list[dict[str, Any]]:
    """Every interaction x strategy x patrolling_sim graph x team size, each with the
    policies study's warm-up and window.

    ``quick``: two graphs, K = 1 and 4, and short runs (a smoke test, not a result).
    """
    maps, teams = (("ps_grid", "ps_example"), (1, 4)) if quick else (FIELD_MAPS, FIELD_TEAMS)
    points = _every_strategy(maps, teams, 500 if quick else POLICY_WINDOW, quick)
    return [{**p, "team.interaction": how} for how in FIELD_INTERACTIONS for p in points]


#: The security study (``qpatrol sweep security``): its maps, team sizes and failures,
#: the steps it measures after the warm-up, and when robots fail (after the warm-up).
SECURITY_MAPS = ("map_a", "facility")
SECURITY_TEAMS = (4, 8)
SECURITY_FAILURES = (0, 1, 2)
SECURITY_WINDOW = 4_000
SECURITY_FAIL_AFTER = 1_000


def security_overrides(quick: bool = False) -> list[dict[str, Any]]:
    """Every strategy x map x team size x robots failing (0, 1, 2), each with the
    policies study's warm-up; robots fail :data:`SECURITY_FAIL_AFTER` steps into the
    window of :data:`SECURITY_WINDOW` steps (the intruder measures come from the points
    without failure).

    ``quick``: map_a only, K = 4, none or 2 robots failing, and short runs (a smoke
    test, not a result).
    """
    maps, teams = (("map_a",), (4,)) if quick else (SECURITY_MAPS, SECURITY_TEAMS)
    failures = (0, 2) if quick else SECURITY_FAILURES
    window, fail_after = (600, 200) if quick else (SECURITY_WINDOW, SECURITY_FAIL_AFTER)
    return [
        # (with no robot failing: where they would have, for comparison)
        {**p, "failures.robots": failed, "failures.at": p["record.warmup"] + fail_after}
        for p in _every_strategy(maps, teams, window, quick)
        for failed in failures
    ]


def learning_overrides(quick: bool = False) -> list[dict[str, Any]]:
    """Every strategy but ``random``: learners for a long run, the others shorter.

    ``quick``: 6,000 and 2,000 steps (with ``record.timeline=1000`` from the quick mode).
    """
    from qpatrol.strategies import learns

    def steps(name: str) -> int:
        if quick:
            return 6_000 if learns(name) else 2_000
        return learning_steps(name)

    return [{"policy": n, "steps": steps(n)} for n in STRATEGY_NAMES if n != "random"]


#: The neural policy's study (``qpatrol sweep neural``): the trained policy (one point per
#: training seed's weights, :data:`NEURAL_SEEDS`) against every strategy, 6 robots (the
#: team it was trained with) on the field's four graphs and a grid maze it never saw,
#: without and with 2 robots failing :data:`NEURAL_FAIL_AFTER` steps into the window.
NEURAL_MAPS = ("ps_grid", "ps_example", "ps_cumberland", "ps_diag_floor1", "map_a")
NEURAL_TEAM = 6
NEURAL_FAILURES = (0, 2)
NEURAL_FAIL_AFTER = 1_000
NEURAL_SEEDS = (0, 1, 2)
#: The training's setting (:mod:`qpatrol.learners.ppo`): runs of this many steps,
#: measured after the first NEURAL_TRAIN_WARMUP, for the training curve's lines.
NEURAL_TRAIN_STEPS = 1_000
NEURAL_TRAIN_WARMUP = 200


def neural_weights(seed: int) -> str:
    """The shipped weights of training seed ``seed`` (a name ``neural.weights`` finds)."""
    return f"ps_cumberland_{NEURAL_TEAM}_seed{seed}.npz"


def neural_overrides(quick: bool = False) -> list[dict[str, Any]]:
    """Every strategy and each training seed's neural policy x map x failures, with the
    policies study's warm-up and window; then cyclic and SEBS in the training's setting
    on ps_cumberland (the training curve's lines).

    ``quick``: two graphs, no failure and 2 failing, short runs (a smoke test)."""
    maps = ("ps_example", "ps_cumberland") if quick else NEURAL_MAPS
    window, fail_after = (600, 200) if quick else (POLICY_WINDOW, NEURAL_FAIL_AFTER)
    points = []
    classic = [p for p in _every_strategy(maps, (NEURAL_TEAM,), window, quick)]
    neural = []
    warm = 200 if quick else POLICY_WARMUP
    for seed in NEURAL_SEEDS:
        for m in maps:
            neural.append(
                {
                    "map": m,
                    "policy": "neural",
                    "neural.weights": neural_weights(seed),
                    "agents": NEURAL_TEAM,
                    "steps": warm + window,
                    "record.warmup": warm,
                }
            )
    for p in classic + neural:
        for failed in NEURAL_FAILURES:
            at = p["record.warmup"] + fail_after
            points.append({**p, "failures.robots": failed, "failures.at": at})
    for name in ("cyclic", "sebs"):
        points.append(
            {
                "map": "ps_cumberland",
                "policy": name,
                "agents": NEURAL_TEAM,
                "steps": NEURAL_TRAIN_STEPS,
                "record.warmup": NEURAL_TRAIN_WARMUP,
                "failures.robots": 0,
                "failures.at": 0,
                "runs": 100,
            }
        )
    return points


NAMED_SWEEPS: dict[str, NamedSweep] = {
    "gamma": NamedSweep(
        "configs/gamma.yaml", "learning.gamma", [round(0.1 * i, 1) for i in range(1, 10)]
    ),
    "multiplier": NamedSweep("configs/multiplier.yaml", "learning.multiplier", [1, 10, 100, 1000]),
    "team-size": NamedSweep(
        "configs/team_size.yaml",
        {"agents": [1, 2, 4, 8], "team.communication": [True, False]},
        None,
    ),
    "strategies": NamedSweep(
        "configs/strategies.yaml",
        {"policy": list(STRATEGY_NAMES), "agents": [1, 2, 4, 8]},
        None,
    ),
    "policies": NamedSweep("configs/policies.yaml", policies_overrides, None),
    "field": NamedSweep("configs/field.yaml", field_overrides, None),
    "security": NamedSweep("configs/security.yaml", security_overrides, None),
    "learning": NamedSweep("configs/learning.yaml", learning_overrides, None),
    "neural": NamedSweep("configs/neural.yaml", neural_overrides, None),
}


# --------------------------------------------------------------------------- results


@dataclass
class SweepResult:
    """What :func:`run_sweep` did.

    Attributes:
        out: the sweep folder.
        points: all points of the sweep.
        done: ids of points computed by this call.
        skipped: ids of points already complete before this call.
        failed: ids of points whose run raised (see ``points/<id>.failed.json``).
        errors: point id -> one-line error of each failed point.
        results: path of ``results.csv`` (rows of every complete point).
    """

    out: Path
    points: list[Point]
    done: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    errors: dict[str, str] = field(default_factory=dict)
    results: Path | None = None

    @property
    def ok(self) -> bool:
        """True when every point is complete."""
        return not self.failed


def load_results(out: str | Path) -> pd.DataFrame:
    """``results.csv`` of a sweep folder (or the CSV path itself) as a DataFrame."""
    p = Path(out)
    return read_csv(p / RESULTS_FILE if p.is_dir() else p)


# --------------------------------------------------------------------------- the sweep


def run_sweep(
    base: Config,
    points: list[Point],
    out: str | Path,
    jobs: int = 1,
    backend: str = "joblib",
    scheduler: str | None = None,
    progress: Progress | None = None,
    force: bool = False,
    meta: dict[str, Any] | None = None,
    batch_points: bool = True,
) -> SweepResult:
    """Run every point of a sweep not yet complete in ``out``, then write ``results.csv``.

    Args:
        base: the config each point's overrides apply to.
        points: the points (see :func:`points_for`, :func:`grid_points`).
        out: the sweep folder; an existing one holding the same sweep is resumed.
        jobs: parallel workers (joblib semantics: -1 = all cores); with ``dask`` and no
            scheduler, the number of local worker processes.
        backend: ``"joblib"`` (loky processes on this machine) or ``"dask"``.
        scheduler: address of a running Dask scheduler (``tcp://host:8786``); None starts
            a local cluster. Workers must see ``out`` at the same absolute path.
        progress: called as ``progress(runs_done, runs_total)`` as points finish and,
            about twice a second, as they advance (``runs_done`` then counts a running
            point's runs by the share of its steps done, so it may be fractional).
        force: start over: remove ``points/`` and ``results.csv`` even if ``out`` holds
            a different sweep (only in a sweep folder or an empty one).
        meta: provenance fields for ``meta.json`` (:func:`qpatrol.util.provenance.collect`),
            written to ``out`` and, per point, into each point folder.
        batch_points: run points that differ only in per-run values as shared batches
            (:mod:`qpatrol.run.batching`); False: one point per batch. Same files either way.

    Raises:
        ConfigError: a bad override, option, or ``out`` holding a different sweep
            (one line). A point whose run raises does not raise here: it is recorded
            in ``points/<id>.failed.json`` and listed in ``SweepResult.failed``.
    """
    if backend not in BACKENDS:
        raise ConfigError(f"backend: got {backend!r}; allowed: one of {', '.join(BACKENDS)}")
    limits.check_jobs(jobs)
    if scheduler is not None and backend != "dask":
        raise ConfigError("scheduler: only used with backend 'dask'")
    meta = dict(meta) if meta is not None else provenance.collect()
    with contextlib.ExitStack() as stack:
        sw = _open(stack, base, points, out, force, meta)
        if progress is not None:
            progress(sw.done_runs, sw.total)
        runs_of = {p.id: c["runs"] for p, c in sw.todo}
        tracker = _Tracker(sw.pdir, runs_of, sw.done_runs, sw.total, progress)
        try:
            for pid, error in _execute(
                sw.todo, sw.pdir, jobs, backend, scheduler, sw.maps, meta, batch_points
            ):
                sw.record(pid, error)
                tracker.finished(pid)
        finally:
            tracker.stop()
        return sw.close(meta)


def point_cost(cfg: Config) -> float:
    """Rough relative cost of a point: steps x runs x (1 + agents)."""
    return float(cfg["steps"]) * cfg["runs"] * (1 + cfg["agents"])


def run_sweeps(
    sweeps: Sequence[tuple[Config, list[Point], str | Path]],
    jobs: int = 1,
    meta: dict[str, Any] | None = None,
    batch_points: bool = True,
    force: bool = False,
) -> list[SweepResult]:
    """Run several sweeps' points in one pool of ``jobs`` workers (joblib).

    As :func:`run_sweep` for each ``(base, points, out)``, but the points of all of them
    share the workers, the costliest first (:func:`point_cost`), so that a large sweep
    never runs on one core while the others idle. Each sweep folder is the same as
    :func:`run_sweep` would write, and resumes the same way; ``batch_points`` as there
    (points of different sweeps never share a batch), ``force`` as there.
    """
    limits.check_jobs(jobs)
    meta = dict(meta) if meta is not None else provenance.collect()
    with contextlib.ExitStack() as stack:
        opened = [_open(stack, base, points, out, force, meta) for base, points, out in sweeps]
        items: list[tuple[Any, Point, Config, Any, Path]] = []
        for i, sw in enumerate(opened):
            ready, failed = _with_maps(sw.todo, sw.maps, sw.pdir)
            for pid, error in failed:
                sw.record(pid, error)
            items += [(i, point, cfg, m, sw.pdir) for point, cfg, m in ready]
        for i, (pid, error) in _pool(_tasks(items, jobs, batch_points), jobs, meta):
            opened[i].record(pid, error)
        return [sw.close(meta) for sw in opened]


def _with_maps(
    todo: list[tuple[Point, Config]], maps: dict[str, Any], pdir: Path
) -> tuple[list[tuple[Point, Config, Any]], list[tuple[str, str]]]:
    """The points whose map loads, with it, and ``(point id, error)`` of those whose map
    does not (recorded as their failure). Maps are loaded here, where relative paths
    mean what the user meant, and shipped to the workers with the task."""
    ready: list[tuple[Point, Config, Any]] = []
    failed: list[tuple[str, str]] = []
    for point, cfg in todo:
        m = _load_map(cfg["map"], maps)
        if isinstance(m, BaseException):
            failed.append((point.id, _record_failure(pdir, point, m)))
        else:
            ready.append((point, cfg, m))
    return ready, failed


#: A task of the pool: ``(tag, [(point, config), ...], map, points folder)``; its points
#: run as shared batches when there are several (:mod:`qpatrol.run.batching`).
Task = tuple[Any, list[tuple[Point, Config]], Any, Path]


def _tasks(items: list[tuple[Any, Point, Config, Any, Path]], jobs: int, batch: bool) -> list[Task]:
    """``(tag, point, config, map, points folder)`` items as tasks: with ``batch``, the
    points of one tag that may share batches are one task, cut by points into smaller
    ones while it costs more than its fair share of the ``jobs`` workers
    (:func:`qpatrol.run.batching.tasks`); else one task per point."""
    if not batch:
        return [(tag, [(point, cfg)], m, pdir) for tag, point, cfg, m, pdir in items]
    from joblib import effective_n_jobs

    from qpatrol.run import batching

    grouped = batching.groups([it[2] for it in items], [it[0] for it in items])
    cost = [point_cost(it[2]) for it in items]
    out: list[Task] = []
    for idx in batching.tasks(grouped, effective_n_jobs(jobs), cost):
        tag, _, _, m, pdir = items[idx[0]]
        out.append((tag, [(items[i][1], items[i][2]) for i in idx], m, pdir))
    return out


def _task_cost(task: Task) -> float:
    return sum(point_cost(cfg) for _, cfg in task[1])


def _pool(
    tasks: list[Task], jobs: int, meta: dict[str, Any]
) -> Iterator[tuple[Any, tuple[str, str | None]]]:
    """Run tasks (:data:`Task`) on ``jobs`` joblib workers, yielding ``(tag, (point id,
    None or one-line error))`` for each point of a task as it finishes. With more than
    one worker the costliest tasks go first (longest-processing-time order, by
    :func:`point_cost`), so that no worker is left with a long task at the end while
    the others idle."""
    if not tasks:
        return
    from joblib import Parallel, delayed, effective_n_jobs

    n = min(effective_n_jobs(jobs), len(tasks))
    # the numpy seconds of each compiled loop's batches, for the choice on a cold cache
    work = coldstart.pool_work((cfg, compiled_loop(cfg)) for t in tasks for _, cfg in t[1])
    if n == 1:
        coldstart.set_pool_work(work)
        try:
            for tag, pts, m, pdir in tasks:
                for outcome in _run_points(pts, m, pdir, meta):
                    yield tag, outcome
        finally:
            coldstart.set_pool_work(None)
        return
    ordered = _distinct_loops_first(sorted(tasks, key=lambda t: -_task_cost(t)))
    # one task at a time (joblib's automatic batching may hand a worker several of the
    # short tasks at the end at once, and the other worker then idles)
    parallel = Parallel(n_jobs=n, backend="loky", return_as="generator_unordered", batch_size=1)
    share = engine_threads.share_of(n)  # the compiled engine's threads of each worker
    for tag, outcomes in parallel(
        delayed(_run_tagged)(tag, pts, m, pdir, meta, share, work) for tag, pts, m, pdir in ordered
    ):
        for outcome in outcomes:
            yield tag, outcome


def _distinct_loops_first(tasks: list[Task]) -> list[Task]:
    """``tasks`` with the first task of each compiled loop
    (:func:`qpatrol.engines.compiled_loop`) moved to the front, in their order, the rest
    after them in theirs. A loop's first use compiles it (tens of seconds when numba's
    on-disk cache does not hold it yet, as on a fresh machine), and every later use
    loads it from the cache: the workers of a pool then start by compiling different
    loops at once, not all the loop of the costliest tasks side by side."""
    first: list[Task] = []
    rest: list[Task] = []
    seen: set[str] = set()
    for task in tasks:
        loop = compiled_loop(task[1][0][1])
        if loop is not None and loop not in seen:
            seen.add(loop)
            first.append(task)
        else:
            rest.append(task)
    return first + rest


def _run_tagged(
    tag: Any,
    pts: list[tuple[Point, Config]],
    m: Any,
    pdir: Path,
    meta: dict[str, Any],
    share: int | None = None,
    work: dict[str, float] | None = None,
) -> tuple[Any, list[tuple[str, str | None]]]:
    engine_threads.set_share(share)
    coldstart.set_pool_work(work)
    return tag, _run_points(pts, m, pdir, meta)


@dataclass
class _Open:
    """A sweep folder set up and locked: what is left to run, and what happened."""

    out: Path
    points: list[Point]
    pdir: Path
    maps: dict[str, Any]
    todo: list[tuple[Point, Config]]
    result: SweepResult
    done_runs: int
    total: int
    ledger: _Ledger

    def record(self, pid: str, error: str | None) -> None:
        if error is None:
            self.result.done.append(pid)
        else:
            self.result.failed.append(pid)
            self.result.errors[pid] = error
        self.ledger.point(pid)

    def close(self, meta: dict[str, Any]) -> SweepResult:
        """Sort the outcome, write ``results.csv`` and ``meta.json``."""
        order = {p.id: p.index for p in self.points}
        self.result.done.sort(key=order.__getitem__)
        self.result.failed.sort(key=order.__getitem__)
        self.result.results = write_results(self.out, self.points)
        atomic.write_text(self.out / provenance.META_FILE, provenance.meta_text(meta))
        self.ledger.wrote(RESULTS_FILE)
        return self.result


class _Ledger:
    """The sweep folder's manifest, kept up to date as the sweep writes: its own files,
    and each point's folder (or ``<id>.failed.json``) as the point finishes."""

    def __init__(self, out: Path, config: str):
        self.out, self.config = out, config

    def wrote(self, *names: str) -> None:
        manifest.add(self.out, "sweep", names, (), self.config, [provenance.META_FILE])

    def point(self, *pids: str) -> None:
        """List each point's folder or failure record, whichever is there now."""
        rels = [f"{POINTS_DIR}/{pid}" for pid in pids]
        manifest.add(self.out, "sweep", [r + FAILED_SUFFIX for r in rels], rels, self.config)


def adoptable(out: Path) -> list[str]:
    """Entries of a sweep folder that its manifest does not list yet but the sweep
    wrote (a point that finished just before the sweep was killed): ``points/<id>``
    with a run manifest of its own and ``points/<id>.failed.json``, for the ids of the
    folder's ``sweep.json`` as the manifest recorded it."""
    try:
        m = manifest.read(out)
    except manifest.ManifestError:
        return []
    if m is None or m.kind != "sweep" or SWEEP_FILE not in m.files:
        return []
    if _sweep_json_changed(out, m):
        return []
    try:
        ids = [str(p["id"]) for p in json.loads((out / SWEEP_FILE).read_text("utf-8"))["points"]]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    found = []
    for pid in ids:
        rel = f"{POINTS_DIR}/{pid}"
        if rel not in m.folders and (out / rel).is_dir() and not (out / rel).is_symlink():
            try:
                sub = manifest.read(out / rel)
            except manifest.ManifestError:
                sub = None
            if sub is not None and sub.kind == "run":
                found.append(rel)
        failed = rel + FAILED_SUFFIX
        if failed not in m.files and (out / failed).is_file():
            found.append(failed)
    return found


def _sweep_json_changed(out: Path, m: manifest.Manifest) -> bool:
    try:
        return manifest.file_entry(out / SWEEP_FILE) != m.files[SWEEP_FILE]
    except OSError:
        return True


def check_target(out: str | Path, force: bool, label: str = "--out") -> None:
    """Check a sweep's output folder before any work (see
    :func:`qpatrol.run.outputs.check_sweep_target`)."""
    out = Path(out)
    outputs.check_sweep_target(out, force, label, also=adoptable(out) if out.is_dir() else [])


def _open(
    stack: contextlib.ExitStack,
    base: Config,
    points: list[Point],
    out: str | Path,
    force: bool,
    meta: dict[str, Any],
) -> _Open:
    """Validate a sweep, lock its folder (until ``stack`` closes), write ``sweep.json``
    and list the points not yet complete."""
    out = Path(out).resolve()
    configs = _point_configs(base, points)
    maps: dict[str, Any] = {}
    for point, cfg in zip(points, configs, strict=True):
        m = _load_map(cfg["map"], maps)
        if not isinstance(m, BaseException):  # a map that does not load fails its point
            try:
                limits.check_config_on_map(cfg, m)
            except ConfigError as e:
                raise ConfigError(f"sweep point {point.id}: {e}") from None
    spec = _describe(base, points)
    check_target(out, force)
    if not force:
        _check_same_sweep(out, spec)  # read-only: a mismatch writes nothing
        _check_points(out, points, configs)
    fresh = not out.exists() or not any(out.iterdir())
    out.mkdir(parents=True, exist_ok=True)
    stack.enter_context(_lock(out))
    if not fresh:
        check_target(out, force)  # again, now that we hold the lock
    pdir = out / POINTS_DIR
    if force:
        manifest.remove(out, keep=(LOCK_FILE,))
    else:
        _check_same_sweep(out, spec)
    ledger = _Ledger(out, manifest.text_digest(json.dumps(spec, sort_keys=True)))
    adopted = adoptable(out)
    if adopted and manifest.read(out) is not None:
        manifest.add(out, "sweep", [a for a in adopted if (out / a).is_file()], adopted)
    if force or not (out / SWEEP_FILE).exists():
        atomic.write_text(out / SWEEP_FILE, json.dumps(spec, indent=2) + "\n")
    _remove_stray_tmp(out)
    pdir.mkdir(exist_ok=True)
    _remove_stray_tmp(pdir)
    ledger.wrote(SWEEP_FILE, LOCK_FILE)
    result = SweepResult(out=out, points=list(points))
    done_runs = 0
    todo: list[tuple[Point, Config]] = []
    for point, cfg in zip(points, configs, strict=True):
        if (pdir / point.id).is_dir():
            (pdir / f"{point.id}{FAILED_SUFFIX}").unlink(missing_ok=True)
            result.skipped.append(point.id)
            done_runs += cfg["runs"]
        else:
            todo.append((point, cfg))
    if result.skipped:
        ledger.point(*result.skipped)
    total = sum(c["runs"] for c in configs)
    return _Open(out, list(points), pdir, maps, todo, result, done_runs, total, ledger)


def _check_points(out: Path, points: list[Point], configs: list[Config]) -> None:
    """Raise ConfigError when a finished point of ``out`` is not what this qpatrol would
    write now: another version wrote it, its config differs, or a file of it changed
    since it was written. Names the points (at most three) and asks for ``--force``."""
    why: list[str] = []
    n = 0
    for point, cfg in zip(points, configs, strict=True):
        d = out / POINTS_DIR / point.id
        if not d.is_dir():
            continue
        try:
            m = manifest.read(d)
            if m is None:
                reason = "no manifest.json"
            elif m.qpatrol != __version__:
                reason = f"written by qpatrol {m.qpatrol}, this is {__version__}"
            elif m.config != manifest.text_digest(cfg.to_yaml()):
                reason = "its config.yaml is not the point's config now"
            else:
                bad = manifest.changed(d)
                reason = f"{bad[0]} changed since it was written" if bad else ""
        except manifest.ManifestError as e:
            reason = str(e)
        if reason:
            n += 1
            if len(why) < 3:
                why.append(f"{point.id}: {reason}")
    if n:
        more = f" and {n - len(why)} more" if n > len(why) else ""
        raise ConfigError(
            f"{out}: {n} finished point{'s differ' if n > 1 else ' differs'} from what this "
            "qpatrol "
            f"would write ({'; '.join(why)}{more}); pass --force to compute the sweep anew, "
            "or choose another output folder"
        )


def read_progress(path: Path) -> float:
    """The share (0..1) of its steps a running point has done, from its progress file."""
    try:
        done, total = path.read_text(encoding="ascii").split()
        return min(1.0, max(0.0, float(done) / float(total))) if float(total) > 0 else 0.0
    except (OSError, ValueError):
        return 0.0


def progress_of(out: str | Path) -> tuple[float, int]:
    """``(runs done, runs in total)`` of a sweep folder, counting the runs of running
    points by their share of steps done (read from the files the workers update)."""
    out = Path(out)
    try:
        spec = json.loads((out / SWEEP_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return 0.0, 0
    base_runs = int((spec.get("base") or {}).get("runs", 1))
    pdir = out / POINTS_DIR
    done, total = 0.0, 0
    for pt in spec.get("points", []):
        runs = int((pt.get("overrides") or {}).get("runs", base_runs))
        total += runs
        if (pdir / pt["id"]).is_dir():
            done += runs
        else:
            done += runs * read_progress(pdir / f".{pt['id']}{PROGRESS_SUFFIX}")
    return done, total


class _Tracker:
    """Reports ``progress(runs_done, runs_total)``: at once when a point finishes, and from
    a background thread about twice a second as running points advance. Never goes
    backwards."""

    def __init__(
        self,
        pdir: Path,
        running: dict[str, int],
        done: float,
        total: int,
        progress: Progress | None,
        every: float = 0.5,
    ):
        self.pdir, self.running, self.done, self.total = pdir, dict(running), done, total
        self.progress = progress
        self._shown = -1.0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if progress is not None:
            self._report(done)
            if running:
                self._thread = threading.Thread(target=self._poll, args=(every,), daemon=True)
                self._thread.start()

    def _report(self, value: float) -> None:
        if self.progress is None:
            return
        with self._lock:
            if value <= self._shown and value < self.total:
                return
            self._shown = max(self._shown, value)
            self.progress(self._shown, self.total)

    def _partial(self) -> float:
        return sum(
            runs * read_progress(self.pdir / f".{pid}{PROGRESS_SUFFIX}")
            for pid, runs in list(self.running.items())
        )

    def _poll(self, every: float) -> None:
        while not self._stop.wait(every):
            self._report(self.done + self._partial())

    def finished(self, pid: str) -> None:
        runs = self.running.pop(pid, 0)
        self.done += runs
        self._report(self.done + self._partial())

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()


def write_results(out: str | Path, points: list[Point]) -> Path:
    """(Re)build ``results.csv`` from the ``summary.json`` of every complete point.

    Columns: ``point``, ``point_id``, one per swept key, ``run``, then the per-run
    measures in the order the summary lists them; a measure named like a swept key
    (``steps``, the steps a run took, when ``steps`` is swept) is written as
    ``<name>_run``. Rows sorted by point, then run.
    """
    out = Path(out)
    swept: list[str] = []
    for p in points:
        swept += [k for k in p.overrides if k not in swept]
    rows: list[dict[str, Any]] = []
    measures: list[str] = []
    for p in sorted(points, key=lambda q: q.index):
        summary_path = out / POINTS_DIR / p.id / "summary.json"
        if not summary_path.is_file():
            continue
        runs = json.loads(summary_path.read_text(encoding="utf-8"))["runs"]
        for r in sorted(runs, key=lambda d: d["run"]):
            r = {(f"{k}_run" if k in swept else k): v for k, v in r.items()}
            measures += [k for k in r if k != "run" and k not in measures]
            row = {"point": p.index, "point_id": p.id}
            row.update({k: _cell(p.overrides.get(k)) for k in swept})
            # a list measure (summary.json's failed_robots) as one cell: joined by "+"
            row.update({k: _cell(v) if isinstance(v, list) else v for k, v in r.items()})
            rows.append(row)
    columns = ["point", "point_id", *swept, "run", *measures]
    df = pd.DataFrame(rows, columns=columns)
    target = out / RESULTS_FILE
    atomic.write_text(target, to_csv_text(df))  # records.FLOAT_FORMAT, Unix newlines
    return target


def _cell(v: Any) -> Any:
    """A swept value as a CSV cell: lists joined by ``+``, everything else as is."""
    return _fmt_value(v) if isinstance(v, list | tuple) else v


# --------------------------------------------------------------------------- internals


def _point_configs(base: Config, points: list[Point]) -> list[Config]:
    """The resolved config of each point; bad or duplicate points raise ConfigError."""
    seen_index: set[int] = set()
    seen_id: set[str] = set()
    configs = []
    for p in points:
        if p.index in seen_index:
            raise ConfigError(f"sweep: point index {p.index} used twice")
        if p.id in seen_id:
            raise ConfigError(f"sweep: point id {p.id} used twice")
        if p.index < 0:
            raise ConfigError(f"sweep: point index {p.index} is negative")
        seen_index.add(p.index)
        seen_id.add(p.id)
        try:
            configs.append(base.replace(**p.overrides))
        except ConfigError as e:
            raise ConfigError(f"sweep point {p.id}: {e}") from None
    if not configs:
        raise ConfigError("sweep: no points to run")
    return configs


def _describe(base: Config, points: list[Point]) -> dict[str, Any]:
    """The content of ``sweep.json``, normalised through JSON.

    ``maps`` holds a hash of each map file the sweep uses, so a map edited between a
    run and its resume is noticed instead of mixing old and new results.
    """
    spec = {
        "format": _FORMAT,
        "base": base.tree(),
        "points": [p.describe() for p in points],
        "maps": _map_hashes(
            [base["map"], *(p.overrides["map"] for p in points if "map" in p.overrides)]
        ),
    }
    return json.loads(json.dumps(spec))


def _map_hashes(names: list[str]) -> dict[str, str | None]:
    """Map name or path -> sha256 prefix of its file (None if it cannot be read)."""
    hashes: dict[str, str | None] = {}
    for name in sorted(set(map(str, names))):
        try:
            hashes[name] = hashlib.sha256(resolve_map(name).read_bytes()).hexdigest()[:16]
        except (MapError, OSError):
            hashes[name] = None
    return hashes


def _flat(tree: Any, prefix: str = "") -> dict[str, Any]:
    if not isinstance(tree, Mapping):
        return {prefix.rstrip("."): tree}
    flat: dict[str, Any] = {}
    for k, v in tree.items():
        flat.update(_flat(v, f"{prefix}{k}."))
    return flat


def _check_same_sweep(out: Path, spec: dict[str, Any]) -> None:
    """Raise ConfigError if ``out`` holds something other than this sweep."""
    path = out / SWEEP_FILE
    hint = "pass --force to start over, or choose another output folder"
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out} exists and is not a folder; choose another output folder")
    if not path.exists():
        if out.is_dir() and (out / POINTS_DIR).exists():
            raise ConfigError(f"{out} has a points/ folder but no {SWEEP_FILE}; {hint}")
        return
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ConfigError(f"{path}: unreadable ({e}); {hint}") from None
    if not isinstance(old, dict) or old.get("format") != _FORMAT:
        raise ConfigError(f"{path}: not a qpatrol sweep description; {hint}")
    why = _difference(old, spec)
    if why:
        raise ConfigError(f"{out} holds a different sweep ({why}); {hint}")


def _difference(old: dict[str, Any], new: dict[str, Any]) -> str:
    """A short phrase naming the first difference between two sweep descriptions."""
    a, b = _flat(old.get("base")), _flat(new["base"])
    for key in [*b, *(k for k in a if k not in b)]:
        if a.get(key, "<unset>") != b.get(key, "<unset>"):
            return f"base {key}: {a.get(key, '<unset>')!r} there, {b.get(key, '<unset>')!r} now"
    old_maps = old.get("maps", new["maps"])
    for name, digest in new["maps"].items():
        if old_maps.get(name, digest) != digest:
            return f"map {name} has changed since the sweep started"
    pa, pb = old.get("points"), new["points"]
    if pa == pb:
        return ""
    if not isinstance(pa, list) or len(pa) != len(pb):
        n = len(pa) if isinstance(pa, list) else "?"
        return f"{n} points there, {len(pb)} now"
    for x, y in zip(pa, pb, strict=True):
        if x != y:
            there = x.get("id") if isinstance(x, dict) else x
            return f"point {there} there, {y['id']} now"
    return "points differ"


@contextlib.contextmanager
def _lock(out: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``out`` so two sweeps never share a folder."""
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock
        yield
        return
    fd = os.open(out / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ConfigError(f"{out}: another sweep is running in this folder") from None
        yield
    finally:
        os.close(fd)


def _remove_stray_tmp(folder: Path) -> None:
    """Remove ``.NAME.*.tmp`` files and folders left by a killed sweep."""
    for p in folder.glob(".*.tmp"):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)


def _execute(
    todo: list[tuple[Point, Config]],
    pdir: Path,
    jobs: int,
    backend: str,
    scheduler: str | None,
    maps: dict[str, Any] | None = None,
    meta: dict[str, Any] | None = None,
    batch: bool = True,
) -> Iterator[tuple[str, str | None]]:
    """Run the points, yielding ``(point id, None or one-line error)`` as each finishes."""
    if not todo:
        return
    ready, failed = _with_maps(todo, {} if maps is None else maps, pdir)
    yield from failed
    if not ready:
        return
    tasks = _tasks([(None, point, cfg, m, pdir) for point, cfg, m in ready], jobs, batch)
    if backend == "dask":
        yield from _execute_dask(tasks, pdir, jobs, scheduler, meta or {})
        return
    for _, outcome in _pool(tasks, jobs, meta or {}):
        yield outcome


def _execute_dask(
    tasks: list[Task],
    pdir: Path,
    jobs: int,
    scheduler: str | None,
    meta: dict[str, Any] | None = None,
) -> Iterator[tuple[str, str | None]]:
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise ConfigError(
            "backend 'dask' needs dask.distributed: pip install 'qpatrol[dask]'"
        ) from None
    cluster = None
    if scheduler is None:
        from joblib import effective_n_jobs

        cluster = LocalCluster(
            n_workers=min(effective_n_jobs(jobs), len(tasks)),
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
        )
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout="30s")
        except (OSError, TimeoutError, ValueError) as e:
            raise ConfigError(f"scheduler: cannot connect to {scheduler} ({e})") from None
    try:
        # one thread per task: a dask worker may share its machine with others
        futures = {
            client.submit(_run_tagged, None, pts, m, pdir, meta, 1, pure=False): pts
            for _, pts, m, _ in sorted(tasks, key=lambda t: -_task_cost(t))
        }
        for fut in as_completed(futures):
            try:
                yield from fut.result()[1]
            except Exception as e:  # the worker died (KilledWorker, ...), not the run
                for point, _ in futures[fut]:
                    yield point.id, _record_failure(pdir, point, e)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _load_map(name: str, cache: dict[str, Any]) -> Any:
    """The Map for ``name``, or the exception loading it raised (cached either way)."""
    if name not in cache:
        from qpatrol.maps import get_map

        try:
            cache[name] = get_map(name)
        except Exception as e:  # MapError, OSError: recorded as the point's failure
            cache[name] = e
    return cache[name]


class _ProgressFile:
    """``progress(done, total)`` for a worker: writes ``done total`` to a small file at
    most every ``every`` seconds, which the main process reads (any backend, as long as
    it shares the sweep folder)."""

    def __init__(self, path: Path, every: float = 0.5):
        self.path, self.every, self._last = path, every, 0.0

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if now - self._last < self.every and done < total:
            return
        self._last = now
        tmp = self.path.with_name(self.path.name + ".w.tmp")
        with contextlib.suppress(OSError):
            tmp.write_text(f"{done} {total}\n", encoding="ascii")
            os.replace(tmp, self.path)

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)


def _run_point(
    point: Point, cfg: Config, m: Any, pdir: Path, meta: dict[str, Any] | None = None
) -> tuple[str, str | None]:
    """Run one point fully and write its folder (in a worker); errors become a
    ``<id>.failed.json`` and are returned as one line."""
    from qpatrol import world
    from qpatrol.run import simulate, write_run

    info = {**(meta or {}), "started": provenance.now(), "ended": None, "point": point.describe()}
    tick = _ProgressFile(pdir / f".{point.id}{PROGRESS_SUFFIX}")
    try:
        result = simulate(
            cfg, point=point.index, prepared=(m, world.make_params(cfg, m)), progress=tick
        )
        write_run(result, pdir / point.id, meta=info)
    except Exception as e:
        return point.id, _record_failure(pdir, point, e)
    finally:
        tick.remove()
    (pdir / f"{point.id}{FAILED_SUFFIX}").unlink(missing_ok=True)
    return point.id, None


def _run_points(
    pts: list[tuple[Point, Config]], m: Any, pdir: Path, meta: dict[str, Any] | None = None
) -> list[tuple[str, str | None]]:
    """Run a task's points and write their folders (in a worker): one point as
    :func:`_run_point`, several as shared batches (:func:`qpatrol.run.batching.run_group`).
    Returns ``(point id, None or one-line error)`` per point; a batch that raises fails
    every point of the task not yet written (each gets its ``<id>.failed.json``)."""
    if len(pts) == 1:
        return [_run_point(pts[0][0], pts[0][1], m, pdir, meta)]
    from qpatrol.run import batching, write_run

    started = provenance.now()
    ticks = {p.id: _ProgressFile(pdir / f".{p.id}{PROGRESS_SUFFIX}") for p, _ in pts}
    outcome: dict[str, str | None] = {}

    def write(point: Point, result: Any) -> None:
        info = {**(meta or {}), "started": started, "ended": None, "point": point.describe()}
        try:
            write_run(result, pdir / point.id, meta=info)
        except Exception as e:  # e.g. Q-values not finite: this point fails alone
            outcome[point.id] = _record_failure(pdir, point, e)
        else:
            (pdir / f"{point.id}{FAILED_SUFFIX}").unlink(missing_ok=True)
            outcome[point.id] = None
        ticks[point.id](1, 1)  # done: counted as complete until the task returns

    def progress(point: Point, done: int, total: int) -> None:
        ticks[point.id](done, total)

    try:
        batching.run_group([(p, p.index, cfg) for p, cfg in pts], m, write, progress)
    except Exception as e:
        for p, _ in pts:
            if p.id not in outcome:
                outcome[p.id] = _record_failure(pdir, p, e)
    finally:
        for tick in ticks.values():
            tick.remove()
    return [(p.id, outcome[p.id]) for p, _ in pts]


def _record_failure(pdir: Path, point: Point, e: BaseException) -> str:
    """Write ``<id>.failed.json`` for an exception; return its one-line message."""
    message = str(e).splitlines()[0] if str(e) else ""
    info = {
        "point": point.index,
        "id": point.id,
        "overrides": point.overrides,
        "error": type(e).__name__,
        "message": str(e),
        "traceback": "".join(traceback.format_exception(e)),
    }
    atomic.write_text(
        pdir / f"{point.id}{FAILED_SUFFIX}", json.dumps(info, indent=2, default=str) + "\n"
    )
    return f"{type(e).__name__}: {message}" if message else type(e).__name__
