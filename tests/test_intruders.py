"""The intruder measures ``capture_random`` and ``capture_observer`` (docs/model.md,
"Intruders"), in each engine on its own.

* **Closed forms on a ring.** K cyclic robots gathered on a ring of n = 12 cells, one
  every g = n / K cells, each advancing a cell a step. In the D steps after any step a
  the robots stand on min(K D, n) distinct cells, so ``capture_random`` =
  min(D, g) / g whatever the window; every departure leaves its cell empty for g - 1
  steps, so ``capture_observer`` = 1 if D >= g - 1 else 0, at cell 0 (the lowest cell,
  as every cell departs in any g steps).
* **A brute-force recount** from ``trajectory.csv`` (and the start cells, from the
  run's stream), with plain loops over every (target, step) pair and every departure,
  on maps the other tests never use: random mazes (a tree, one with loops), a patrol
  graph with waypoints, collisions off, the battery on.

Deliberately broken rules each of these catches, in the numpy engine
(``qpatrol/measures``) and the compiled one (``engines/compiled/observe.py``): the
random window one step short (``max(e - 1, w)`` -> ``max(e, w)``: closed forms and
recount); a departure caught only strictly inside D (``b - e > d`` -> ``>= d``: closed
form at D = g - 1); departures counted from ``warmup + 1`` (recount); departures counted
up to ``S - D - 1`` only (recount); random intruders from ``warmup + 1`` (closed forms,
recount); one pair too few per target (``S - D - w``: closed forms); arrivals counted
after departures (recount: a robot following another into its cell makes a spurious
departure).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from qpatrol import measures, world
from qpatrol.config import ConfigError, from_flat, load_config
from qpatrol.maps import get_map
from qpatrol.run import simulate, write_run
from qpatrol.world.rng import Streams, run_keys

RING12 = "....\n.##.\n.##.\n....\n"
N = 12

ENGINES = ["numpy", "numba"]


def engine_or_skip(engine: str) -> None:
    if engine == "numba":
        pytest.importorskip("numba")


def write(tmp_path: Path, text: str, name: str = "m.txt") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_closed_forms_on_a_ring(tmp_path, engine, k):
    """K cyclic robots on the 12-ring, gathered during a warm-up of 5 laps, then 4 laps
    measured (S = 108, w = 60): both measures for every D from 1 to 50 (from D = 49 no
    intruder fits: None)."""
    engine_or_skip(engine)
    g = N // k
    w, s = 5 * N, 9 * N
    cfg = from_flat(
        {
            "map": write(tmp_path, RING12),
            "agents": k,
            "policy": "cyclic",
            "battery.enabled": False,
            "record.warmup": w,
            "steps": s,
            "security.attack_steps": list(range(1, 51)),
            "engine": engine,
        }
    )
    r = simulate(cfg)
    assert r.engine == engine
    row = r.summary[0]
    for d in range(1, 51):
        rand, obs, cell = (row[key] for key in measures.attack_names(d))
        if d > s - w:
            assert rand is None and obs is None and cell is None
            continue
        assert rand == min(d, g) / g, d
        assert obs == (1.0 if d >= g - 1 else 0.0), d
        if s - d - w + 1 >= g:  # every cell departs inside the window
            assert cell == 0, d


def occupancy_from_trajectory(folder: Path, run: int, starts: np.ndarray, n_cells: int, steps: int):
    """bool ``[S + 1, C]``: the cells a robot stands on at the end of each step (row 0:
    the start), from ``trajectory.csv`` (a cell of -1: no robot)."""
    tr = pd.read_csv(folder / "trajectory.csv")
    tr = tr[(tr["run"] == run) & (tr["cell"] >= 0)]
    occ = np.zeros((steps + 1, n_cells), dtype=bool)
    occ[tr["step"].to_numpy(), tr["cell"].to_numpy()] = True
    occ[0, starts] = True
    return occ


def recount(occ: np.ndarray, targets: np.ndarray, w: int, d: int):
    """The two measures by their definitions, with plain loops."""
    s = occ.shape[0] - 1
    pairs = caught = 0
    for c in targets:
        for a in range(w, s - d + 1):
            pairs += 1
            caught += bool(occ[a + 1 : a + d + 1, c].any())
    rand = caught / pairs if pairs else None
    worst = None
    for c in targets:
        departures = [a for a in range(max(w, 1), s - d + 1) if occ[a - 1, c] and not occ[a, c]]
        if departures:
            frac = sum(bool(occ[a + 1 : a + d + 1, c].any()) for a in departures) / len(departures)
            if worst is None or frac < worst[0]:
                worst = (frac, int(c))
    return rand, (None, None) if worst is None else worst


UNSEEN = {
    # a tree of dead ends, 4 conscientious robots, warm-up 0 (the start counts)
    "tree": ({"policy": "conscientious", "agents": 4, "record.warmup": 0}, ("maze", 4, 5, 31, 0.0)),
    # a maze with loops, 3 random walkers that may share cells
    "shared": (
        {"policy": "random", "agents": 3, "team.avoid_collisions": False, "record.warmup": 7},
        ("maze", 4, 4, 32, 0.4),
    ),
    # learners with the battery on (stations, queues, pushes)
    "battery": (
        {"policy": "qlearning", "agents": 3, "battery.enabled": True, "record.warmup": 1},
        ("maze", 4, 5, 33, 0.3),
    ),
    # two of four robots fail at step 90: they stand nowhere from then on, and the window
    # starts there
    "failures": (
        {
            "policy": "conscientious",
            "agents": 4,
            "record.warmup": 3,
            "failures.robots": 2,
            "failures.at": 90,
        },
        ("maze", 5, 4, 34, 0.2),
    ),
    # a patrol graph: waypoints are not targets
    "graph": ({"policy": "cc", "agents": 3, "record.warmup": 5}, ("graph", "maps/ps_example.txt")),
}


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("case", sorted(UNSEEN))
def test_a_brute_force_recount_from_the_trajectory(tmp_path, engine, case):
    """Both measures, for the default durations and a few more, equal a recount from
    ``trajectory.csv`` exactly, run by run."""
    engine_or_skip(engine)
    from mazes import random_maze

    keys, (kind, *spec) = UNSEEN[case]
    if kind == "maze":
        rows, cols, seed, loops = spec
        path = write(tmp_path, random_maze(rows, cols, seed, loops=loops))
    else:
        path = str(Path(__file__).resolve().parents[1] / spec[0])
    steps = 260
    flat = {
        "map": path,
        "runs": 2,
        "steps": steps,
        "record.trajectory": steps,
        "engine": engine,
        "battery.enabled": False,
        **keys,
    }
    m = get_map(path)
    durations = [1, 2, 3, *measures.attack_steps("auto", m.n_targets), steps - 40]
    cfg = from_flat({**flat, "security.attack_steps": durations})
    res = simulate(cfg)
    assert res.engine == engine
    out = tmp_path / "run"
    write_run(res, out)
    summary = json.loads((out / "summary.json").read_text())["runs"]
    streams = Streams(run_keys(cfg["seed"], cfg["runs"]), res.params.n_agents)
    starts = [world.place_agents(res.params, m, g) for g in streams.generators]
    targets = np.flatnonzero(res.params.target)
    w = max(cfg["record.warmup"], cfg["failures.at"])  # the window starts at a failure
    for i, row in enumerate(summary):
        occ = occupancy_from_trajectory(out, row["run"], starts[i], m.n_cells, steps)
        for d in sorted(set(durations)):
            rand, (obs, cell) = recount(occ, targets, w, d)
            k_rand, k_obs, k_cell = measures.attack_names(d)
            assert (row[k_rand], row[k_obs], row[k_cell]) == (rand, obs, cell), (case, i, d)


def test_attack_steps_auto_and_validation(tmp_path):
    """``auto`` gives T/8, T/4, T/2, T and 2T rounded up (the 12-ring: 2, 3, 6, 12, 24);
    a duration below 1 is refused naming the key; [] (the default) turns the measures off,
    and the security study's config turns them on."""
    assert measures.attack_steps("auto", 12) == (2, 3, 6, 12, 24)
    assert measures.attack_steps("auto", 1) == (1, 2)
    assert measures.attack_steps([30, 5, 5], 12) == (5, 30)
    for bad in ([0], [-3], "soon", [1.5], True):
        with pytest.raises(ConfigError, match=r"^security\.attack_steps: got .* allowed: auto"):
            from_flat({"security.attack_steps": bad})
    base = {
        "map": write(tmp_path, RING12),
        "agents": 1,
        "policy": "cyclic",
        "steps": 40,
        "battery.enabled": False,
    }
    row = simulate(from_flat({**base, "security.attack_steps": "auto"})).summary[0]
    assert [k for k in row if k.startswith("capture_random")] == [
        f"capture_random_d{d}" for d in (2, 3, 6, 12, 24)
    ]
    off = simulate(from_flat(base)).summary[0]
    assert not [k for k in off if k.startswith("capture")]
    assert load_config("security")["security.attack_steps"] == "auto"
