"""How robots meet (``team.interaction``): ``exclusive``, ``interference`` and ``none``.

By hand, each engine alone (:class:`test_station_rules.Team`: the ``random`` strategy
with a fixed uniform per robot; on a one-wide horizontal line a robot's moves are East
and West, so ``FIRST`` asks East and ``LAST`` West): robots pass each other under
``none`` and ``interference`` and never under ``exclusive``; under ``interference`` the
robot of higher index stops for ``interference_steps`` steps when it comes within
``interference_radius`` moves of a lower-numbered robot (or swaps cells with one at
radius 0), at most once per ``interference_cooldown`` steps, and a failed robot counts
for nothing. Then the two engines to the bit on every compiled strategy, grids and a
graph with waypoints, battery on and off, failures; the wait bounds; and the battery
with passing robots: no pocket closes, no room rule refuses a team, and 12 robots on a
floor of dead-end rooms with docks at their ends are accepted and live.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from covering import pairs
from test_station_rules import FIRST, LAST, Team

from qpatrol import measures, world
from qpatrol.config import ConfigError, from_flat
from qpatrol.maps import available_maps, get_map, parse_map
from qpatrol.world import interference
from qpatrol.world.battery import GONE

HAS_NUMBA = importlib.util.find_spec("numba") is not None

#: A one-wide line of n cells, numbered 0..n-1 from the west.
LINE10 = "#" * 12 + "\n#" + "." * 10 + "#\n" + "#" * 12 + "\n"
LINE16 = "#" * 18 + "\n#" + "." * 16 + "#\n" + "#" * 18 + "\n"

STOP = {"team.interaction": "interference", "team.interference_radius": 2}
STOP["team.interference_steps"] = 3
STOP.update({"team.interference_cooldown": 10, "battery.enabled": False})


@pytest.fixture(params=["numpy", "numba"])
def engine(request) -> str:
    if request.param == "numba":
        pytest.importorskip("numba")
    return request.param


def positions(team: Team, steps: int, picks: list[float]) -> list[tuple[int, ...]]:
    """Each robot's cell after each of ``steps`` steps taken with ``picks``."""
    out = []
    for _ in range(steps):
        team.step(picks)
        out.append(tuple(team.s.pos[0].tolist()))
    return out


@pytest.mark.parametrize("interaction", ["none", "interference", "exclusive"])
def test_robots_pass_each_other_unless_exclusive(engine, interaction):
    """Robot 0 walks East from cell 0, robot 1 West from cell 9. Without interference
    they cross between steps 4 and 5 (sharing no cell: 4/5, then 5/4); exclusive, they
    never pass (robot 1 is pushed back East by the right of way or they wait)."""
    flat = {**STOP, "team.interaction": interaction, "team.interference_radius": 0}
    team = Team(engine, LINE10, [0, 9], **flat)
    got = positions(team, 6, [FIRST, LAST])
    if interaction == "exclusive":
        assert all(a < b for a, b in got)
    else:  # a swap at radius 0 stops robot 1 under interference
        assert got[:5] == [(1, 8), (2, 7), (3, 6), (4, 5), (5, 4)]
        assert got[5] == ((6, 3) if interaction == "none" else (6, 4))


def test_the_higher_robot_stops_when_it_comes_within_the_radius(engine):
    """Radius 2, stops of 3 steps. The robots walk towards each other from cells 0 and
    9: after step 4 they stand on 4 and 5, one move apart (after step 3: three), so
    robot 1 meets robot 0 and does not move in steps 5, 6 and 7, while robot 0 walks
    through its cell (sharing it in step 5) and on; robot 1 walks again in step 8. Robot
    0 never stops (no robot has a lower index). Each refused move is a wait."""
    team = Team(engine, LINE10, [0, 9], **STOP)
    got = positions(team, 4, [FIRST, LAST])
    assert got == [(1, 8), (2, 7), (3, 6), (4, 5)]
    assert team.s.met[0].tolist() == [interference.NEVER, 4]
    waits = []
    for _ in range(4):
        team.step([FIRST, LAST])
        waits.append(tuple(team.s.wait[0].tolist()))
        got.append(tuple(team.s.pos[0].tolist()))
    assert got[4:] == [(5, 5), (6, 5), (7, 5), (8, 4)]
    assert waits == [(0, 1), (0, 2), (0, 3), (0, 0)]
    assert team.s.met[0].tolist() == [interference.NEVER, 4]


def test_a_robot_meets_again_only_after_the_cooldown(engine):
    """Robot 1 on cell 2 walks East ahead of robot 0 on cell 0: after step 1 they are 2
    apart (cells 1 and 3), so robot 1 stops in steps 2-4 while robot 0 catches up; from
    step 5 both walk East one move apart. A meeting is possible again 10 steps after the
    first: at the end of step 11 (not of step 10) robot 1 stops again."""
    team = Team(engine, LINE16, [0, 2], **STOP)
    got = positions(team, 10, [FIRST, FIRST])
    assert got[:5] == [(1, 3), (2, 3), (3, 3), (4, 3), (5, 4)]
    assert got[9] == (10, 9)
    assert team.s.met[0, 1] == 1  # one move apart since step 5, cooling down
    team.step([FIRST, FIRST])
    assert tuple(team.s.pos[0].tolist()) == (11, 10)
    assert team.s.met[0, 1] == 11
    assert positions(team, 2, [FIRST, FIRST]) == [(12, 10), (13, 10)]


@pytest.mark.parametrize("start, expect", [(1, 1), (2, 1), (3, interference.NEVER)])
def test_radius_zero_meets_on_one_cell_or_by_a_swap(engine, start, expect):
    """At radius 0 robot 1 meets robot 0 only when they swap cells (start 1: cells 0 and
    1 exchanged in step 1) or share one (start 2: both on cell 1), not one move apart
    (start 3: cells 1 and 2 after step 1)."""
    flat = {**STOP, "team.interference_radius": 0}
    team = Team(engine, LINE10, [0, start], **flat)
    team.step([FIRST, LAST])
    assert team.s.met[0, 1] == expect
    assert team.s.met[0, 0] == interference.NEVER


def test_a_failed_robot_stands_nowhere(engine):
    """Robot 0 has failed (mode gone) on cell 4; robot 1 walks West past it from cell 6
    and never stops; robot 2, walking East from cell 0, meets robot 1 at the end of step
    2 (cells 2 and 4). Only robots on the map count."""
    team = Team(engine, LINE10, [4, 6, 0], **{**STOP, "agents": 3})
    team.s.mode[0, 0] = GONE
    for _ in range(4):
        team.step([FIRST, LAST, FIRST])
    assert team.s.met[0].tolist() == [interference.NEVER, interference.NEVER, 2]
    assert team.s.pos[0, 1] == 2


def test_dropping_the_stop_is_caught(monkeypatch):
    """The stop itself: with ``stopped`` always False (the rule dropped from the numpy
    engine), the hand case of :func:`test_the_higher_robot_stops_when_it_comes_within_the_radius`
    fails."""
    monkeypatch.setattr(interference, "stopped", lambda s, p: np.zeros(s.pos.shape, bool))
    with pytest.raises(AssertionError):
        test_the_higher_robot_stops_when_it_comes_within_the_radius("numpy")


def test_interferences_and_waits_count_the_stopped_steps(tmp_path):
    """``interferences`` counts the robot-steps a move was refused: under interference
    each stop that falls in the window, as steps; under none, nothing."""
    from qpatrol.run import simulate

    m = "map_a"
    flat = {"map": m, "agents": 6, "policy": "conscientious", "steps": 600, "runs": 2}
    flat.update({"battery.enabled": False, "record.warmup": 100})
    none = simulate(from_flat({**flat, "team.interaction": "none"})).summary
    stops = simulate(from_flat({**flat, "team.interaction": "interference"})).summary
    assert [r["interferences"] for r in none] == [0, 0]
    assert [r["max_wait"] for r in none] == [0, 0]
    for r in stops:
        assert r["interferences"] > 0 and r["interferences"] == r["waits"]
        assert r["max_wait"] == 3 and r["max_stall"] <= r["stall_bound"] and r["live"]


# --- the two engines -----------------------------------------------------------------

LONG_GRAPH = """\
; name: longedges
; kind: graph
v 0 0 0 start=0
v 1 4 0
v 2 2 3 station
v 3 0 4
v 4 5 5
e 0 1 3
e 1 2 2
e 2 0 4
e 0 3 1
e 3 2 2
e 1 4 3
e 0 4 4
"""


def compiled_policies() -> tuple[str, ...]:
    from qpatrol.engines import COMPILED_POLICIES

    return COMPILED_POLICIES


#: (strategy, map kind, battery, radius): each compiled strategy on a grid and on the
#: graph, the battery and a radius of 0 or 2 turning through their pairs.
ENGINE_ROWS = [
    (policy, kind, (i + j) % 2 == 0, 0 if (i + j) % 3 == 0 else 2)
    for i, policy in enumerate(compiled_policies())
    for j, kind in enumerate(("grid", "graph"))
]


def _engine_map(kind: str, rooms_map, tmp_path) -> str:
    """The map of an engine-agreement case: the rooms grid, or the graph of long edges."""
    if kind == "grid":
        return str(rooms_map)
    path = tmp_path / "longedges.txt"
    path.write_text(LONG_GRAPH)
    return str(path)


@pytest.mark.skipif(not HAS_NUMBA, reason="the compiled engine needs numba")
@pytest.mark.parametrize("policy, kind, battery, radius", ENGINE_ROWS)
def test_both_engines_alike_under_interference(rooms_map, tmp_path, policy, kind, battery, radius):
    """Every compiled strategy under ``interference``, grid and graph, battery on and
    off: the same files to the bit, strategy arrays and ``met`` included."""
    from test_engines import both

    m = _engine_map(kind, rooms_map, tmp_path)
    flat = {
        "map": m, "policy": policy, "agents": 5, "runs": 2, "seed": 7, "steps": 260,
        "record.trajectory": 260, "team.interaction": "interference",
        "team.interference_radius": radius, "team.interference_steps": 2,
        "team.interference_cooldown": 5, "battery.enabled": battery,
        "battery.capacity": 60, "battery.charge_steps": 3, "record.warmup": 30,
    }  # fmt: skip
    assert both(flat, tmp_path, strategy=True) == ("numba", "")


@pytest.mark.skipif(not HAS_NUMBA, reason="the compiled engine needs numba")
@pytest.mark.parametrize("policy, kind, battery, radius", ENGINE_ROWS)
def test_both_engines_alike_when_robots_ignore_each_other(
    rooms_map, tmp_path, policy, kind, battery, radius
):
    """Every compiled strategy under ``none`` (robots share cells), grid and graph,
    battery on and off (the other of each pair than under interference): alike."""
    from test_engines import both

    m = _engine_map(kind, rooms_map, tmp_path)
    flat = {
        "map": m, "policy": policy, "agents": 5, "runs": 2, "seed": 8, "steps": 200,
        "record.trajectory": 200, "team.interaction": "none", "battery.enabled": not battery,
        "battery.capacity": 60, "battery.charge_steps": 3, "record.warmup": 30,
    }  # fmt: skip
    assert both(flat, tmp_path, strategy=True) == ("numba", "")


@pytest.mark.skipif(not HAS_NUMBA, reason="the compiled engine needs numba")
@pytest.mark.parametrize(
    "interaction, policy, failures",
    pairs(
        [("interference", "none"), ("qlearning", "cyclic", "dta-ssi"), (0, 2)],
        [
            ("interference", "qlearning", 2),
            ("interference", "cyclic", 0),
            ("interference", "dta-ssi", 2),
            ("none", "qlearning", 0),
            ("none", "cyclic", 2),
            ("none", "dta-ssi", 0),
        ],
    ),
)
def test_both_engines_alike_with_failures_and_recorders(
    rooms_map, tmp_path, interaction, policy, failures
):
    """Robots failing in the middle, every recorder, communication off: alike."""
    from test_engines import both

    flat = {
        "map": str(rooms_map), "policy": policy, "agents": 4, "runs": 2, "seed": 3,
        "steps": 300, "team.interaction": interaction, "failures.robots": failures,
        "failures.at": 120, "record.timeline": 50, "record.trajectory": 20,
        "team.communication": False, "battery.capacity": 40, "battery.charge_steps": 4,
        "record.transitions": policy == "qlearning",
    }  # fmt: skip
    assert both(flat, tmp_path) == ("numba", "")


# --- wait bounds ---------------------------------------------------------------------


def test_travel_steps_and_stall_bounds_by_hand():
    """A trip of d moves with stops of 3 at most once per 10 steps, at worst each block
    of 10 steps starting with a stop: 1 move takes 4 steps, 7 take 10, 8 take 14 (the
    next block's stop, then a move), 14 take 20, 15 take 24. The stall bound is K trips
    of the diameter without battery (a trip of D moves under none); with it the queue's
    bound with the trip's steps."""
    m = get_map("map_a")
    p = world.make_params(from_flat({**STOP, "team.interaction": "interference"}), m)
    assert [interference.travel_steps(d, p) for d in (0, 1, 7, 8, 14, 15)] == [0, 4, 10, 14, 20, 24]
    assert measures.stall_bound(p) == p.n_agents * interference.travel_steps(p.diameter, p)
    none = world.make_params(from_flat({"battery.enabled": False, "team.interaction": "none"}), m)
    assert measures.stall_bound(none) == none.n_agents * none.diameter
    assert interference.travel_steps(9, none) == 9
    on = {"team.interaction": "interference", "battery.charge_steps": 50}
    pb = world.make_params(from_flat(on), m)
    trip = interference.travel_steps(pb.diameter, pb)
    turnaround = 50 + 2 * int(pb.depart_len.max()) + 2 * trip + 1
    assert measures.stall_bound(pb) == pb.n_agents * turnaround + trip


# --- the battery when robots pass ----------------------------------------------------

#: A corridor with four side rooms of 3 x 4 cells, each a dead end behind a one-wide
#: door, a charging dock at the far end of each (72 cells).
DOCK_ROOMS = """; name: dock-rooms
######################
#....................#
###.####.####.####.###
##...##...##...##...##
##...##...##...##...##
##...##...##...##...##
##.H.##.H.##.H.##.H.##
######################
"""


def test_no_pocket_closes_when_robots_pass():
    """A station at the end of a one-wide dead end has a pocket only under exclusive:
    with robots passing each other nothing is closed, so no move is refused for it."""
    m = parse_map("; name: t\n...H\n#.##\n#.##\n")
    for interaction, has in (("exclusive", True), ("interference", False), ("none", False)):
        p = world.make_params(from_flat({"agents": 1, "team.interaction": interaction}), m)
        assert bool((p.pocket_of >= 0).any()) == has
        assert bool((p.pocket_entry >= 0).any()) == has


def test_twelve_robots_with_docks_in_dead_end_rooms_are_refused_only_when_exclusive():
    m = parse_map(DOCK_ROOMS)
    assert m.n_cells == 72
    flat = {"agents": 12, "battery.enabled": True}
    with pytest.raises(ConfigError, match="agents: 12 robots with battery.enabled"):
        world.make_params(from_flat({**flat, "team.interaction": "exclusive"}), m)
    for interaction in ("interference", "none"):
        world.make_params(from_flat({**flat, "team.interaction": interaction}), m)


@pytest.mark.parametrize("policy", ["conscientious", "cyclic", "cc", "qlearning"])
def test_eleven_exclusive_robots_on_dock_rooms_are_accepted_and_live(tmp_path, policy):
    """Under ``exclusive`` the room rules accept 11 robots on the dock rooms (12 are
    refused: the room ahead of a room's door), and 11 run live with the battery on:
    every target visited in the window, no stretch without progress past the bound,
    no charge below 0."""
    _dock_rooms_are_live(tmp_path, policy, 11, {"engine": "numba"})


@pytest.mark.parametrize("interaction", ["interference", "none"])
@pytest.mark.parametrize("policy", ["conscientious", "cyclic", "cc"])
def test_twelve_robots_on_dock_rooms_are_live(tmp_path, interaction, policy):
    """12 robots, battery on (a charge every ~100 moves, four docks), 3,000 steps: every
    robot charges, every target is visited in the window, no wait past the bound, no
    charge below 0."""
    _dock_rooms_are_live(tmp_path, policy, 12, {"team.interaction": interaction})


def _dock_rooms_are_live(tmp_path, policy: str, agents: int, extra: dict) -> None:
    """``agents`` robots of ``policy`` on the dock rooms, battery on (a charge every ~100
    moves), 2 runs x 3,000 steps, warm-up 1,000: every run live, every target visited in
    the window, no stretch without progress past the bound, no charge below 0."""
    from qpatrol.run import simulate

    path = tmp_path / "dock.txt"
    path.write_text(DOCK_ROOMS)
    flat = {
        "map": str(path), "agents": agents, "policy": policy, "runs": 2, "steps": 3000,
        "record.warmup": 1000, "battery.capacity": 100, "battery.charge_steps": 10,
        "seed": 5, **extra,
    }  # fmt: skip
    for r in simulate(from_flat(flat)).summary:
        assert r["live"] and r["max_stall"] <= r["stall_bound"]
        assert r["coverage"] == 1.0
        assert r["min_charge"] >= 0


def test_no_shipped_map_refuses_half_its_cells_when_robots_pass():
    """Battery on: under interference and none, a team of half the free cells fits on
    every shipped map (the room rules are exclusive's)."""
    for name in available_maps():
        m = get_map(name)
        k = min(64, m.n_cells // 2)
        for interaction in ("interference", "none"):
            flat = {"agents": k, "team.interaction": interaction, "map": name}
            world.make_params(from_flat(flat), m)
