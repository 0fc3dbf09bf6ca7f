"""The patrolling measures (qpatrol.measures) by hand on tiny maps, and by brute force.

Definitions as implemented, over the *window* of team steps ``t > record.warmup``:
idleness of cell c after step t is ``t - (last step c was entered, 0 if never)``;
``avg_idleness`` is its mean over cells and window steps, ``worst_idleness`` its max
over cells and window steps; an *interval* is ``t - previous visit`` for each visit at
a window step t of a cell entered before (at step >= 1); ``coverage`` is the share of
cells entered in the window; ``division_of_labour`` the mean over cells entered in
the window of (visits by the cell's most frequent visitor) / (all its visits).

The brute-force reimplementation below recomputes these from every robot's position
at every step with plain Python loops, and a deliberately broken measure is shown to
be caught by it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import ROOMS

from qpatrol import measures, world
from qpatrol.config import from_flat
from qpatrol.maps import EAST, WEST, parse_map
from qpatrol.measures import Measures, division_of_labour
from qpatrol.run import simulate
from qpatrol.world.battery import HOMING, PATROL, QUEUED
from qpatrol.world.rng import Streams, run_seeds

# a one-wide ring of n = 12 cells (the border of a 4 x 4 square), no station:
#   0  1  2  3
#   4  #  #  5
#   6  #  #  7
#   8  9 10 11
RING12 = "....\n.##.\n.##.\n....\n"
N = 12


def write(tmp_path: Path, text: str, name: str = "m.txt") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def ring_run(tmp_path: Path, agents: int, policy: str, warmup: int, steps: int):
    cfg = from_flat(
        {
            "map": write(tmp_path, RING12),
            "agents": agents,
            "policy": policy,
            "battery.enabled": False,
            "record.warmup": warmup,
            "steps": steps,
        }
    )
    return simulate(cfg)


# --- by hand: one closed walk on a ring ------------------------------------------------


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_cyclic_team_on_a_ring_by_hand(tmp_path, k):
    """K cyclic robots on the 12-ring, gathered on slots 12/K apart (warm-up 5 x 12 steps,
    far past the gathering), then 4 laps of 12 steps measured.

    Each robot advances one cell per step and the next robot is 12/K cells behind, so
    every cell is entered every g = 12/K steps: every interval is g. After any window
    step the cells behind each robot have idleness 0, 1, ..., g-1 (the one it just
    entered 0), K times over: avg_idleness = (g - 1) / 2 and worst_idleness = g - 1.
    In 48 steps each robot enters each cell exactly 4 times: division of labour 1/K.
    An episode ends when every dot is eaten: the K robots together eat 12 dots in g
    steps (the cells under them get their dots back too), so every episode lasts g.
    """
    g = N // k
    r = ring_run(tmp_path, k, "cyclic", warmup=5 * N, steps=9 * N)
    s = r.summary[0]
    assert s["steps"] == 9 * N
    assert s["mean_interval"] == g and s["max_interval"] == g
    assert s["avg_idleness"] == (g - 1) / 2
    assert s["worst_idleness"] == g - 1
    assert s["coverage"] == 1.0
    assert s["division_of_labour"] == pytest.approx(1 / k, abs=1e-15)
    assert s["mean_steps_per_episode"] == g
    assert s["max_wait"] == 0 and s["waits"] == 0
    assert r.strategy.describe()["walk_length"] == N
    # every robot entered every cell 4 times in the window
    assert (r.measures.window_visits[0] == 4).all()


def test_coverage_of_a_short_window_by_hand(tmp_path):
    """One cyclic robot, window of 5 steps: it enters 5 distinct cells, coverage 5/12.

    Worst idleness: a cell entered at window step t had idleness t - 1 - (t - 12) = 11
    at step t - 1 (its peak, counted when step t - 1 is in the window); cells not
    entered in the window have open gaps of at most 11 at the last step. Intervals: the
    4 visits at steps 62..65 each close a gap of 12 (the visit at step 61 closes one
    too: its previous visit, at 49, was before the window, but the visit is in it).
    """
    r = ring_run(tmp_path, 1, "cyclic", warmup=60, steps=65)
    s = r.summary[0]
    assert s["coverage"] == 5 / 12
    assert s["worst_idleness"] == 11
    assert s["mean_interval"] == 12 and s["max_interval"] == 12
    assert r.measures.gap_count[0] == 5
    assert s["avg_idleness"] == 5.5


def test_worst_idleness_counts_open_gaps_and_only_window_steps():
    """One robot going back and forth on the first cells of a corridor (cells 0, 1, 2 of
    a 5-cell line): cells 3 and 4 are never entered. Window: steps 11..20. Their
    idleness at step 20 is 20 (never entered: visited at step 0), an open gap:
    worst_idleness = 20. avg_idleness by hand below."""
    cfg = from_flat({"agents": 1, "battery.enabled": False})
    m = parse_map("0.---\n")
    p = world.make_params(cfg, m)
    s = world.init_state(p, np.array([[0]]))
    meas = Measures(1, 1, m.n_cells, warmup=10)
    # the robot alternates 0 -> 1 -> 0 -> 1 ...: at step t it enters 1 (t odd) or 0 (t even)
    for t in range(1, 21):
        obs = world.begin_step(s, p)
        out = world.step(s, p, obs, np.array([[EAST if t % 2 else WEST]]))
        meas.observe(out, s.wait, None)
    # after step t (window t = 11..20), cell entered at t: 0, the other of {0, 1}: 1;
    # cells 2, 3, 4: t each. Sum = 1 + 3t; over t = 11..20: 10 + 3 x 155 = 475
    assert meas.idle_total[0] == 475
    summary = measures.summarize(
        meas,
        pd.DataFrame({"run": [], "complete": [], "start_step": [], "steps": []}),
        np.array([0]),
        s.steps_done,
        bound=4,
    )[0]
    assert summary["avg_idleness"] == 475 / (5 * 10)
    assert summary["worst_idleness"] == 20
    assert summary["coverage"] == 2 / 5
    assert summary["mean_interval"] == 2 and summary["max_interval"] == 2


# --- division of labour ---------------------------------------------------------------


def test_division_of_labour_on_hand_made_visit_counts():
    visits = np.zeros((4, 2, 3), dtype=np.int64)  # 4 runs, 2 robots, 3 cells
    visits[0] = [[2, 2, 5], [2, 2, 5]]  # every cell shared equally: 1/2
    visits[1] = [[3, 0, 1], [0, 4, 0]]  # a partition: 1
    visits[2] = [[3, 1, 0], [1, 1, 0]]  # cell 0: 3/4, cell 1: 1/2, cell 2 unvisited
    # run 3: no visit at all: NaN
    dol = division_of_labour(visits)
    assert dol[0] == 0.5 and dol[1] == 1.0
    assert dol[2] == pytest.approx((3 / 4 + 1 / 2) / 2, abs=1e-15)
    assert np.isnan(dol[3])
    three = np.ones((1, 3, 5), dtype=np.int64)  # 3 robots, each cell once by each
    assert division_of_labour(three)[0] == pytest.approx(1 / 3, abs=1e-15)


def test_partition_gives_full_division_of_labour(tmp_path):
    """Two robots with ``policy=partition`` on the 12-ring each cycle their own half
    (a 6-cell path, walked there and back): after the warm-up no cell is entered by
    both, so the division of labour is 1; each half's walk has length 10, so the
    largest interval is 10 (the end cells of each half)."""
    r = ring_run(tmp_path, 2, "partition", warmup=5 * N, steps=5 * N + 40)
    s = r.summary[0]
    assert s["division_of_labour"] == 1.0
    assert s["coverage"] == 1.0
    assert sorted(r.strategy.describe()["region_walk_lengths"]) == [10, 10]
    assert s["max_interval"] == 10


# --- waits --------------------------------------------------------------------------------


def queue_scenario(warmup: int) -> Measures:
    """Robot 1 holds the only station; robot 0 needs it from step 2 and waits (QUEUED) at
    steps 2-7 (wait 1..6), is given it at step 8 and walks home (wait 0). See
    test_world.test_a_station_is_held_by_one_robot_first_come_first_served."""
    cfg = from_flat(
        {
            "agents": 2,
            "battery.capacity": 20,
            "battery.margin": 0,
            "battery.charge_steps": 0,
            "battery.initial_charge": "full",
        }
    )
    m = parse_map("......H......\n")
    p = world.make_params(cfg, m)
    s = world.init_state(p, np.array([[3, 11]]))
    s.charge[0] = [5, 6]
    meas = Measures(1, 2, m.n_cells, warmup=warmup)
    modes = []
    for _ in range(11):
        obs = world.begin_step(s, p)
        out = world.step(s, p, obs, np.array([[WEST, EAST]]))
        meas.observe(out, s.wait, s.charge)
        modes.append(int(s.mode[0, 0]))
    assert modes == [PATROL] + [QUEUED] * 6 + [HOMING] * 3 + [PATROL]
    return meas


@pytest.mark.parametrize(
    "warmup, max_wait, waits",
    [
        (0, 6, 6),  # robot 0 waits at steps 2..7, 6 steps in a row
        (4, 6, 3),  # the stretch reaches 6 at step 7, in the window; steps 5, 6, 7 counted
        (7, 0, 0),  # the window starts at step 8: nobody waits there
    ],
)
def test_max_wait_on_a_station_queue(warmup, max_wait, waits):
    meas = queue_scenario(warmup)
    assert meas.max_wait[0] == max_wait
    assert meas.wait_total[0] == waits
    # robot 0 is 1 move from H with charge 1 after step 10; it arrives at step 11 and,
    # with charge_steps 0, is full at once: the lowest charge seen after a step is 1
    assert meas.min_charge[0] == 1


# --- steps per episode ------------------------------------------------------------------


def test_mean_steps_per_episode_counts_complete_episodes_started_in_the_window():
    meas = Measures(2, 1, 3, warmup=10)
    meas.measured[:] = 5
    episodes = pd.DataFrame(
        {
            "run": [0, 0, 0, 0, 0, 1, 1],
            "start_step": [1, 9, 11, 20, 40, 12, 30],
            "steps": [8, 2, 9, 20, 7, 3, 50],
            "complete": [1, 1, 1, 1, 0, 0, 0],
        }
    )
    out = measures.summarize(meas, episodes, np.array([0, 1]), np.array([50, 50]), bound=0)
    # run 0: started after step 10 and complete: the episodes of 9 and 20 steps
    assert out[0]["mean_steps_per_episode"] == (9 + 20) / 2
    assert out[0]["episodes_completed"] == 4 and out[0]["episodes_truncated"] == 1
    # run 1: no complete episode
    assert out[1]["mean_steps_per_episode"] is None
    assert out[1]["episodes_truncated"] == 2


def test_mean_steps_per_episode_of_a_simulated_run(tmp_path):
    """One cyclic robot on the 12-ring with dots on three cells only (1, 5, 10). Once on
    its walk (0 4 6 8 9 10 11 7 5 3 2 1, one lap = 12 steps) it meets them in the order
    10, 5, 1. An episode ends on entering the cell of its last dot, say X; all dots come
    back, and the robot eats the other two and then X again one lap later: every
    episode that starts in the window lasts 12 steps. Warm-up 30 steps, past the
    gathering."""
    text = "-.--\n-##.\n-##-\n--.-\n"
    assert parse_map(text).dot_kind.nonzero()[0].tolist() == [1, 5, 10]
    cfg = from_flat(
        {
            "map": write(tmp_path, text),
            "agents": 1,
            "policy": "cyclic",
            "battery.enabled": False,
            "record.warmup": 30,
            "steps": 30 + 5 * N,
        }
    )
    r = simulate(cfg)
    ep = r.episodes
    window = ep[(ep.start_step > 30) & (ep.complete == 1)]
    assert len(window) >= 4 and (window.steps == 12).all()
    assert r.summary[0]["mean_steps_per_episode"] == 12


# --- brute force --------------------------------------------------------------------------


def positions(result) -> dict[int, np.ndarray]:
    """int ``[T + 1, K]`` per run: every robot's cell after each step, step 0 = start."""
    tr = result.trajectory
    cfg, p, m = result.config, result.params, result.map
    streams = Streams(run_seeds(cfg["seed"], result.run_ids.tolist()), p.n_agents)
    out = {}
    for i, run_id in enumerate(result.run_ids.tolist()):
        starts = world.place_agents(p, m, streams.generators[i])  # as simulate placed them
        mine = tr[tr.run == run_id].sort_values(["step", "agent"])
        steps = int(result.state.steps_done[i])
        assert mine.step.min() == 1 and mine.step.max() == steps  # the whole run is there
        cells = mine.cell.to_numpy().reshape(steps, -1)
        out[run_id] = np.vstack([starts[None, :], cells])
    return out


def brute_force(pos: np.ndarray, n_cells: int, warmup: int) -> dict:
    """The measures of one run from its positions, straight from their definitions."""
    steps, k = pos.shape[0] - 1, pos.shape[1]
    last = [0] * n_cells
    idle_sum = measured = worst = worst_closed = still = 0
    intervals = []
    window_visits = [[0] * n_cells for _ in range(k)]
    for t in range(1, steps + 1):
        for a in range(k):
            c = int(pos[t, a])
            if c == pos[t - 1, a]:
                still += 1
                continue  # no move, no visit
            if t > warmup:
                window_visits[a][c] += 1
                if last[c] > 0:
                    intervals.append(t - last[c])
                if t - 1 > warmup:
                    worst_closed = max(worst_closed, t - 1 - last[c])
            last[c] = t
        if t > warmup:
            idle = [t - last[c] for c in range(n_cells)]
            idle_sum += sum(idle)
            worst = max(worst, max(idle))
            measured += 1
    shares = []
    for c in range(n_cells):
        total = sum(window_visits[a][c] for a in range(k))
        if total:
            shares.append(max(window_visits[a][c] for a in range(k)) / total)
    return {
        "avg_idleness": idle_sum / (n_cells * measured),
        "worst_idleness": worst,
        "mean_interval": sum(intervals) / len(intervals),
        "max_interval": max(intervals),
        "coverage": sum(1 for c in range(n_cells) if any(v[c] for v in window_visits)) / n_cells,
        "division_of_labour": sum(shares) / len(shares),
        "window_visits": np.array(window_visits),
        "worst_closed_only": worst_closed,
        "zero_intervals": intervals.count(0),
        "still": still,
    }


def compare(result) -> list[dict]:
    """Assert that the run's summary equals the brute-force measures; return them."""
    warmup = result.config["record.warmup"]
    found = []
    for i, (run_id, pos) in enumerate(positions(result).items()):
        want = brute_force(pos, result.map.n_cells, warmup)
        got = result.summary[i]
        assert got["run"] == run_id
        for key in ("avg_idleness", "worst_idleness", "mean_interval", "max_interval"):
            assert got[key] == want[key], (run_id, key)
        assert got["coverage"] == want["coverage"], run_id
        assert got["division_of_labour"] == pytest.approx(want["division_of_labour"], rel=1e-12)
        assert np.array_equal(result.measures.window_visits[i], want["window_visits"])
        found.append(want)
    return found


def random_team(tmp_path: Path, **extra):
    """4 random robots (on the start digits of ROOMS), battery on, 4 runs."""
    flat = {
        "map": write(tmp_path, ROOMS, "rooms.txt"),
        "agents": 4,
        "runs": 4,
        "policy": "random",
        "battery.capacity": 30,
        "battery.charge_steps": 5,
        "record.warmup": 60,
        "steps": 400,
        "seed": 2,
    }
    flat.update(extra)
    flat["record.trajectory"] = flat["steps"]
    return simulate(from_flat(flat))


@pytest.mark.parametrize("steps", [100, 400])
def test_measures_equal_a_brute_force_recount(tmp_path, steps):
    result = random_team(tmp_path, steps=steps)
    found = compare(result)
    # not a trivial run: robots stood still (charging, waiting) in every run
    assert all(w["still"] > 0 for w in found)
    assert result.measures.min_charge.max() < 30


def test_measures_equal_a_brute_force_recount_without_collision_avoidance(tmp_path):
    """Without collision avoidance robots may enter one cell in the same step. The
    brute force counts each robot's entry as a visit (as the measures do): the second
    entry of a cell in a step closes an interval of 0."""
    result = random_team(tmp_path, **{"team.avoid_collisions": False, "agents": 6})
    found = compare(result)
    assert sum(w["zero_intervals"] for w in found) > 0  # it did happen


def test_measures_equal_a_brute_force_recount_with_an_episode_quota(tmp_path):
    result = random_team(tmp_path, episodes=3, steps=3000)
    done = result.state.steps_done
    assert (done < 3000).all() and len(set(done.tolist())) > 1  # runs stopped, unevenly
    compare(result)


def test_a_broken_idleness_sum_is_caught(tmp_path, monkeypatch):
    """The guard works: an idleness sum off by one per visit fails the comparison."""
    observe = Measures.observe

    def off_by_one(self, out, wait, charge, *rest):
        observe(self, out, wait, charge, *rest)
        self.last_sum -= out.moved.sum(axis=1)  # as if each visit were one step earlier

    monkeypatch.setattr(Measures, "observe", off_by_one)
    result = random_team(tmp_path)
    with pytest.raises(AssertionError, match="avg_idleness"):
        compare(result)


def test_a_worst_idleness_without_open_gaps_is_caught(tmp_path, monkeypatch):
    """The guard works: a worst idleness that forgets the gaps still open at the end of
    the run fails the comparison, as soon as one run has an open gap as its worst (a
    window of 40 steps, in which random robots leave some cells unvisited)."""
    monkeypatch.setattr(Measures, "worst_idleness", lambda self, steps_done: self.worst.copy())
    result = random_team(tmp_path, steps=100)
    want = [brute_force(pos, result.map.n_cells, 60) for pos in positions(result).values()]
    assert any(w["worst_idleness"] > w["worst_closed_only"] for w in want)  # it matters
    with pytest.raises(AssertionError, match="worst_idleness"):
        compare(result)
