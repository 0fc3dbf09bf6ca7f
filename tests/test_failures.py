"""Robot failures (``failures.robots``, ``failures.at``; docs/model.md, "Robot failures").

At the end of team step ``failures.at`` the chosen robots leave the map for good: mode
GONE, no right of way, no station, no wait, their cell empty. By hand on tiny maps (a
ring, a station at the end of a dead end), each engine alone; then every strategy on
every shipped map with two of four robots failing, the battery on: the engines write
the same files to the bit, and on the numpy engine no two remaining robots share a
cell or swap, the failed robots never move again, and the measures start at the
failure.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from qpatrol import engines, measures, strategies, world
from qpatrol.config import ConfigError, from_flat
from qpatrol.engines import numpy_loop
from qpatrol.maps import available_maps, get_map, parse_map
from qpatrol.measures.records import Recorder, Tail
from qpatrol.run import simulate, write_run
from qpatrol.world import failures
from qpatrol.world.battery import CHARGING, GONE, HOMING, QUEUED
from qpatrol.world.rng import RunKey, run_keys

NUMBA = importlib.util.find_spec("numba") is not None
META = {"started": "-", "ended": "-"}


@pytest.fixture(params=["numpy", "numba"])
def engine(request) -> str:
    if request.param == "numba" and not NUMBA:
        pytest.skip("numba not installed")
    return request.param


def both(flat: dict, tmp_path: Path, prepared=None):
    """Run ``flat`` on both engines (the compiled one where installed), compare every
    file of the run folders byte for byte (meta.json: but the engine) and the
    strategies' arrays; the numpy engine's result. ``prepared``: the map and
    parameters, if already built."""
    results, folders = {}, {}
    for eng in ("numpy", "numba") if NUMBA else ("numpy",):
        results[eng] = simulate(from_flat({**flat, "engine": eng}), prepared=prepared)
        folders[eng] = write_run(results[eng], tmp_path / eng, replace=True, meta=META)
    if NUMBA:
        assert results["numba"].engine == "numba"
        # the strategies' arrays too (e.g. a goal no file holds)
        va, vb = vars(results["numpy"].strategy), vars(results["numba"].strategy)
        for name, x in va.items():
            if isinstance(x, np.ndarray):
                y = vb[name]
                assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), name
        a, b = folders["numpy"], folders["numba"]
        names = sorted(p.name for p in a.iterdir())
        assert names == sorted(p.name for p in b.iterdir())
        for name in names:
            if name == "meta.json":
                ma, mb = (json.loads((f / name).read_text()) for f in (a, b))
                ma.pop("engine"), mb.pop("engine")
                assert ma == mb
            else:
                assert (a / name).read_bytes() == (b / name).read_bytes(), (flat, name)
    return results["numpy"]


# --- the config ---------------------------------------------------------------------------


def test_the_keys_are_checked_on_load():
    assert from_flat({})["failures.robots"] == 0
    with pytest.raises(ConfigError, match=r"^failures.robots: got 4 with 4 agents"):
        from_flat({"agents": 4, "failures.robots": 4, "failures.at": 10})
    with pytest.raises(ConfigError, match=r"^failures.at: got 0 with failures.robots 1"):
        from_flat({"agents": 4, "failures.robots": 1})
    with pytest.raises(ConfigError, match=r"^failures.at: got 100 .* 1..99"):
        from_flat({"steps": 100, "failures.robots": 1, "failures.at": 100})
    with pytest.raises(ConfigError, match=r"^failures.robots"):
        from_flat({"failures.robots": -1})
    cfg = from_flat({"agents": 4, "failures.robots": 3, "failures.at": 99, "steps": 100})
    assert (cfg["failures.robots"], cfg["failures.at"]) == (3, 99)


def test_the_environments_refuse_failures():
    from qpatrol.envs.sim import Sim

    cfg = from_flat({"agents": 2, "failures.robots": 1, "failures.at": 5})
    with pytest.raises(ConfigError, match=r"^failures.robots: got 1; allowed here: 0"):
        Sim(cfg)


def test_a_qlearning_team_with_failures_runs_the_general_compiled_loop():
    flat = {"agents": 4, "battery.enabled": False, "engine": "numba", "steps": 40}
    if not NUMBA:
        pytest.skip("numba not installed")
    assert engines.compiled_loop(from_flat(flat)) == "qlearning-team"
    cfg = from_flat({**flat, "failures.robots": 1, "failures.at": 5})
    assert engines.compiled_loop(cfg) == "any"


def test_a_qlearning_team_without_battery_fails_alike_on_both_engines(rooms_map, tmp_path):
    """(The compiled engine's Q-learning team loop has no failures: the general loop runs
    such a team, and the engines agree.)"""
    flat = {
        "map": str(rooms_map),
        "agents": 3,
        "battery.enabled": False,
        "runs": 2,
        "steps": 80,
        "failures.robots": 1,
        "failures.at": 20,
        "record.trajectory": 5,
    }
    result = both(flat, tmp_path)
    assert result.measures.measured.tolist() == [60, 60]


# --- which robots fail ------------------------------------------------------------------


def test_the_failed_robots_come_from_a_stream_of_their_own():
    """Run r of point p: SeedSequence(seed, spawn_key=(p, r, 1)), whatever the batch."""
    assert failures.failure_sequence(RunKey(7, 3, 5)).spawn_key == (3, 5, failures.FAILURE_KEY)
    batch = failures.choose(run_keys(7, 6, 3), 8, 3)
    for r in range(6):
        assert (failures.choose([RunKey(7, 3, r)], 8, 3)[0] == batch[r]).all()
        assert (batch[r] == np.sort(batch[r])).all() and np.unique(batch[r]).size == 3
    assert len({tuple(x) for x in batch.tolist()}) > 1  # not the same robots in every run
    assert failures.choose(run_keys(7, 6, 3), 8, 0).shape == (6, 0)


def test_the_failed_robots_depend_only_on_the_seed_and_the_run(ring_map):
    """The same robots in a batch of four runs and in a batch of one, on both engines;
    and no other draw changes: every step before the failure is the run's without
    failures (the trajectory and episodes up to it)."""
    flat = {
        "map": str(ring_map),
        "agents": 3,
        "policy": "random",
        "battery.enabled": False,
        "runs": 4,
        "seed": 3,
        "steps": 60,
        "failures.robots": 2,
        "failures.at": 30,
        "record.trajectory": 60,
    }
    want = failures.choose(run_keys(3, 4), 3, 2).tolist()
    for eng in ("numpy", "numba") if NUMBA else ("numpy",):
        four = simulate(from_flat({**flat, "engine": eng}))
        assert [s["failed_robots"] for s in four.summary] == want
        assert [s["failed_at"] for s in four.summary] == [30] * 4
        one = simulate(from_flat({**flat, "engine": eng}), runs=range(2, 3))
        assert one.summary[0]["failed_robots"] == want[2]
        assert one.summary[0] == four.summary[2]
        plain = simulate(from_flat({**flat, "engine": eng, "failures.robots": 0}))
        assert "failed_robots" not in plain.summary[0]
        before = four.trajectory["step"] < 30
        tr, tp = four.trajectory[before], plain.trajectory[plain.trajectory["step"] < 30]
        assert tr.reset_index(drop=True).equals(tp.reset_index(drop=True))
        after = four.trajectory[~before]
        failed = np.array(want)[after["run"].to_numpy()]  # [rows, F]
        gone = (failed == after["agent"].to_numpy()[:, None]).any(axis=1)
        assert (after["cell"][gone] == -1).all() and (after["cell"][~gone] >= 0).all()


# --- by hand ----------------------------------------------------------------------------

RING12 = """\
; name: ring12
; description: a one-wide ring of twelve cells
....
.##.
.##.
....
"""


def test_a_failed_robot_blocks_no_one_on_a_ring(tmp_path):
    """Two cyclic robots on a one-wide ring of 12 cells, six apart; at step 20 one
    fails. From then on its cell is empty (-1 in trajectory.csv), and the other walks
    on, one cell a step, through the failed robot's cell, never waiting."""
    path = tmp_path / "ring12.txt"
    path.write_text(RING12)
    flat = {
        "map": str(path),
        "agents": 2,
        "policy": "cyclic",
        "battery.enabled": False,
        "runs": 2,
        "seed": 1,
        "steps": 60,
        "failures.robots": 1,
        "failures.at": 20,
        "record.trajectory": 60,
        "record.timeline": 10,
    }
    result = both(flat, tmp_path)
    s = result.state
    for r in range(2):
        (gone,) = result.summary[r]["failed_robots"]
        other = 1 - gone
        assert s.mode[r, gone] == GONE and s.occ[r, s.pos[r, gone]] == -1
        run = result.trajectory[result.trajectory["run"] == r]
        cells = run["cell"].to_numpy().reshape(-1, 2)  # [step, robot]
        assert (cells[19:, gone] == -1).all() and (cells[:19, gone] >= 0).all()
        walk = cells[19:, other]
        assert (walk[1:] != walk[:-1]).all()  # it moves every step
        assert s.pos[r, gone] in walk[1:]  # through the failed robot's last cell
        assert result.summary[r]["waits"] == 0 and result.summary[r]["max_wait"] == 0
        assert result.measures.window_visits[r, gone].sum() == 0
        # the measures' window starts at the failure
        assert result.measures.warmup == 20 and result.measures.measured[r] == 40


# A T whose stem is a dead end with the station H at its end: cells 0..6 on top, the
# junction 3 above the stem 7, 8 and H = 9 (the station's pocket: 7, 8, 9).
T_POCKET = ".......\n###.###\n###.###\n###H###\n"


class Team:
    """One run on a hand-built map from a hand-set state, one engine; robot ``failed``
    fails at the end of step ``at``."""

    def __init__(self, engine: str, text: str, starts: list[int], failed: list[int], at: int):
        cfg = from_flat(
            {
                "agents": len(starts),
                "policy": "random",
                "battery.capacity": 20,
                "battery.margin": 0,
                "battery.charge_steps": 3,
                "battery.initial_charge": "full",
                "failures.robots": len(failed),
                "failures.at": at,
            }
        )
        m = parse_map(text)
        self.p = p = world.make_params(cfg, m)
        cells = np.array([starts], dtype=np.int64)
        self.s = world.init_state(p, cells, np.array([failed]))
        self.strategy = strategies.make("random", cfg, m, p, cells)
        self.engine = engine
        self.loop = None

    def step(self) -> None:
        s, p = self.s, self.p
        if self.engine == "numpy":
            out = numpy_loop.advance(s, p, self.strategy, np.zeros((1, p.n_agents, 2)))
            if s.t == p.failures_at:
                failures.apply(s, p, np.flatnonzero(out.active))
            return
        if self.loop is None:
            from qpatrol.engines import numba_core

            watch = measures.Measures(1, p.n_agents, p.n_cells, 0)
            words = np.zeros((1, 4), dtype=np.uint64)
            self.loop = numba_core.Loop(
                s, p, self.strategy, watch, Tail(0, s), Recorder(np.arange(1)), 1, lambda: words
            )
        self.loop.run(1, [(0, 1)])


def test_a_failed_robot_gives_up_its_station_and_the_right_of_way(engine):
    """Robot 0 holds the station (on its way down the dead end, with the right of way);
    robot 1 waits for the station at the far end of the top row. Robot 0 fails at the
    end of step 1, in the pocket: the token goes to nobody, the station is free, and
    robot 1 takes it in step 2 and walks down the pocket through robot 0's cell, which
    neither holds it back (no robot in the pocket) nor blocks it (the cell is empty)."""
    team = Team(engine, T_POCKET, [7, 0], failed=[0], at=1)
    s, p = team.s, team.p
    assert p.homes.tolist() == [9] and p.pocket_of[[7, 8, 9]].tolist() == [0, 0, 0]
    s.goal[0, 0], s.reserved[0, 0], s.mode[0, 0] = 0, 0, HOMING
    s.mode[0, 1], s.charge[0, 1] = QUEUED, 7  # 6 moves from H: it needs the station
    s.token[0], s.token_held[0] = 0, 1
    team.step()  # robot 0: 7 -> 8, keeps the token, then fails
    assert s.pos[0].tolist() == [8, 0] and s.mode[0].tolist() == [GONE, QUEUED]
    assert (s.token[0], s.token_held[0]) == (-1, 0)
    assert s.reserved[0].tolist() == [-1] and s.goal[0, 0] == -1
    assert s.occ[0, 8] == -1 and s.occ[0, 0] == 1 and s.wait[0, 0] == 0
    cells = []
    for _ in range(7):
        team.step()
        cells.append(int(s.pos[0, 1]))
        assert s.reserved[0].tolist() == [1] and s.token[0] != 0
    # 0 -> 1 -> 2 -> 3 (the junction) -> 7 -> 8 (robot 0's cell) -> 9 = H, then charges
    assert cells == [1, 2, 3, 7, 8, 9, 9]
    assert s.mode[0].tolist() == [GONE, CHARGING] and s.pos[0, 0] == 8


# --- every strategy on every shipped map ------------------------------------------------

MAPS = sorted(available_maps())


@pytest.mark.parametrize("name", MAPS)
def test_every_strategy_survives_two_failures_on_every_map(tmp_path, name):
    """Four robots, two fail at step 30 of 100, the battery on (every shipped map has a
    station): both engines write the same files; on the numpy engine's trajectory no
    two remaining robots share a cell or swap, the failed ones are gone (-1) from the
    failure on and never entered a cell again, and the measures count from there."""
    m = get_map(name)
    dist = m.distances()
    nearest = int(dist[m.homes].min(axis=0).max())
    at, steps = 30, 100
    prepared = None
    for policy in strategies.NAMES:
        flat = {
            "map": name,
            "agents": 4,
            "policy": policy,
            "runs": 2,
            "seed": 5,
            "steps": steps,
            "battery.capacity": max(3 * int(dist.max()), nearest + 10) + 20,
            "battery.charge_steps": 10,
            "failures.robots": 2,
            "failures.at": at,
            "record.trajectory": steps,
        }
        if prepared is None:  # (the same map and parameters for every strategy)
            prepared = (m, world.make_params(from_flat(flat), m))
        result = both(flat, tmp_path / policy, prepared)
        s = result.state
        want = failures.choose(run_keys(5, 2), 4, 2)
        for r in range(2):
            gone = want[r]
            assert result.summary[r]["failed_robots"] == gone.tolist()
            assert (s.mode[r, gone] == GONE).all()
            # their last cells are empty, or another robot has walked in since
            assert not np.isin(s.occ[r, s.pos[r, gone]], gone).any()
            assert result.measures.window_visits[r, gone].sum() == 0, (policy, r)
            if hasattr(result.strategy, "goal"):  # a goal follower: no goal announced
                assert (result.strategy.goal[r, gone] == -1).all(), (policy, r)
            assert result.measures.measured[r] == steps - at
            run = result.trajectory[result.trajectory["run"] == r]
            cells = run["cell"].to_numpy().reshape(steps, 4)
            assert (cells[at - 1 :, gone] == -1).all() and (cells[: at - 1] >= 0).all()
            stay = np.setdiff1d(np.arange(4), gone)
            assert (cells[:, stay] >= 0).all()
            check_steps(cells[:, stay], m.neighbors)
            check_steps(cells[: at - 1], m.neighbors)


def check_steps(cells: np.ndarray, neighbors: np.ndarray) -> None:
    """``cells`` int ``[T, K]``: no two robots in a cell, no swap, no jump."""
    k = cells.shape[1]
    ordered = np.sort(cells, axis=1)
    assert not (ordered[:, 1:] == ordered[:, :-1]).any(), "two robots in one cell"
    before, after = cells[:-1], cells[1:]
    swap = (after[:, :, None] == before[:, None, :]) & (before[:, :, None] == after[:, None, :])
    assert not (swap & ~np.eye(k, dtype=bool)).any(), "two robots swapped cells"
    step = after != before
    assert (neighbors[before] == after[..., None]).any(axis=-1)[step].all(), "a jump"


@pytest.mark.parametrize("stop", [10, 30])
def test_a_run_stopped_before_or_after_the_failure_resumes_to_the_same_files(
    ring_map, tmp_path, engine, stop, stop_and_resume
):
    """A checkpoint before the failure (step 20) and one after it both resume to the
    uninterrupted run's numbers: the failed robots travel with the state."""
    flat = {
        "map": str(ring_map),
        "agents": 3,
        "policy": "random",
        "battery.enabled": False,
        "runs": 2,
        "steps": 50,
        "failures.robots": 1,
        "failures.at": 20,
        "record.trajectory": 50,
        "engine": engine,
    }
    cfg = from_flat(flat)
    whole = simulate(cfg)
    resumed = stop_and_resume(cfg, tmp_path / "ck", stop)
    assert resumed.summary == whole.summary
    assert resumed.trajectory.equals(whole.trajectory)
    assert (resumed.state.mode == whole.state.mode).all()


def test_results_csv_joins_the_failed_robots(tmp_path):
    """A sweep's results.csv writes a run's list of failed robots as one cell, joined
    by ``+`` (as a swept list value)."""
    from qpatrol.study import sweep

    point = sweep.Point(0, {"failures.robots": 2})
    folder = tmp_path / sweep.POINTS_DIR / point.id
    folder.mkdir(parents=True)
    runs = [
        {"run": 0, "avg_idleness": 1.5, "failed_robots": [0, 2], "failed_at": 5},
        {"run": 1, "avg_idleness": 2.5, "failed_robots": [1, 3], "failed_at": 5},
    ]
    (folder / "summary.json").write_text(json.dumps({"runs": runs}))
    df = sweep.load_results(sweep.write_results(tmp_path, [point]))
    assert df["failed_robots"].tolist() == ["0+2", "1+3"]
    assert df["failed_at"].tolist() == [5, 5]
