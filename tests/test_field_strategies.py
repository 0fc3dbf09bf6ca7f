"""The goal-following strategies of patrolling_sim: ``hcr``, ``cc``, ``gbs``, ``sebs``.

One decision of each, computed by hand on a tiny map (a patrol graph whose hub has four
edges of 2, 3, 1 and 2 moves, and a small grid); the two engines to the bit on grids and
graphs; and their safety and liveness (no shared cell, no swap, no wait past the bound)
with 1, 2 and 4 robots, battery on and off, on map A and on the graph.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from test_liveness import drive

from qpatrol import strategies, world
from qpatrol.config import from_flat
from qpatrol.maps import get_map, parse_map
from qpatrol.strategies import base, gbs, goals, sebs

FIELD = ("hcr", "cc", "gbs", "sebs")
FAST = "numba" if importlib.util.find_spec("numba") else "numpy"

#: Hub 1 reaches vertex 0 by port 0 (2 moves), 2 by port 1 (3), 3 by port 2 (1) and the
#: station 4 by port 3 (2); D = 4, 7 vertices and 9 waypoints.
GRAPH = """; name: hub4
; description: a small patrol graph whose hub has four edges (D = 4)
; kind: graph
v 0 0.0 0.0
v 1 2.0 0.0
v 2 5.0 0.0
v 3 2.0 1.0
v 4 2.0 -2.0 station
v 5 0.0 2.0
v 6 5.0 2.0
e 1 0 2
e 1 2 3
e 1 3 1
e 1 4 2
e 0 5 2
e 5 3 2
e 3 6 3
e 6 2 2
"""

GRID = """; name: loop
#######
#.....#
#.#.#.#
#..H..#
#######
"""


def setup(m, policy: str, starts: list[int], **extra):
    """A one-run world with robots on ``starts``, battery off, and its strategy."""
    cfg = from_flat(
        {"agents": len(starts), "policy": policy, "runs": 1, "battery.enabled": False, **extra}
    )
    p = world.make_params(cfg, m)
    start = np.array([starts], dtype=np.int64)
    return p, world.init_state(p, start), strategies.make(policy, cfg, m, p, start)


def decide(p, s, strat, t: int, u: float) -> np.ndarray:
    """The asks of the step ``t`` (every robot's tie-break uniform ``u``)."""
    s.t = t - 1
    obs = world.begin_step(s, p)
    uu = np.full((1, p.n_agents, 2), u)
    return strat.act(obs, uu)[0]


def decide_anywhere(p, s, strat, t: int, u: float) -> np.ndarray:
    """:func:`decide` with the strategy asked on a graph's waypoints too (the world does
    not ask it there: robots travel on; docs/model.md), to check its own rule off a
    target."""
    s.t = t - 1
    obs = world.begin_step(s, p)
    assert obs.travel is None or not (obs.choosing & (obs.travel >= 0)).any()
    uu = np.full((1, p.n_agents, 2), u)
    return strat.act(base.walking(obs), uu)[0]


def idle_at(s, t: int, idle: dict[int, int], group: int = 0) -> None:
    """Set the group's last visits so that cell c has idleness ``idle[c]`` at step t."""
    for c, i in idle.items():
        s.last[0, group, c] = t - i


def test_target_neighbours_walk_through_waypoints():
    m = parse_map(GRAPH)
    tnbr, tcost = goals.target_neighbours(m)
    assert m.n_ports == 4
    assert tnbr[1].tolist() == [0, 2, 3, 4] and tcost[1].tolist() == [2, 3, 1, 2]
    assert (tnbr[~m.target] == -1).all()  # waypoints decide nothing
    grid = parse_map(GRID)
    tn, tc = goals.target_neighbours(grid)
    assert (tn == grid.neighbors).all() and (tc[tn >= 0] == 1).all()


def test_hcr_weighs_idleness_against_distance():
    """Idleness 8, 9, 2, 4 at 2, 3, 1, 2 moves: scores (L_max - L)/L_max + I/I_max =
    1/3 + 8/9, 0 + 1, 2/3 + 2/9, 1/3 + 4/9: vertex 0 (1.22), not the idlest (2: 1.0) nor
    the nearest (3: 0.89)."""
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "hcr", [1])
    idle_at(s, 10, {0: 8, 2: 9, 3: 2, 4: 4})
    ask = decide(p, s, strat, 10, 0.0)
    assert strat.goal[0, 0] == 0 and ask[0] == 0
    # on a target that is not its goal (its first move was blocked), it chooses again
    strat.goal[0, 0] = 2
    decide(p, s, strat, 10, 0.0)
    assert strat.goal[0, 0] == 0
    # off its vertex, inside the edge, it keeps its goal and follows the edge
    s.pos[0, 0], s.occ[0] = m.neighbors[1, 0], -1
    s.occ[0, s.pos[0, 0]] = 0
    assert decide(p, s, strat, 11, 0.0)[0] < 0  # not asked: the world moves it on
    assert decide_anywhere(p, s, strat, 11, 0.0)[0] >= 0 and strat.goal[0, 0] == 0


def test_hcr_on_a_grid_is_the_idlest_open_neighbour():
    """All moves are 1 long: the distance term is 0 for every neighbour."""
    m = parse_map(GRID)
    c = m.state_at(1, 3)
    p, s, strat = setup(m, "hcr", [c])
    n, e, w = m.neighbors[c, 0], m.neighbors[c, 1], m.neighbors[c, 3]
    south = m.neighbors[c, 2]
    assert n < 0
    idle_at(s, 20, {e: 5, south: 7, w: 6})
    assert decide(p, s, strat, 20, 0.0)[0] == 2 and strat.goal[0, 0] == south


@pytest.mark.parametrize("battery", [True, False])
def test_hcr_on_a_grid_moves_as_shared_conscientious(battery):
    """On a grid every target is one move away, so the distance term is 0 and hcr's goal
    is the idlest open neighbour on the group map, ties broken alike: the same run."""
    from qpatrol.run import simulate

    base = {"agents": 4, "runs": 2, "steps": 400, "engine": "numpy"}
    base.update({"battery.enabled": battery, "record.trajectory": 400})
    hcr, sc = (simulate(from_flat({**base, "policy": p})) for p in ("hcr", "shared-conscientious"))
    assert (hcr.trajectory["cell"].to_numpy() == sc.trajectory["cell"].to_numpy()).all()
    assert hcr.summary == sc.summary


def test_cc_goes_to_its_own_oldest_target_by_a_shortest_path():
    """Own memory: every cell entered at step 5 but a far corner (1) and the neighbour
    (2) and the robot's own cell (0, never chosen): the goal is the corner, the first
    move the lowest port of a shortest path."""
    m = parse_map(GRID)
    here, corner = m.state_at(1, 1), m.state_at(3, 5)
    near = m.neighbors[here, 1]
    p, s, strat = setup(m, "cc", [here])
    strat.memory[0, 0, :] = 5
    strat.memory[0, 0, here] = 0
    strat.memory[0, 0, corner] = 1
    strat.memory[0, 0, near] = 2
    s.last[0, 0, :] = 9  # the team's map is not what cc reads
    ask = decide(p, s, strat, 10, 0.0)
    assert strat.goal[0, 0] == corner
    dist = m.distances()
    # from (1, 1) both E and S start shortest paths to (3, 5): E is the lower port
    assert dist[m.neighbors[here, 2], corner] == dist[here, corner] - 1
    assert ask[0] == 1
    # it keeps the goal on the way, whatever its memory says
    strat.memory[0, 0, corner] = 7
    s.occ[0, here], s.pos[0, 0] = -1, near
    s.occ[0, near] = 0
    decide(p, s, strat, 11, 0.0)
    assert strat.goal[0, 0] == corner


def test_cc_breaks_ties_with_the_runs_stream():
    m = parse_map(GRID)
    here = m.state_at(1, 1)
    a, b = sorted([m.state_at(3, 5), m.state_at(1, 5)])
    goals_seen = []
    for u in (0.0, 0.99):
        p, s, strat = setup(m, "cc", [here])
        strat.memory[0, 0, :] = 5
        strat.memory[0, 0, [a, b]] = 1
        decide(p, s, strat, 10, u)
        goals_seen.append(int(strat.goal[0, 0]))
    assert goals_seen == [a, b]


def test_gbs_posterior_of_the_gain():
    """Gains I / L = 6/2, 9/3, 5/1, 4/2: the greatest posterior is vertex 3 (gain 5), not
    the idlest (2); the posterior is patrolling_sim's formula."""
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "gbs", [1])
    idle_at(s, 10, {0: 6, 2: 9, 3: 5, 4: 4})
    assert decide(p, s, strat, 10, 0.0)[0] == 2 and strat.goal[0, 0] == 3
    pp = gbs.posterior(np.array([3.0, 150.0]), 0.1, math.log(10.0) / 100.0, 100.0)
    assert pp[0] == pytest.approx(0.1 * 10**0.03) and pp[1] == 1.0


@pytest.mark.parametrize("u, goal", [(0.0, 0), (0.5, 2), (0.9, 3)])
def test_gbs_posterior_is_one_from_g2_on(u, goal):
    """With G2 = 2.5 the gains 3, 3 and 5 all have posterior 1: a tie of ports 0, 1, 2,
    broken by the stream; vertex 4 (gain 2) is never taken."""
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "gbs", [1], **{"bayes.g2": 2.5})
    idle_at(s, 10, {0: 6, 2: 9, 3: 5, 4: 4})
    decide(p, s, strat, 10, u)
    assert strat.goal[0, 0] == goal


def test_gbs_edge_min_floors_the_distance():
    """edge_min 3: every edge counts 3 moves, and the idlest target (2) wins."""
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "gbs", [1], **{"bayes.edge_min": 3.0})
    idle_at(s, 10, {0: 6, 2: 9, 3: 5, 4: 4})
    decide(p, s, strat, 10, 0.0)
    assert strat.goal[0, 0] == 2


def test_sebs_discounts_a_target_another_robot_intends():
    """As in the gbs test, but robot 1 has announced vertex 3: its posterior 0.1 x
    10^0.05 = 0.112 is multiplied by 2^(2-1) / (2^2 - 1) = 2/3, 0.075, below vertices 0
    and 2 (0.1 x 10^0.03 = 0.107 each, a tie broken by the stream)."""
    assert sebs.state_factors(2).tolist() == [1.0, 2 / 3, 1 / 3]
    m = parse_map(GRAPH)
    for u, goal in ((0.0, 0), (0.6, 2)):
        p, s, strat = setup(m, "sebs", [1, 6])
        idle_at(s, 10, {0: 6, 2: 9, 3: 5, 4: 4})
        strat.goal[0, 1] = 3
        decide(p, s, strat, 10, u)
        assert strat.goal[0, 0] == goal
    # without communication nothing is exchanged: gbs's choice
    p, s, strat = setup(m, "sebs", [1, 6], **{"team.communication": False})
    idle_at(s, 10, {0: 6, 2: 9, 3: 5, 4: 4}, group=0)
    strat.goal[0, 1] = 3
    decide(p, s, strat, 10, 0.0)
    assert strat.goal[0, 0] == 3


def test_a_goal_in_a_held_pocket_is_dropped():
    """The station 4 ends a dead-end edge: while robot 1 holds it, robot 0 at the hub
    does not take vertex 4 even as the idlest and nearest target."""
    m = parse_map(GRAPH)
    cfg = from_flat({"agents": 2, "policy": "hcr", "runs": 1, "battery.capacity": 60})
    p = world.make_params(cfg, m)
    start = np.array([[1, 6]])
    s = world.init_state(p, start)
    strat = strategies.make("hcr", cfg, m, p, start)
    assert p.pocket_of[4] == 0
    idle_at(s, 10, {0: 1, 2: 1, 3: 1, 4: 9})
    decide(p, s, strat, 10, 0.0)
    assert strat.goal[0, 0] == 4
    s.reserved[0, 0] = 1
    decide(p, s, strat, 10, 0.0)
    assert strat.goal[0, 0] in (0, 2, 3)


def test_a_goal_dropped_off_a_target_becomes_the_nearest_target_outside_held_pockets():
    """A robot inside the edge from the hub to vertex 0 (one move from each) whose goal is
    the station 4, held by robot 1: it drops the goal and heads for the nearest target,
    0 (the lower of the two at one move)."""
    m = parse_map(GRAPH)
    cfg = from_flat({"agents": 2, "policy": "gbs", "runs": 1, "battery.capacity": 60})
    p = world.make_params(cfg, m)
    way = int(m.neighbors[1, 0])
    start = np.array([[way, 6]])
    s = world.init_state(p, start)
    strat = strategies.make("gbs", cfg, m, p, start)
    strat.goal[0, 0] = 4
    decide_anywhere(p, s, strat, 10, 0.0)
    assert strat.goal[0, 0] == 4  # free station: kept
    s.reserved[0, 0] = 1
    decide_anywhere(p, s, strat, 11, 0.0)
    assert strat.goal[0, 0] == 0


def test_travel_takes_the_lowest_open_port_on_a_shortest_path_else_insists():
    """From (1, 1) to (3, 5) both E and S start shortest paths: with E taken by another
    robot it goes S. From (1, 3) to (1, 5) only E does: with E taken it insists on E
    (and is blocked) rather than take the open S or W."""
    m = parse_map(GRID)
    here, corner = m.state_at(1, 1), m.state_at(3, 5)
    p, s, strat = setup(m, "cc", [here, int(m.neighbors[here, 1])])
    strat.goal[0, 0] = corner
    assert decide(p, s, strat, 10, 0.0)[0] == 2
    here = m.state_at(1, 3)
    p, s, strat = setup(m, "cc", [here, int(m.neighbors[here, 1])])
    strat.goal[0, 0] = m.state_at(1, 5)
    obs = world.begin_step(s, p)
    assert not obs.open[0, 0, 1] and obs.open[0, 0, 2] and obs.open[0, 0, 3]
    assert decide(p, s, strat, 10, 0.0)[0] == 1


def graph_file(tmp_path: Path) -> Path:
    path = tmp_path / "hub4.txt"
    path.write_text(GRAPH)
    return path


#: (map, agents, battery, communication): grids and the graph, each team size.
ENGINE_CASES = [
    ("graph", 4, True, True),
    ("graph", 2, False, False),
    ("graph", 1, True, True),
    ("map_a", 4, True, True),
    ("map_a", 2, True, False),
    ("map_a", 1, False, True),
]


@pytest.mark.parametrize("policy", FIELD)
@pytest.mark.parametrize("case", ENGINE_CASES, ids=lambda c: "-".join(map(str, c)))
def test_engines_agree(tmp_path, policy, case):
    pytest.importorskip("numba")
    from test_engines import both

    name, k, battery, comm = case
    flat = {
        "runs": 2,
        "seed": 5,
        "steps": 400,
        "record.trajectory": 400,
        "map": str(graph_file(tmp_path)) if name == "graph" else name,
        "agents": k,
        "policy": policy,
        "battery.enabled": battery,
        "battery.capacity": 60 if name == "graph" else 200,
        "battery.charge_steps": 5,
        "team.communication": comm,
    }
    assert both(flat, tmp_path, strategy=True) == ("numba", "")


@pytest.mark.parametrize("policy", ["gbs", "sebs"])
def test_engines_agree_on_the_bayes_keys(tmp_path, policy):
    """A low G2 (most gains capped: posteriors of 1 tie, broken by the stream) and an
    edge_min above the shortest edges."""
    pytest.importorskip("numba")
    from test_engines import both

    flat = {
        "runs": 2,
        "seed": 8,
        "steps": 400,
        "record.trajectory": 400,
        "map": str(graph_file(tmp_path)),
        "agents": 3,
        "policy": policy,
        "battery.capacity": 60,
        "bayes.g2": 5.0,
        "bayes.edge_min": 2.0,
        "bayes.g1": 0.3,
    }
    assert both(flat, tmp_path, strategy=True) == ("numba", "")


@pytest.mark.parametrize("policy", FIELD)
@pytest.mark.parametrize("name", ["map_a", "graph"])
@pytest.mark.parametrize("k", [1, 2, 4])
@pytest.mark.parametrize("battery", [True, False])
def test_safe_and_live(policy, name, k, battery):
    """No shared cell, no swap, no jump at any step; no wait past the bound. (Battery off
    on the numpy engine, whose ``drive`` checks every step itself: the compiled path of
    ``drive`` reads the charges, which a run without battery does not report.)"""
    m = get_map("map_a") if name == "map_a" else parse_map(GRAPH)
    seed = sum(map(ord, name + policy)) + k
    extra = {} if battery else {"battery.enabled": False}
    engine = FAST if battery else "numpy"
    stall, bound, _ = drive(m, policy, k, seed, steps=600, engine=engine, **extra)
    assert stall.max() <= bound, f"{name} K={k} {policy}: max_stall {stall} > {bound}"
