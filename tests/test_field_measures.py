"""The patrolling field's measures (qmi, std_interval, freq_std, the targets' average
intervals, cycles, interferences) by hand on tiny graph and grid maps, in each engine on
its own, and every measure over target cells only (a graph's waypoints never count).

Definitions as implemented (``docs/model.md``, "Patrolling measures"), over the window
of team steps ``t > record.warmup``: an *interval* is ``t - previous visit`` for each
visit of a target at a window step t, if the target was entered before (at any step >=
1, warm-up included); ``qmi = sqrt(mean interval^2)``; ``std_interval`` the population
standard deviation of the intervals; ``freq_std`` the population standard deviation
over targets of (window visits / window steps); a target's *average* is the mean of its
intervals, or, with none, its idleness at the end (steps - last visit, steps if never
entered); ``worst_avg_idleness``, ``mean_avg_idleness``, ``median_idleness``,
``std_idleness`` their max, mean, median and population standard deviation over
targets; ``cycles`` the covers completed in the window (a cover: every target entered
at a step of it; the next starts at the step after); ``interferences`` the robot-steps
of the window in which a robot asked for a move and did not make it.
"""

from __future__ import annotations

import importlib.util
import math
import statistics
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from qpatrol import measures, world
from qpatrol.config import from_flat
from qpatrol.maps import parse_map
from qpatrol.measures import Measures
from qpatrol.run import simulate
from qpatrol.world.rng import Streams, run_seeds

NUMBA = importlib.util.find_spec("numba") is not None
ENGINES = [
    "numpy",
    pytest.param("numba", marks=pytest.mark.skipif(not NUMBA, reason="numba not installed")),
]

# Two loops through vertex 0 (degree 4, so D = 4): A = 0-1-2-0 whose edge 1-2 takes two
# moves (its waypoint is cell 5), B = 0-3-4-0. Ports of vertex 0, in file order: 1, 2, 3, 4.
EIGHT = """\
; name: eight
; kind: graph
v 0 0 0 start=0
v 1 -1 1
v 2 -1 -1
v 3 1 1
v 4 1 -1
e 0 1 1
e 1 2 2
e 2 0 1
e 0 3 1
e 3 4 1
e 4 0 1
"""
WAYPOINT = 5
# The figure eight with a two-move edge 2-0 too (waypoint 6): loop A = 0-1-5-2-6-0 (5
# moves) is then strictly shorter than its out-and-back alternatives (6 moves), so the
# cyclic walk, which need not walk every edge (only visit every vertex), takes the
# waypoints: a lap is loop A and loop B = 0-3-4-0 (3 moves), 8 steps.
EIGHT_LONG = EIGHT.replace("e 2 0 1", "e 2 0 2")

# A 3 x 3 lattice of vertices (the centre 4 has degree 4) with edges of 1 to 3 moves:
#   0 -- 1 --- 2
#   |    |     |
#   3 -- 4 ---- 5      (the long edges have waypoints: 7 in all)
#   |    |     |
#   6 --- 7 -- 8
LATTICE = """\
; name: lattice
; kind: graph
v 0 0 2 start=0
v 1 1 2
v 2 2 2
v 3 0 1 start=1
v 4 1 1
v 5 2 1
v 6 0 0
v 7 1 0
v 8 2 0 start=2
e 0 1 1
e 1 2 2
e 3 4 1
e 4 5 3
e 6 7 2
e 7 8 1
e 0 3 2
e 3 6 1
e 1 4 1
e 4 7 2
e 2 5 1
e 5 8 2
"""

# a one-wide ring of 12 grid cells (tests/test_measures.py)
RING12 = "....\n.##.\n.##.\n....\n"

FIELD = measures.FIELD_MEASURES


def write(tmp_path: Path, text: str, name: str) -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def run(tmp_path: Path, text: str, engine: str, **flat):
    cfg = {"map": write(tmp_path, text, "m.txt"), "battery.enabled": False, "engine": engine}
    cfg.update(flat)
    result = simulate(from_flat(cfg))
    assert result.engine == engine
    return result


# --- by hand: a cyclic robot on the figure eight ----------------------------------------


@pytest.mark.parametrize("engine", ENGINES)
def test_one_cyclic_robot_on_a_figure_eight_by_hand(tmp_path, engine):
    """One cyclic robot walks loop A 0 1 5 2 6 (5 and 6 the waypoints) and loop B 0 3 4:
    a lap of 8 steps. Warm-up 10 laps, then 4 laps (32 steps) measured.

    Targets 1..4 are entered once a lap: 4 window intervals of 8 each; vertex 0 twice,
    alternately after 5 and 3 steps: 4 intervals of 5 and 4 of 3. So N = 24 intervals,
    sum 16 x 8 + 4 x 5 + 4 x 3 = 160, sum of squares 16 x 64 + 4 x 25 + 4 x 9 = 1160:
    mean_interval 160/24, qmi sqrt(1160/24), std_interval sqrt(24 x 1160 - 160^2)/24 =
    sqrt(2240)/24. The waypoints count in none: with them the mean would be 224/32 = 7.
    Averages by target: 4 (vertex 0), 8, 8, 8, 8: worst 8, mean 36/5 = 7.2, median 8,
    population std sqrt(((4-7.2)^2 + 4 x 0.8^2)/5) = sqrt(2.56) = 1.6.
    Window visits 8, 4, 4, 4, 4 in 32 steps: freq_std = sqrt(5 x 128 - 24^2)/(5 x 32)
    = 8/160. Cycles: from any step of the lap every target is entered within 8 steps,
    and after the first cover each takes one lap: 4 covers in 32 steps. One robot is
    never blocked: no interference.

    Today's measures over the 5 targets: idleness summed over a lap is 0+...+7 = 28
    for each of 1..4 and 0+1+2+3+4+0+1+2 = 13 for vertex 0: avg_idleness 4 x 125 / (5 x
    32); worst 7 (a target of 1..4 just before its visit).
    """
    r = run(
        tmp_path, EIGHT_LONG, engine, agents=1, policy="cyclic", **{"record.warmup": 80}, steps=112
    )
    s = r.summary[0]
    assert r.map.n_targets == 5 and not r.map.target[5:].any()
    assert s["mean_interval"] == 160 / 24 and s["max_interval"] == 8
    assert s["qmi"] == math.sqrt(1160 / 24)
    assert s["std_interval"] == math.sqrt(2240) / 24
    assert s["worst_avg_idleness"] == 8.0
    assert s["mean_avg_idleness"] == pytest.approx(7.2, rel=1e-15)
    assert s["median_idleness"] == 8.0
    assert s["std_idleness"] == pytest.approx(1.6, rel=1e-15)
    assert s["freq_std"] == 8 / 160
    assert s["cycles"] == 4
    assert s["interferences"] == 0
    assert s["avg_idleness"] == 4 * 125 / (5 * 32)
    assert s["worst_idleness"] == 7
    assert s["coverage"] == 1.0
    assert r.measures.window_visits[0, 0].tolist() == [8, 4, 4, 4, 4, 0, 0]  # no waypoint
    assert r.measures.visits[0, 0, 5:].tolist() == [14, 14]  # but the robot did pass them
    assert r.measures.last[0, 5:].tolist() == [0, 0]


@pytest.mark.parametrize("engine", ENGINES)
def test_two_cyclic_robots_on_a_grid_ring_by_hand(tmp_path, engine):
    """Two cyclic robots 6 cells apart on the 12-ring (every cell a target), 4 laps of
    12 steps measured after a warm-up of 5 laps: every cell is entered every 6 steps,
    by the two robots in turn. Every interval is 6: qmi 6, std_interval 0; every
    target's average 6: worst, mean and median 6, std 0; every cell entered 8 times in
    48 steps: freq_std 0. In any 6 consecutive steps the two robots enter 6 cells each,
    all 12: a cover every 6 steps, 8 in the window. The robots keep their spacing and
    never block each other."""
    r = run(tmp_path, RING12, engine, agents=2, policy="cyclic", **{"record.warmup": 60}, steps=108)
    s = r.summary[0]
    assert s["qmi"] == 6.0 and s["std_interval"] == 0.0
    for key in ("worst_avg_idleness", "mean_avg_idleness", "median_idleness"):
        assert s[key] == 6.0, key
    assert s["std_idleness"] == 0.0 and s["freq_std"] == 0.0
    assert s["cycles"] == 8
    assert s["interferences"] == 0 and s["waits"] == 0


# --- by hand: forced moves with the numpy world ------------------------------------------


def forced(cells: list[int], warmup: int) -> dict:
    """One robot on the figure eight (start: vertex 0) made to enter ``cells`` one per
    step, with the numpy world (each move by the port that leads there); the summary."""
    cfg = from_flat({"agents": 1, "battery.enabled": False})
    m = parse_map(EIGHT)
    p = world.make_params(cfg, m)
    s = world.init_state(p, np.array([[0]]))
    meas = Measures(1, 1, m.n_cells, warmup, p.target)
    for c in cells:
        port = m.neighbors[s.pos[0, 0]].tolist().index(c)
        obs = world.begin_step(s, p)
        out = world.step(s, p, obs, np.array([[port]]))
        meas.observe(out, s.wait, None)
    no_episodes = pd.DataFrame({"run": [], "complete": [], "start_step": [], "steps": []})
    return measures.summarize(meas, no_episodes, np.array([0]), s.steps_done, bound=0)[0]


# steps 1..12: 1 w 2 0 1 0 1 0 3 4 0 1 (w = the waypoint, cell 5)
WALK = [1, WAYPOINT, 2, 0, 1, 0, 1, 0, 3, 4, 0, 1]


def test_forced_walk_by_hand_whole_run():
    """Warm-up 0, window steps 1..12. Target visits: 1@1, 2@3, 0@4, 1@5, 0@6, 1@7, 0@8,
    3@9, 4@10, 0@11, 1@12 (the waypoint at step 2 is none).

    Intervals: 1@5: 4, 0@6: 2, 1@7: 2, 0@8: 2, 0@11: 3, 1@12: 5; N = 6, sum 18, squares
    62: qmi sqrt(62/6), std_interval sqrt(6 x 62 - 18^2)/6 = sqrt(48)/6. Averages: vertex
    0 (2+2+3)/3 = 7/3, vertex 1 (4+2+5)/3 = 11/3; 2, 3, 4 have no interval and count with
    their idleness at the end: 12-3 = 9, 12-9 = 3, 12-10 = 2. Worst 9, mean (7/3 + 11/3
    + 14)/5 = 4, median of 2, 7/3, 3, 11/3, 9: 3, std sqrt(((7/3-4)^2 + (11/3-4)^2 + 25 +
    1 + 4)/5) = sqrt(296/45). Window visits 4, 4, 1, 1, 1 in 12 steps: freq_std =
    sqrt(5 x 35 - 11^2)/(5 x 12) = sqrt(54)/60. Every target is entered by step 10: one
    cover; the next, from step 11, sees 0 and 1 only. Nothing blocks: 0 interferences.
    """
    s = forced(WALK, warmup=0)
    assert s["mean_interval"] == 3 and s["max_interval"] == 5
    assert s["qmi"] == math.sqrt(62 / 6)
    assert s["std_interval"] == math.sqrt(48) / 6
    assert s["worst_avg_idleness"] == 9.0
    assert s["mean_avg_idleness"] == pytest.approx(4.0, rel=1e-15)
    assert s["median_idleness"] == 3.0
    assert s["std_idleness"] == pytest.approx(math.sqrt(296 / 45), rel=1e-14)
    assert s["freq_std"] == math.sqrt(54) / 60
    assert s["cycles"] == 1
    assert s["interferences"] == 0
    assert s["worst_idleness"] == 9  # vertex 4, not entered before step 10
    assert s["coverage"] == 1.0


def test_forced_walk_by_hand_after_a_warm_up():
    """The same walk with warm-up 4 (window steps 5..12, 8 steps). Every interval ends
    in the window (the first, 1@5, began at step 1, before it: it counts, as in
    mean_interval): qmi, std_interval and the averages are those of the whole run.
    Window visits 3, 3, 0, 1, 1: freq_std = sqrt(5 x 20 - 8^2)/(5 x 8) = 6/40. The
    cover under way from step 5 sees 1, 0, 3, 4 but never 2 again: no cycle (the visit
    of 2 at step 3, before the window, does not count)."""
    s = forced(WALK, warmup=4)
    assert s["qmi"] == math.sqrt(62 / 6)
    assert s["std_interval"] == math.sqrt(48) / 6
    assert s["worst_avg_idleness"] == 9.0 and s["median_idleness"] == 3.0
    assert s["freq_std"] == 6 / 40
    assert s["cycles"] == 0


def test_interferences_by_hand():
    """Robot 0 on vertex 0 asks for vertex 3 (port 2) twice; robot 1 stands on 3 and asks
    for nothing. Step 1: the cell is taken, robot 0 stays (1 interference) and gets the
    right of way; step 2: it pushes robot 1 on to 4 and moves as asked (robot 1 moved
    without asking: no interference). Warm-up 1: step 1 is outside the window, 0.
    Without collision avoidance robot 0 enters at once: 0."""

    def two(warmup: int, avoid: bool) -> Measures:
        cfg = from_flat({"agents": 2, "battery.enabled": False, "team.avoid_collisions": avoid})
        m = parse_map(EIGHT)
        p = world.make_params(cfg, m)
        s = world.init_state(p, np.array([[0, 3]]))
        meas = Measures(1, 2, m.n_cells, warmup, p.target)
        for _ in range(2):
            obs = world.begin_step(s, p)
            out = world.step(s, p, obs, np.array([[2, -1]]))
            meas.observe(out, s.wait, None)
        assert s.pos[0, 0] == 3
        return meas

    assert two(0, True).interferences[0] == 1
    assert two(1, True).interferences[0] == 0
    assert two(0, False).interferences[0] == 0


# --- brute force: every measure over targets only, recounted from the trajectory ------


def positions(result) -> dict[int, np.ndarray]:
    """int ``[T + 1, K]`` per run: every robot's cell after each step, step 0 = start."""
    tr = result.trajectory
    cfg, p, m = result.config, result.params, result.map
    streams = Streams(run_seeds(cfg["seed"], result.run_ids.tolist()), p.n_agents)
    out = {}
    for i, run_id in enumerate(result.run_ids.tolist()):
        starts = world.place_agents(p, m, streams.generators[i])
        mine = tr[tr.run == run_id].sort_values(["step", "agent"])
        steps = int(result.state.steps_done[i])
        assert mine.step.min() == 1 and mine.step.max() == steps
        cells = mine.cell.to_numpy().reshape(steps, -1)
        out[run_id] = np.vstack([starts[None, :], cells])
    return out


def brute_force(pos: np.ndarray, target: np.ndarray, warmup: int) -> dict:
    """The measures of one run from its positions, straight from their definitions,
    over the target cells only, with plain Python loops."""
    steps, k = pos.shape[0] - 1, pos.shape[1]
    targets = [c for c in range(target.size) if target[c]]
    last = dict.fromkeys(targets, 0)
    visits = dict.fromkeys(targets, 0)
    by_target: dict[int, list[int]] = {c: [] for c in targets}
    intervals: list[int] = []
    idle_sum = measured = worst = cycles = 0
    cover: set[int] = set()
    cover_from = warmup + 1
    for t in range(1, steps + 1):
        for a in range(k):
            c = int(pos[t, a])
            if c == pos[t - 1, a] or not target[c]:
                continue  # no move, or a waypoint: no visit
            if t > warmup:
                visits[c] += 1
                if last[c] > 0:
                    intervals.append(t - last[c])
                    by_target[c].append(t - last[c])
                if t >= cover_from:
                    cover.add(c)
                    if len(cover) == len(targets):
                        cycles += 1
                        cover, cover_from = set(), t + 1
            last[c] = t
        if t > warmup:
            idle = [t - last[c] for c in targets]
            idle_sum += sum(idle)
            worst = max(worst, *idle)
            measured += 1
    avg = [sum(g) / len(g) if g else steps - last[c] for c, g in by_target.items()]
    n = len(intervals)
    return {
        "avg_idleness": idle_sum / (len(targets) * measured),
        "worst_idleness": worst,
        "mean_interval": sum(intervals) / n,
        "max_interval": max(intervals),
        "coverage": sum(1 for c in targets if visits[c]) / len(targets),
        "qmi": math.sqrt(sum(g * g for g in intervals) / n),
        "std_interval": statistics.pstdev(intervals),
        "freq_std": statistics.pstdev([visits[c] / measured for c in targets]),
        "worst_avg_idleness": max(avg),
        "mean_avg_idleness": statistics.fmean(avg),
        "median_idleness": statistics.median(avg),
        "std_idleness": statistics.pstdev(avg),
        "cycles": cycles,
        "zero_intervals": intervals.count(0),
    }


EXACT = ("avg_idleness", "worst_idleness", "mean_interval", "max_interval", "coverage", "qmi")
EXACT += ("worst_avg_idleness", "cycles")


def compare(result) -> list[dict]:
    """Assert that the run's summary equals the brute-force recount; return it."""
    warmup = result.config["record.warmup"]
    found = []
    for i, (run_id, pos) in enumerate(positions(result).items()):
        want = brute_force(pos, result.map.target, warmup)
        got = result.summary[i]
        for key in EXACT:
            assert got[key] == want[key], (run_id, key)
        for key in ("std_interval", "freq_std", "mean_avg_idleness", "median_idleness"):
            assert got[key] == pytest.approx(want[key], rel=1e-12, abs=1e-12), (run_id, key)
        assert got["std_idleness"] == pytest.approx(want["std_idleness"], rel=1e-9, abs=1e-12)
        if not result.params.battery:  # every wait is a move another robot blocked
            assert got["interferences"] == got["waits"], run_id
        found.append(want)
    return found


def lattice_run(tmp_path: Path, engine: str, **extra):
    flat = {
        "agents": 3,
        "runs": 3,
        "policy": "random",
        "record.warmup": 40,
        "steps": 400,
        "seed": 5,
    }
    flat.update(extra)
    flat["record.trajectory"] = flat["steps"]
    return run(tmp_path, LATTICE, engine, **flat)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "extra",
    [
        {},
        {"team.avoid_collisions": False, "agents": 4},
        {"policy": "qlearning", "agents": 1},  # the compiled engine's lone-robot loop
        {"policy": "qlearning", "agents": 3},  # and its team loop
        {"policy": "conscientious", "record.timeline": 50},  # the general loop, timeline on
    ],
)
def test_graph_measures_equal_a_recount_over_vertices(tmp_path, engine, extra):
    """Random (or learning) robots on the lattice, whose 7 waypoints are in transit:
    every measure equals a recount over the 9 vertices from trajectory.csv."""
    result = lattice_run(tmp_path, engine, **extra)
    assert result.map.n_targets == 9 and result.map.n_cells == 16
    found = compare(result)
    assert sum(w["cycles"] for w in found) > 0  # covers did complete
    if extra.get("team.avoid_collisions") is False:
        assert sum(w["zero_intervals"] for w in found) > 0  # two entries in one step
    if result.timeline is not None:
        check_timeline(result)


def check_timeline(result) -> None:
    """timeline.csv over vertices only: each window's average and worst idleness."""
    window = result.config["record.timeline"]
    target = result.map.target
    for run_id, pos in positions(result).items():
        last = {c: 0 for c in range(target.size) if target[c]}
        rows = result.timeline[result.timeline.run == run_id]
        idle_sum, worst = {}, {}
        for t in range(1, pos.shape[0]):
            w = (t - 1) // window
            for a in range(pos.shape[1]):
                c = int(pos[t, a])
                if c != pos[t - 1, a] and target[c]:
                    last[c] = t
            idle = [t - v for v in last.values()]
            idle_sum[w] = idle_sum.get(w, 0) + sum(idle)
            worst[w] = max(worst.get(w, 0), *idle)
        assert rows.window.tolist() == sorted(idle_sum)
        for row in rows.itertuples():
            n = row.last_step - row.first_step + 1
            assert row.avg_idleness == idle_sum[row.window] / (len(last) * n)
            assert row.worst_idleness == worst[row.window]


def test_a_waypoint_counted_as_a_target_is_caught(tmp_path, monkeypatch):
    """The guard works: measures that count the waypoints too (every cell a target)
    differ from the recount over vertices."""
    real = Measures.__init__

    def every_cell(self, n_runs, n_agents, n_cells, warmup, target=None, *rest):
        real(self, n_runs, n_agents, n_cells, warmup, None, *rest)

    monkeypatch.setattr(Measures, "__init__", every_cell)
    result = lattice_run(tmp_path, "numpy", runs=1)
    with pytest.raises(AssertionError, match="avg_idleness"):
        compare(result)


@pytest.mark.parametrize("engine", ENGINES)
def test_interferences_with_the_battery(tmp_path, engine):
    """With batteries a robot also waits for a station, which is no interference: at
    most as many interferences as waits; and the engines count the same."""
    flat = {
        "agents": 4,
        "runs": 2,
        "policy": "random",
        "battery.enabled": True,
        "battery.capacity": 30,
        "battery.charge_steps": 5,
        "record.warmup": 60,
        "steps": 400,
        "seed": 2,
    }
    from conftest import ROOMS

    r = run(tmp_path, ROOMS, engine, **flat)
    for s in r.summary:
        assert 0 < s["interferences"] <= s["waits"]
    if engine == "numba":
        ref = run(tmp_path, ROOMS, "numpy", **flat)
        assert [s["interferences"] for s in r.summary] == [s["interferences"] for s in ref.summary]
