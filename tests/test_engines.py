"""The compiled engine writes the numpy engine's files to the bit, on every config.

Configs run through both loops: those of the compiled strategies
(:data:`qpatrol.engines.COMPILED_POLICIES`) must run compiled, the rest must fall back
to the numpy engine and say so. Every file of the run folder is compared byte for byte;
in ``meta.json`` only ``engine`` (which engine and loop ran) may differ.
"""

from __future__ import annotations

import json
from pathlib import Path

import mazes
import numpy as np
import pytest
from covering import BOTH2, BOTH3, covers_every_pair, pairs

from qpatrol import engines, world
from qpatrol.config import ConfigError, from_flat
from qpatrol.run import checkpoint as ck
from qpatrol.run import simulate, write_run
from qpatrol.strategies import NAMES

pytest.importorskip("numba")

META = {"started": "-", "ended": "-"}
ENGINE_FIELDS = ("engine",)


@pytest.fixture
def crowded(monkeypatch):
    """Teams denser than the battery room rule allows (:func:`world.check_battery_room`):
    the engines must agree on every config, and crowded dead ends take the most rules."""
    monkeypatch.setattr(world, "check_battery_room", lambda *a: None)


def both(flat: dict, tmp_path: Path, strategy: bool = False) -> tuple[str, str]:
    """Run ``flat`` on both engines, compare every file (and with ``strategy`` every
    array of the strategy object after the run); ``(engine, note)`` of numba's."""
    folders = {}
    ran = {}
    objs = {}
    for engine in ("numpy", "numba"):
        result = simulate(from_flat({**flat, "engine": engine}))
        ran[engine] = (result.engine, result.engine_note)
        objs[engine] = result.strategy
        folders[engine] = write_run(result, tmp_path / engine, replace=True, meta=META)
    if strategy:
        same_arrays(objs["numpy"], objs["numba"])
    same_files(folders["numpy"], folders["numba"], flat)
    assert ran["numpy"] == ("numpy", "")
    return ran["numba"]


def same_files(a: Path, b: Path, flat: dict) -> None:
    """Every file of run folders ``a`` and ``b`` is the same (meta.json: but the engine)."""
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for name in names:
        if name == "meta.json":
            ma, mb = (json.loads((f / name).read_text()) for f in (a, b))
            for key in ENGINE_FIELDS:
                ma.pop(key, None), mb.pop(key, None)
            assert ma == mb
        else:
            assert (a / name).read_bytes() == (b / name).read_bytes(), (flat, name)


def same_arrays(a: object, b: object) -> None:
    """Every array attribute of ``a`` and ``b`` equal in dtype, shape and values."""
    va, vb = vars(a), vars(b)
    names = sorted(k for k, v in va.items() if isinstance(v, np.ndarray))
    assert names == sorted(k for k, v in vb.items() if isinstance(v, np.ndarray))
    for name in names:
        x, y = va[name], vb[name]
        assert (x.dtype, x.shape) == (y.dtype, y.shape), name
        assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name


BASE = {"runs": 2, "seed": 11, "steps": 160, "max_episode_steps": 60, "record.trajectory": 5}


#: (agents, communication, avoid collisions, battery): each team size with two rows whose
#: booleans are each other's complement; every pair of values of any two columns occurs.
QLEARNING_TEAMS = pairs(
    [(1, 2, 4, 8), (True, False), (True, False), (True, False)],
    [
        (k, *row)
        for k, first in zip((1, 2, 4, 8), BOTH3, strict=True)
        for row in (first, tuple(not b for b in first))
    ],
)


@pytest.mark.parametrize("agents, communication, avoid, battery", QLEARNING_TEAMS)
def test_compiled_qlearning_teams(rooms_map, tmp_path, agents, communication, avoid, battery):
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": agents,
        "battery.enabled": battery,
        "battery.capacity": 30,
        "battery.charge_steps": 4,
        "team.communication": communication,
        "team.avoid_collisions": avoid,
        "steps": 300,
    }
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("agents", [3, 6])
def test_compiled_battery_on_dead_end_stations(crowded, tmp_path, seed, agents):
    """Station pockets, queues, homing yields and pushes: random tree-like mazes."""
    path = tmp_path / "maze.txt"
    path.write_text(mazes.random_maze(5, 6, seed, loops=0.1 * seed, stations=2))
    flat = {
        **BASE,
        "map": str(path),
        "agents": agents,
        "battery.capacity": 90,
        "battery.charge_steps": 3 * (seed - 1),
        "battery.initial_charge": "full" if seed == 1 else "staggered",
        "steps": 900,
        "max_episode_steps": 300,
    }
    assert both(flat, tmp_path) == ("numba", "")


def test_compiled_crowded_dead_end_floor(crowded, tmp_path):
    """Eight learners on a 62-cell floor of one-wide corridors with both stations at the
    ends of dead ends: token holders offered only the moves a push makes room for
    (the steps that froze the old rules)."""
    path = tmp_path / "floor.txt"
    path.write_text(mazes.random_maze(5, 6, 6, loops=0.08))
    flat = {**BASE, "map": str(path), "agents": 8, "steps": 2500, "runs": 2}
    flat.update({"battery.capacity": 200, "battery.charge_steps": 20})
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize(
    "extra",
    [
        {"learning.epsilon": 0.3, "learning.state_space": "cell", "record.warmup": 20},
        {"episodes": 2, "max_episode_steps": None, "steps": 900, "agents": 3},
        {"learning.gamma": 0.9, "learning.multiplier": 100.0, "reward.lambda": 0.5},
    ],
)
def test_compiled_qlearning_settings(tmp_path, extra):
    flat = {**BASE, "map": "map_b", "agents": 2, "battery.enabled": False, **extra}
    assert both(flat, tmp_path) == ("numba", "")


LONE = [
    {},
    {"team.avoid_collisions": False, "runs": 3},
    {"team.communication": False, "learning.epsilon": 0.3, "learning.state_space": "cell"},
    {"record.warmup": 20, "record.trajectory": 0, "learning.q_init.east": 2.0},
    {"episodes": 2, "max_episode_steps": None, "steps": 900},
    {"learning.gamma": 0.9, "reward.lambda": 0.5, "reward.idle_horizon": 7},
]


@pytest.mark.parametrize("extra", LONE)
def test_compiled_lone_qlearner(rooms_map, tmp_path, loop_specs, extra):
    """A lone Q-learning robot without battery runs in the compiled loop for it
    (numba_core._solo_qlearning): the numpy engine's files, to the bit."""
    from qpatrol.engines import numba_core

    flat = {**BASE, "map": str(rooms_map), "agents": 1, "battery.enabled": False, **extra}
    assert both(flat, tmp_path) == ("numba", "")
    assert loop_specs == [numba_core.SPEC_QLEARNING_SOLO]


def test_lone_qlearner_episodes_of_different_lengths(ring_map, tmp_path):
    """Runs whose episodes end at different steps (the ring's dots all eaten, or 12
    steps up), so that their episodes start at different steps."""
    flat = {**BASE, "map": str(ring_map), "agents": 1, "runs": 6, "max_episode_steps": 12}
    assert both({**flat, "steps": 300, "battery.enabled": False}, tmp_path) == ("numba", "")


def test_lone_qlearner_without_moves(tmp_path):
    """A one-cell map (collision avoidance off, else it is refused): its robot has no
    move and waits on every step."""
    one = tmp_path / "one.txt"
    one.write_text("; name: one\n#0#\n")
    flat = {**BASE, "map": str(one), "agents": 1, "battery.enabled": False}
    assert both({**flat, "team.avoid_collisions": False}, tmp_path) == ("numba", "")


TEAM = [  # (settings, team size, the right of way pushes robots aside in these runs)
    ({}, 4, True),
    ({"team.avoid_collisions": False, "runs": 3}, 3, False),
    (
        {"team.communication": False, "learning.epsilon": 0.3, "learning.state_space": "cell"},
        4,
        False,
    ),
    ({"record.warmup": 20, "record.trajectory": 0, "learning.q_init.east": 2.0}, 2, False),
    ({"episodes": 2, "max_episode_steps": None, "steps": 900}, 3, False),
    ({"learning.gamma": 0.9, "reward.lambda": 0.5, "reward.idle_horizon": 7}, 8, True),
]


@pytest.mark.parametrize("extra, agents, pushing", TEAM)
def test_compiled_qlearning_team(
    rooms_map, tmp_path, monkeypatch, loop_specs, extra, agents, pushing
):
    """Q-learning teams without battery run in the compiled loop for them
    (numba_core._team_qlearning): the numpy engine's files and Q-tables, to the bit,
    in runs with and without the right of way's pushes."""
    from qpatrol.engines import numba_core
    from qpatrol.world import traffic

    pushes = []
    push = traffic._push_path

    def counted(*args, **kwargs):
        path = push(*args, **kwargs)
        pushes.append(path is not None and len(path) > 1)
        return path

    monkeypatch.setattr(traffic, "_push_path", counted)
    flat = {**BASE, "map": str(rooms_map), "agents": agents, "battery.enabled": False, **extra}
    assert both(flat, tmp_path, strategy=True) == ("numba", "")
    assert loop_specs == [numba_core.SPEC_QLEARNING_TEAM]
    if pushing:
        assert any(pushes)


def test_compiled_loop_specializations(loop_specs):
    """Which compiled loop a batch runs: the lone Q-learner's loop, the Q-learning
    team's loop, the Q-learning loop (Q-update recorders), or the loop for any
    strategy (battery, timeline, other strategies)."""
    from qpatrol.engines import numba_core
    from qpatrol.run import bench, simulate

    cases = [
        ({}, 1, numba_core.SPEC_QLEARNING_SOLO),
        ({}, 4, numba_core.SPEC_QLEARNING_TEAM),
        ({"record.transitions": True}, 1, numba_core.SPEC_QLEARNING),
        ({"record.watch": [3]}, 4, numba_core.SPEC_QLEARNING),
        ({"record.timeline": 10}, 1, numba_core.SPEC_ANY),
        ({"battery.enabled": True}, 1, numba_core.SPEC_ANY),
        ({"policy": "random"}, 1, numba_core.SPEC_ANY),
    ]
    for extra, agents, spec in cases:
        loop_specs.clear()
        cfg = bench.workload(2, agents, 20, engine="numba", extra=extra)
        simulate(cfg)
        assert loop_specs == [spec], (extra, agents)
        # read from the config alone, for a pool to compile different loops at once
        assert engines.compiled_loop(cfg) == numba_core.SPEC_NAMES[spec], (extra, agents)
    assert engines.compiled_loop(bench.workload(2, 1, 20, engine="numpy")) is None
    assert engines.compiled_loop(bench.workload(1, 1, 20, engine="auto")) is None  # small


@pytest.mark.parametrize("policy", NAMES)
@pytest.mark.parametrize("battery", [True, False])
def test_every_strategy_and_battery(rooms_map, tmp_path, policy, battery):
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": 2,
        "policy": policy,
        "battery.enabled": battery,
        "battery.capacity": 40,
        "battery.charge_steps": 5,
        "steps": 120,
    }
    engine, note = both(flat, tmp_path)
    if policy in engines.COMPILED_POLICIES:
        assert (engine, note) == ("numba", "")
    else:
        assert engine == "numpy" and note.startswith("fallback from numba")


@pytest.mark.parametrize(
    "record",
    [
        {"record.watch": [3, 4, 17]},
        {"record.transitions": True, "learning.state_space": "cell"},
        {"record.transitions": True, "record.watch": [5], "agents": 4},
    ],
)
@pytest.mark.parametrize("battery", [True, False])
def test_recorders(rooms_map, tmp_path, record, battery):
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": 2,
        "battery.enabled": battery,
        "battery.capacity": 30,
        "steps": 300,
        **record,
    }
    assert both(flat, tmp_path) == ("numba", "")


def test_the_compiled_strategies_are_the_ones_the_engine_choice_names():
    """``engines.COMPILED_POLICIES`` (read without numba) lists the strategy files of
    ``engines.compiled``; every strategy is compiled."""
    from qpatrol.engines import compiled

    assert set(engines.COMPILED_POLICIES) == set(compiled.MODULES) == set(NAMES)


def test_the_kernels_wall_masks():
    """``choice.legal_bits`` (each cell's legal moves as N=1, E=2, S=4, W=8) and
    ``choice.MASKED`` (0.0 or -inf per direction of a mask), with which the Q-learning
    kernels take the greatest Q of some moves with no branch: by hand on a tiny map, and
    against a plain loop over the mask's directions for every mask."""
    from qpatrol.engines.compiled.choice import MASKED, legal_bits

    # cells: 0 open to the east and the south, 1 to the west, 2 to the north, 3 nowhere
    nbrs = np.array([[-1, 1, 2, -1], [-1, -1, -1, 0], [0, -1, -1, -1], [-1, -1, -1, -1]])
    assert legal_bits(nbrs).tolist() == [2 + 4, 8, 1, 0]
    assert legal_bits(nbrs).dtype == np.int64
    assert MASKED[0b0101].tolist() == [0.0, -np.inf, 0.0, -np.inf]
    rng = np.random.default_rng(7)
    for b in range(16):
        for q in (rng.normal(size=4) * 100, np.array([-0.0, 0.0, 2.5, 2.5])):
            want = max([q[d] for d in range(4) if b >> d & 1], default=-np.inf)
            got = max(
                max(q[0] + MASKED[b, 0], q[1] + MASKED[b, 1]),
                max(q[2] + MASKED[b, 2], q[3] + MASKED[b, 3]),
            )
            assert got == want
            ties = [d for d in range(4) if b >> d & 1 and q[d] + MASKED[b, d] == got]
            assert ties == [d for d in range(4) if b >> d & 1 and q[d] == want]


def test_both_forms_of_the_compiled_choice_choose_alike():
    """``qlearning.choose`` finds its candidates with a branch per move (a lone robot's
    loop) or without (a team's): for every mask of open moves, every pattern of ties
    among the Q-values, exploring or not and any tie-break uniform, both forms give the
    move the numpy learner gives (``learner.choose``: the j-th candidate, j = floor(u x
    candidates)), and ``best_of`` the greatest Q of the open moves."""
    pytest.importorskip("numba")
    from numba import njit

    from qpatrol.engines.compiled import qlearning
    from qpatrol.strategies import learner

    @njit
    def both(q_f, free, explore, u):
        best = qlearning.best_of(q_f, 0, free)
        a = qlearning.choose(q_f, 0, free, best, explore, u, True)
        b = qlearning.choose(q_f, 0, free, best, explore, u, False)
        return best, a, b

    for free in range(16):
        for pattern in range(81):  # each move's Q one of three values: every tie
            q = np.array([float(pattern // 3**d % 3) - 1.0 for d in range(4)])
            for explore in (False, True):
                for u in (0.0, 0.34, 0.5, 0.99):
                    best, a, b = both(q, free, explore, u)
                    open_ = np.array([[free >> d & 1 == 1 for d in range(4)]])
                    e = np.array([0.0 if explore else 1.0])  # u_explore < epsilon 0.5
                    action, has = learner.choose(q[None], open_, e, np.array([u]), 0.5)
                    want = int(action[0]) if has[0] else -1
                    assert a == b == want, (free, q, explore, u)
                    assert best == max((q[d] for d in range(4) if free >> d & 1), default=-np.inf)


def test_engine_choice(monkeypatch):
    cfg = from_flat({"battery.enabled": False, "engine": "numpy", "runs": 16})
    assert engines.choose(cfg) == ("numpy", "")
    assert engines.choose(cfg.replace(engine="auto")) == ("numba", "")
    small = cfg.replace(engine="auto", runs=1, steps=300)
    assert engines.choose(small)[0] == "numpy" and "small batch" in engines.choose(small)[1]
    assert engines.choose(small.replace(engine="numba")) == ("numba", "")
    monkeypatch.setattr(engines, "numba_installed", lambda: False)
    assert engines.choose(cfg.replace(engine="auto")) == ("numpy", "numba not installed")
    with pytest.raises(ConfigError, match="engine: numba is not installed"):
        engines.choose(cfg.replace(engine="numba"))


def test_engine_is_not_part_of_the_experiment():
    a = from_flat({"engine": "numpy"})
    b = from_flat({"engine": "numba"})
    assert a.digest() == b.digest() and a.to_yaml() == b.to_yaml()
    assert "engine" not in a.to_yaml()


@pytest.mark.parametrize(
    "agents, battery, window",
    pairs(
        [(1, 4), (True, False), (7, 50)],
        [(1, True, 7), (1, False, 50), (4, True, 50), (4, False, 7)],
    ),
)
def test_compiled_timeline(rooms_map, tmp_path, agents, battery, window):
    """``record.timeline`` (idleness in windows), including a short last window (7 does
    not divide 300) and runs that stop early on an episode quota."""
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": agents,
        "battery.enabled": battery,
        "battery.capacity": 30,
        "battery.charge_steps": 4,
        "steps": 300,
        "record.timeline": window,
    }
    assert both(flat, tmp_path) == ("numba", "")
    assert (tmp_path / "numba" / "timeline.csv").is_file()
    assert both({**flat, "episodes": 2}, tmp_path) == ("numba", "")


@pytest.mark.parametrize("policy", ["cyclic", "partition", "evap"])
def test_compiled_lanes_slice_only_the_strategys_per_run_arrays(
    rooms_map, tmp_path, monkeypatch, policy
):
    """As many runs as the map has cells (30): a strategy's constant arrays (distances
    [C, C], walks, evap's powers) have as many rows as there are runs, and must not be
    cut into lanes of runs (threads) with the per-run ones."""
    from qpatrol.engines import threads
    from qpatrol.maps import get_map

    monkeypatch.setattr(threads, "MIN_LANE_WORK", 1)
    n_cells = get_map(str(rooms_map)).distances().shape[0]
    flat = {
        **BASE,
        "map": str(rooms_map),
        "policy": policy,
        "runs": n_cells,
        "agents": 2,
        "steps": 150,
        "battery.enabled": False,
        "threads": 2,
    }
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize("battery", [True, False])
@pytest.mark.parametrize("timeline", [0, 50])
def test_compiled_blocks_of_runs(rooms_map, tmp_path, monkeypatch, battery, timeline):
    """Large batches go through the compiled loop in blocks of COMPILED_RUN_STEPS team
    steps, one run after the other, each drawing its uniforms from its stream's words:
    shrunk limits force blocks of 64 steps, with a short last block and runs stopped
    early by an episode quota (their streams stepped past the steps they sat out);
    every file equals the numpy engine's."""
    from qpatrol import run

    monkeypatch.setattr(run, "COMPILED_BLOCK", 256)
    monkeypatch.setattr(run, "COMPILED_RUN_STEPS", 64)
    assert run.compiled_schedule(5, 2, False) == 64
    flat = {
        **BASE,
        "map": str(rooms_map),
        "runs": 5,
        "agents": 2,
        "steps": 300,
        "episodes": 3,
        "max_episode_steps": 40,
        "battery.enabled": battery,
        "battery.capacity": 30,
        "record.timeline": timeline,
    }
    assert both(flat, tmp_path) == ("numba", "")


# --- qlearning-idleness ---------------------------------------------------------------

#: (agents, communication, battery) x the strategy's settings: every pair of values of
#: any two of these columns occurs in some row (a covering subset of the product).
QIDLE_TEAMS = [
    # K, comm, battery, share, known, state, reward, alpha, epsilon, avoid
    (1, True, True, True, True, "cell_heading", "idleness", 0.1, 0.3, False),
    (1, True, False, False, True, "cell_heading_idle", "dot", 0.0, 0.3, False),
    (1, False, True, True, False, "cell_heading", "idleness", 0.0, 0.3, True),
    (1, False, False, True, False, "cell_idle", "idleness", 0.1, 0.0, False),
    (2, True, True, True, True, "cell_heading", "dot", 0.0, 0.3, True),
    (2, True, False, True, False, "cell_heading", "idleness", 0.1, 0.0, True),
    (2, False, True, False, True, "cell_idle", "dot", 0.1, 0.0, False),
    (2, False, False, False, False, "cell_heading_idle", "dot", 0.0, 0.3, True),
    (4, True, True, False, False, "cell_idle", "idleness", 0.0, 0.3, True),
    (4, True, False, True, True, "cell_heading_idle", "dot", 0.1, 0.3, True),
    (4, False, True, False, True, "cell_heading", "idleness", 0.0, 0.0, True),
    (4, False, False, True, True, "cell_idle", "idleness", 0.1, 0.3, False),
    (8, True, True, False, False, "cell_heading_idle", "idleness", 0.1, 0.0, True),
    (8, True, False, False, True, "cell_heading", "dot", 0.0, 0.3, False),
    (8, False, True, False, False, "cell_heading", "idleness", 0.1, 0.3, True),
    (8, False, False, True, True, "cell_idle", "idleness", 0.0, 0.3, True),
]


def qidle(row: tuple) -> dict:
    """The flat config of a row of :data:`QIDLE_TEAMS`."""
    agents, comm, battery, share, known, state, reward, alpha, epsilon, avoid = row
    return {
        "policy": "qlearning-idleness",
        "agents": agents,
        "team.communication": comm,
        "battery.enabled": battery,
        "battery.capacity": 30,
        "battery.charge_steps": 4,
        "qidle.share": share,
        "qidle.known_reward": known,
        "qidle.state": state,
        "qidle.reward": reward,
        "qidle.alpha": alpha,
        "qidle.epsilon": epsilon,
        "qidle.explore_steps": 200,  # epsilon reaches 0 before the end
        "qidle.reward_cap": 1.5 if agents == 8 else 3.0,
        "team.avoid_collisions": avoid,
    }


@pytest.mark.parametrize("row", QIDLE_TEAMS, ids=lambda r: "-".join(map(str, r[:3])))
def test_compiled_qlearning_idleness_teams(rooms_map, tmp_path, row):
    flat = {**BASE, "map": str(rooms_map), "steps": 300, **qidle(row)}
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("agents", [3, 6])
def test_compiled_qlearning_idleness_dead_end_stations(crowded, tmp_path, seed, agents):
    """Station pockets, queues, yields and pushes on random tree-like mazes, shared
    table (seed 1) or one per robot (seed 2)."""
    path = tmp_path / "maze.txt"
    path.write_text(mazes.random_maze(5, 6, seed, loops=0.1 * seed, stations=2))
    flat = {
        **BASE,
        "map": str(path),
        "agents": agents,
        "policy": "qlearning-idleness",
        "qidle.share": seed == 1,
        "qidle.alpha": 0.0 if seed == 1 else 0.2,
        "battery.capacity": 90,
        "battery.charge_steps": 3 * (seed - 1),
        "battery.initial_charge": "full" if seed == 1 else "staggered",
        "steps": 600,
        "max_episode_steps": 300,
    }
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize(
    "extra",
    [
        {"record.watch": [3, 4, 17], "record.timeline": 7, "record.warmup": 20},
        {"record.transitions": True, "qidle.state": "cell_idle", "qidle.known_reward": False},
        {
            "record.transitions": True,
            "record.watch": [5],
            "agents": 4,
            "qidle.share": False,
            "qidle.reward": "dot",
            "qidle.epsilon": 0.2,
            "qidle.explore_steps": 100,
        },
    ],
)
@pytest.mark.parametrize("battery", [True, False])
def test_compiled_qlearning_idleness_recorders(rooms_map, tmp_path, extra, battery):
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": 2,
        "policy": "qlearning-idleness",
        "battery.enabled": battery,
        "battery.capacity": 30,
        "steps": 300,
        **extra,
    }
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize("communication", [True, False])
def test_compiled_qlearning_idleness_quota_leaves_the_strategy_as_numpy(
    rooms_map, tmp_path, communication
):
    """Runs stop at different steps on an episode quota (dot reward: the dots come back
    at each episode's end); the strategy object (q, n, last, dots, feat) ends as on numpy."""
    flat = {
        **BASE,
        "runs": 3,
        "map": str(rooms_map),
        "agents": 3,
        "policy": "qlearning-idleness",
        "team.communication": communication,
        "battery.enabled": False,
        "qidle.reward": "dot",
        "qidle.epsilon": 0.5,
        "qidle.explore_steps": 400,
        "episodes": 3,
        "max_episode_steps": None,
        "steps": 900,
        "record.transitions": True,
    }
    assert both(flat, tmp_path, strategy=True) == ("numba", "")
    assert both({**flat, "record.transitions": False}, tmp_path, strategy=True)[0] == "numba"


@pytest.mark.parametrize("first", ["numpy", "numba"])
def test_qlearning_idleness_resumes_on_the_other_engine(rooms_map, tmp_path, first):
    """A checkpoint taken on one engine, resumed on the other: the files and the
    strategy object of an uninterrupted numpy run."""
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": 3,
        "policy": "qlearning-idleness",
        "battery.enabled": True,
        "battery.capacity": 30,
        "qidle.epsilon": 0.3,
        "qidle.explore_steps": 150,
        "record.transitions": True,
        "steps": 300,
    }
    whole = simulate(from_flat({**flat, "engine": "numpy"}))
    then = "numba" if first == "numpy" else "numpy"

    class StopAt(ck.Checkpointer):
        every_step = True  # stops at an exact step

        def tick(self, position, payload):
            if position == 133:
                self.request_stop()
            super().tick(position, payload)

    with pytest.raises(ck.Interrupted):
        simulate(from_flat({**flat, "engine": first}), checkpoint=StopAt(tmp_path / "cp", every=0))
    resumed = ck.Checkpointer(tmp_path / "cp", every=0)
    assert resumed.load().position == 133
    rest = simulate(from_flat({**flat, "engine": then}), checkpoint=resumed)
    assert rest.engine == then
    same_arrays(whole.strategy, rest.strategy)
    a = write_run(whole, tmp_path / "whole", meta=META)
    b = write_run(rest, tmp_path / "rest", meta=META)
    for name in sorted(p.name for p in a.iterdir()):
        if name != "meta.json":
            assert (a / name).read_bytes() == (b / name).read_bytes(), name


# --------------------------------------------------------------------- classic strategies

#: The strategies compiled besides qlearning (qpatrol/engines/compiled/).
CLASSIC = ("random", "conscientious", "shared-conscientious", "evap", "cyclic", "partition")


#: (strategy, agents, communication, battery): each strategy with each team size, the
#: booleans turning through their four pairs; every pair of values of any two columns
#: occurs (24 rows of the 96 of the product).
CLASSIC_TEAMS = pairs(
    [CLASSIC, (1, 2, 4, 8), (True, False), (True, False)],
    [
        (policy, k, *BOTH2[(i + j) % 4])
        for i, policy in enumerate(CLASSIC)
        for j, k in enumerate((1, 2, 4, 8))
    ],
)


@pytest.mark.parametrize("policy, agents, communication, battery", CLASSIC_TEAMS)
def test_compiled_classic_teams(rooms_map, tmp_path, policy, agents, communication, battery):
    """Collisions avoided (pushes, right of way, head-on exchanges of walks), on a map
    of 30 cells that 8 robots crowd; battery with one station."""
    flat = {
        **BASE,
        "map": str(rooms_map),
        "policy": policy,
        "agents": agents,
        "battery.enabled": battery,
        "battery.capacity": 30,
        "battery.charge_steps": 4,
        "team.communication": communication,
        "steps": 300,
    }
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize(
    "policy, agents, battery",
    pairs(
        [CLASSIC, (2, 8), (True, False)],
        [(p, k, (k == 2) == (i % 2 == 0)) for i, p in enumerate(CLASSIC) for k in (2, 8)],
    ),
)
def test_compiled_classic_without_avoidance(rooms_map, tmp_path, policy, agents, battery):
    """Robots may share cells (two of one group entering one cell in a step)."""
    flat = {
        **BASE,
        "map": str(rooms_map),
        "policy": policy,
        "agents": agents,
        "battery.enabled": battery,
        "battery.capacity": 30,
        "team.avoid_collisions": False,
        "team.communication": agents == 8,
        "steps": 300,
    }
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize("policy", CLASSIC)
@pytest.mark.parametrize("seed, agents", [(1, 3), (2, 6), (3, 1)])
def test_compiled_classic_on_dead_end_stations(crowded, tmp_path, policy, seed, agents):
    """Station pockets (walk targets skipped while another robot holds the pocket, not
    while the robot itself does, leaving it), queues, homing yields and pushes: random
    tree-like mazes."""
    path = tmp_path / "maze.txt"
    path.write_text(mazes.random_maze(5, 6, seed, loops=0.1 * seed, stations=2))
    flat = {
        **BASE,
        "map": str(path),
        "policy": policy,
        "agents": agents,
        "battery.capacity": 90,
        "battery.charge_steps": 3 * (seed - 1),
        "battery.initial_charge": "full" if seed == 1 else "staggered",
        "team.communication": seed == 1,
        "steps": 900,
        "max_episode_steps": 300,
    }
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize("policy", CLASSIC)
@pytest.mark.parametrize(
    "extra",
    [
        {
            "record.watch": [3, 4, 17],
            "record.timeline": 7,
            "record.transitions": True,
            "record.warmup": 20,
            "evap.evaporation": 0.3,
        },
        {"episodes": 2, "max_episode_steps": None, "steps": 900, "team.communication": False},
    ],
)
def test_compiled_classic_recorders_and_quotas(rooms_map, tmp_path, policy, extra):
    """Every recorder and a warm-up; runs that meet an episode quota at different steps
    and sit out the rest of the batch."""
    flat = {**BASE, "map": str(rooms_map), "policy": policy, "agents": 3, "steps": 300}
    flat.update({"battery.capacity": 40, "battery.charge_steps": 5, **extra})
    assert both(flat, tmp_path) == ("numba", "")


@pytest.mark.parametrize("policy", ["conscientious", "evap", "cyclic", "partition"])
def test_checkpoint_resumed_on_the_other_engine(rooms_map, tmp_path, policy):
    """A run checkpointed halfway on one engine and resumed on the other writes the
    files of an uninterrupted run: the strategy's arrays are the numpy engine's after
    every compiled step."""
    flat = {**BASE, "map": str(rooms_map), "policy": policy, "agents": 4, "steps": 240}
    flat.update({"battery.capacity": 30, "battery.charge_steps": 4, "record.timeline": 50})
    whole = write_run(simulate(from_flat(flat)), tmp_path / "whole", meta=META)

    class StopAt(ck.Checkpointer):
        every_step = True  # stops at an exact step

        def tick(self, position, payload):
            if position == 111:
                self.request_stop()
            super().tick(position, payload)

    first, then = ("numpy", "numba") if policy in ("evap", "cyclic") else ("numba", "numpy")
    with pytest.raises(ck.Interrupted):
        simulate(from_flat({**flat, "engine": first}), checkpoint=StopAt(tmp_path / "cp", every=0))
    resumed = ck.Checkpointer(tmp_path / "cp", every=0)
    rest = simulate(from_flat({**flat, "engine": then}), checkpoint=resumed)
    assert rest.engine == then
    same_files(whole, write_run(rest, tmp_path / "rest", meta=META), flat)


@pytest.mark.parametrize(
    "policy, agents, battery, switch",
    [
        ("cyclic", 4, False, None),
        ("cyclic", 8, False, None),
        ("cyclic", 8, True, None),
        ("partition", 8, True, None),
        ("cyclic", 8, False, "keep_spacing"),
        ("cyclic", 4, True, "exchange_early"),
    ],
)
def test_compiled_walk_followers_on_a_dead_end_floor(
    tmp_path, monkeypatch, policy, agents, battery, switch
):
    """Walk followers on one-wide corridors with dead ends deeper than L/(2K): robots
    wait for their spacing, exchange plans before meeting head-on, are pushed aside and
    (battery on) go home and come back; the rules switched off one at a time too. Every
    file and the strategy's arrays equal the numpy engine's."""
    from qpatrol.strategies import follow

    if switch is not None:
        monkeypatch.setattr(follow.WalkFollower, switch, False)
    path = tmp_path / "floor.txt"
    path.write_text(mazes.random_maze(6, 8, 4, loops=0.15, dead_end_stations=False))
    flat = {
        **BASE,
        "map": str(path),
        "policy": policy,
        "agents": agents,
        "battery.enabled": battery,
        "battery.capacity": 150,
        "battery.charge_steps": 5,
        "steps": 700,
        "max_episode_steps": 200,
    }
    assert both(flat, tmp_path, strategy=True) == ("numba", "")


#: Each compiled strategy given the code of another whose pack it can feed (so the
#: loop reads only arrays that exist): the comparison must see the difference.
WRONG_CODE = {
    "random": "shared-conscientious",
    "conscientious": "random",
    "shared-conscientious": "random",
    "evap": "random",
    "cyclic": "random",
    "partition": "random",
}


@pytest.mark.parametrize("policy", CLASSIC)
def test_a_broken_compiled_strategy_is_caught(rooms_map, tmp_path, monkeypatch, policy):
    """The comparison has teeth: a compiled strategy that chooses otherwise fails it."""
    from qpatrol.engines import compiled

    wrong = compiled.MODULES[WRONG_CODE[policy]][0]
    monkeypatch.setitem(compiled.MODULES, policy, (wrong, compiled.MODULES[policy][1]))
    flat = {**BASE, "map": str(rooms_map), "policy": policy, "agents": 3, "steps": 200}
    with pytest.raises(AssertionError):
        both({**flat, "battery.enabled": False}, tmp_path)


def test_sat_out_mirrors_the_numpy_engine(rooms_map):
    """The compiled loop skips runs that met their episode quota; ``follow.sat_out``
    does what the numpy engine's walk followers do in those steps: the cyclic hold ends
    once past ``gather_until`` (unit test on one numpy step)."""
    import copy

    from qpatrol import strategies, world
    from qpatrol.engines.compiled import follow
    from qpatrol.engines.numpy_loop import advance
    from qpatrol.maps import get_map
    from qpatrol.measures.records import Recorder

    cfg = from_flat({"map": str(rooms_map), "policy": "cyclic", "agents": 3, "runs": 2})
    m = get_map(cfg["map"])
    p = world.make_params(cfg, m)
    starts = np.array([[1, 5, 9], [2, 6, 12]])
    state = world.init_state(p, starts)
    strategy = strategies.make("cyclic", cfg, m, p, starts)
    state.t = strategy.gather_until + 3
    state.steps_done[:] = state.t
    state.active[1] = False  # run 1 met its quota
    mirror = copy.deepcopy(strategy)
    u = np.full((2, 3, 2), 0.5)
    advance(state, p, strategy, u, Recorder(np.arange(2)))
    mirror_state = copy.deepcopy(state)
    follow.sat_out(mirror, mirror_state)
    assert state.steps_done[1] < state.t  # run 1 sat out the step
    assert np.array_equal(mirror.hold[1], strategy.hold[1]) and not strategy.hold[1].any()


def test_evap_powers_are_numpys_and_long_tables_fall_back():
    """The compiled evap reads ``keep ** n`` from numpy's own table (numba's power is
    not numpy's to the bit); a table past 2^22 entries is refused, the run falls back."""
    from qpatrol.engines.compiled import evap

    table = evap.powers(0.98, 100_000)
    assert table[-1] == 0.0 and table[-2] > 0.0  # cut at the first 0.0 ...
    n = np.arange(100_000, dtype=np.int64)
    assert np.array_equal(table[np.minimum(n, table.size - 1)], 0.98**n)  # ... and after
    assert evap.powers(0.5, 30).size == 31
    cfg = from_flat({"policy": "evap", "steps": 5_000_000, "runs": 1})
    assert engines.compiled_gap(cfg) is None
    gap = engines.compiled_gap(cfg.replace(**{"evap.evaporation": 1e-9}))
    assert gap is not None and "evap" in gap


def test_a_table_that_misses_a_pair_is_refused():
    """The covering tables above are checked: drop one row and some pair is missing."""
    domains = [CLASSIC, (1, 2, 4, 8), (True, False), (True, False)]
    assert covers_every_pair(CLASSIC_TEAMS, domains)
    for k in range(len(CLASSIC_TEAMS)):
        assert not covers_every_pair(CLASSIC_TEAMS[:k] + CLASSIC_TEAMS[k + 1 :], domains)
    with pytest.raises(AssertionError):
        pairs([(1, 2), (True, False)], [(1, True), (2, False)])


#: A patrol graph of long edges (waypoints; D = 4, as record.transitions needs): robots
#: decide at its vertices only, and the learners' transitions run vertex to vertex.
LONG_GRAPH = """\
; name: longedges
; kind: graph
v 0 0 0 start=0
v 1 4 0
v 2 2 3
v 3 0 4
v 4 5 4 station
e 0 1 3
e 1 2 2
e 2 0 4
e 0 3 1
e 3 2 2
e 1 4 3
e 0 4 4
"""


@pytest.mark.parametrize(
    "policy, agents, avoid, battery, extra",
    [
        ("qlearning", 1, True, False, {"record.transitions": True}),
        ("qlearning", 3, True, True, {"record.transitions": True}),
        ("qlearning", 2, False, False, {"episodes": 3, "max_episode_steps": 40}),
        ("qlearning-idleness", 3, True, False, {"record.transitions": True}),
        ("qlearning-idleness", 2, True, True, {"qidle.share": True, "episodes": 2}),
        ("evap", 3, True, True, {}),
        ("conscientious", 2, False, False, {}),
        ("cyclic", 3, True, True, {}),
    ],
)
def test_compiled_decisions_at_vertices_on_graphs(tmp_path, policy, agents, avoid, battery, extra):
    """Both engines alike, strategy arrays included (the learners' pending decisions),
    on a graph with waypoints: battery on and off, pushes, quotas, Q-update rows."""
    path = tmp_path / "longedges.txt"
    path.write_text(LONG_GRAPH)
    flat = {
        "map": str(path), "policy": policy, "agents": agents, "runs": 3, "seed": 4,
        "steps": 300, "record.trajectory": 300, "team.avoid_collisions": avoid,
        "battery.enabled": battery, "battery.capacity": 60, "battery.charge_steps": 3,
        **extra,
    }  # fmt: skip
    assert both(flat, tmp_path, strategy=True) == ("numba", "")


#: A patrol graph whose vertices have at most 3 edges (D = 3).
TRIANGLE_GRAPH = """\
; name: triangle
; kind: graph
v 0 0 0 start=0
v 1 4 0
v 2 2 3
v 3 0 4
e 0 1 2
e 1 2 3
e 2 0 2
e 0 3 1
"""


def test_transitions_on_a_graph_of_fewer_than_four_ports(tmp_path):
    """Q-update rows on a map with D = 3 (watch.csv, which holds four Q values, is
    refused there; transitions.csv is not): both engines alike, one row per update."""
    path = tmp_path / "triangle.txt"
    path.write_text(TRIANGLE_GRAPH)
    flat = {
        "map": str(path), "policy": "qlearning", "agents": 2, "runs": 2, "seed": 3,
        "steps": 200, "record.transitions": True, "battery.enabled": False,
    }  # fmt: skip
    assert both(flat, tmp_path, strategy=True) == ("numba", "")
    rows = (tmp_path / "numba" / "transitions.csv").read_text().splitlines()
    assert len(rows) > 50 and rows[0].startswith("run,step,agent,cell,heading,action")


@pytest.mark.parametrize("battery", [True, False])
@pytest.mark.parametrize("agents", [1, 4])
def test_cyclic_by_rows_of_moves_equals_the_table(
    rooms_map, tmp_path, monkeypatch, agents, battery
):
    """cyclic without its [C, C] table (a map above TABLE_CELLS: each robot searches its
    goal's row) writes the files of the table, on both engines."""
    from qpatrol.maps import core

    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": agents,
        "policy": "cyclic",
        "battery.enabled": battery,
        "battery.capacity": 40,
        "battery.charge_steps": 5,
        "steps": 200,
    }
    table = write_run(simulate(from_flat({**flat, "engine": "numpy"})), tmp_path / "t", meta=META)
    monkeypatch.setattr(core, "TABLE_CELLS", 0)
    numpy_rows = simulate(from_flat({**flat, "engine": "numpy"}))
    assert numpy_rows.strategy.dist is None
    assert numpy_rows.strategy.goal_rows or (agents == 1 and not battery)  # rows searched
    same_files(table, write_run(numpy_rows, tmp_path / "r", meta=META), flat)
    assert both(flat, tmp_path, strategy=True) == ("numba", "")
    same_files(table, tmp_path / "numba", flat)
