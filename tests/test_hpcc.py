"""``hpcc``: patrolling_sim's Heuristic Pathfinder Conscientious Cognitive agent.

Decisions computed by hand on a small patrol graph (the hub graph of
``test_field_strategies``, edges of 1 to 3 moves) and on a ring of 8 grid cells: the
goal by normalised idleness and nearness over every target, the route by Dijkstra on
idleness-reweighted arc costs (longer than a shortest path when idleness says so), kept
to the goal, ties as documented; the two engines to the bit (grid and graph with
waypoints, 1, 2 and 4 robots, battery, communication and collisions on and off);
checkpoints resumed on either engine; safety and liveness.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from test_field_strategies import GRAPH, decide, decide_anywhere, graph_file, setup
from test_liveness import drive

from qpatrol import strategies, world
from qpatrol.config import from_flat
from qpatrol.maps import get_map, parse_map

FAST = "numba" if importlib.util.find_spec("numba") else "numpy"

#: A ring of 8 cells, numbered 0 (1,1), 1 (1,2), 2 (1,3), 3 (2,1), 4 (2,3), 5 (3,1),
#: 6 (3,2), 7 (3,3): 0-1-2-4-7-6-5-3-0. Every move is 1 long, so every arc's
#: normalised length is 0 and a route's cost is the sum of its targets' staleness.
RING = """; name: ring
#####
#...#
#.#.#
#...#
#####
"""
NORTH, EAST, SOUTH, WEST = range(4)


def route_of(strat, k: int, start: int, goal: int) -> list[int]:
    """The cells of robot k's route from ``start`` to ``goal`` (run 0)."""
    cells = [start]
    while cells[-1] != goal:
        port = int(strat.route[0, k, cells[-1]])
        assert port >= 0, (cells, strat.route[0, k])
        cells.append(int(strat.tnbr[cells[-1], port]))
        assert len(cells) <= strat.route.shape[2]
    return cells


def move(s, k: int, cell: int) -> None:
    """Put robot k of run 0 on ``cell``."""
    s.occ[0, s.pos[0, k]] = -1
    s.pos[0, k] = cell
    s.occ[0, cell] = k


def idle_at(strat, t: int, idle: dict[int, int], robot: int | None = None) -> None:
    """Set the own record of ``robot`` (every robot of run 0 if None) so that cell c has
    idleness ``idle[c]`` at step t (hpcc reads each robot's own visits)."""
    robots = range(strat.n_agents) if robot is None else [robot]
    for k in robots:
        for c, i in idle.items():
            strat.memory[0, k, c] = t - i


# --------------------------------------------------------------- a patrol graph, by hand

#: Idleness at step 20 of the hub graph's vertices (the robot stands on 0). Waypoints
#: are never visited (idleness 20): not targets, they count in no maximum.
HUB_IDLE = {0: 2, 1: 1, 2: 6, 3: 12, 4: 4, 5: 8, 6: 10}


def test_goal_and_route_by_hand_on_a_graph():
    """From vertex 0: moves 2, 5, 3, 4, 2, 6 to vertices 1..6 (L_max 6), idleness 1, 6,
    12, 4, 8, 10 (I_max 12). U = (6 - L)/6 + I/12: 0.75, 0.67, 1.5, 0.67, 1.33, 0.83:
    the goal is 3 (not the nearest, 1 and 5, nor the idlest but one, 6).

    Arcs are 1 to 3 moves long (normalised (len - 1)/2): 0-1 and 0-5 and 5-3 0.5, 1-3
    0. Staleness (12 - I)/12: 1 11/12, 5 4/12, 3 0. Via 1: 11/12 + 0.5 + 0 + 0 = 1.42;
    via 5: 4/12 + 0.5 + 0 + 0.5 = 1.33. The route is 0-5-3 (4 moves), not the shortest
    path 0-1-3 (3 moves): vertex 0 leaves by port 1 (to 5), not port 0 (to 1)."""
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "hpcc", [0])
    idle_at(strat, 20, HUB_IDLE)
    dist = m.distances()
    assert [int(dist[0, v]) for v in range(1, 7)] == [2, 5, 3, 4, 2, 6]
    assert dist[m.neighbors[0, 0], 3] == dist[0, 3] - 1  # port 0 starts the shortest path
    ask = decide(p, s, strat, 20, 0.0)
    assert strat.goal[0, 0] == 3
    assert route_of(strat, 0, 0, 3) == [0, 5, 3]
    assert ask[0] == 1 and strat.hop[0, 0] == 5
    assert strat.route[0, 0, 1] == -1 and strat.route[0, 0, 3] == -1  # off the route, goal
    u = strat.utility(world.begin_step(s, p), 0, np.array([0]), np.array([0]))[0]
    want = {1: 4 / 6 + 1 / 12, 2: 1 / 6 + 6 / 12, 3: 3 / 6 + 1, 5: 4 / 6 + 8 / 12, 6: 10 / 12}
    for v, x in want.items():
        assert u[v] == pytest.approx(x)


def test_the_route_is_kept_to_the_goal():
    """On vertex 5, the route's middle, the robot goes on to its goal 3 though a new
    plan would now take the very idle 6; on 3 it plans again, and takes 6."""
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "hpcc", [0])
    idle_at(strat, 20, HUB_IDLE)
    decide(p, s, strat, 20, 0.0)
    move(s, 0, 5)
    idle_at(strat, 24, {**HUB_IDLE, 6: 40, 0: 4, 5: 1})
    assert decide(p, s, strat, 24, 0.0)[0] == 1  # 5's port 1 leads to 3
    assert strat.goal[0, 0] == 3 and strat.hop[0, 0] == 3
    move(s, 0, 3)
    idle_at(strat, 26, {**HUB_IDLE, 6: 40, 0: 4, 5: 1, 3: 1})
    decide(p, s, strat, 26, 0.0)
    assert strat.goal[0, 0] == 6


def test_off_its_route_a_robot_heads_for_its_hop():
    """Pushed from 0 (making for 5) onto vertex 1, off its route, it takes a shortest
    path to 5 (1-3-5, 3 moves, not 1-0-5, 4) and keeps its goal; put back on 0, it
    follows its route again."""
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "hpcc", [0])
    idle_at(strat, 20, HUB_IDLE)
    decide(p, s, strat, 20, 0.0)
    move(s, 0, 1)
    assert decide(p, s, strat, 21, 0.0)[0] == 2  # port 2 of the hub leads to 3
    assert strat.goal[0, 0] == 3 and strat.hop[0, 0] == 5
    move(s, 0, 0)
    assert decide(p, s, strat, 22, 0.0)[0] == 1 and strat.hop[0, 0] == 5


def test_distances_are_shortest_paths_in_moves_and_maxima_over_every_target():
    """A neighbour at the end of a long edge counts its shortest path (vertex 2 of
    ``SHORTCUT``: edge 0-2 of 5 moves, path 0-1-2 of 2): patrolling_sim counts the
    edge. I_max is over every target, the robot's own cell included."""
    m = parse_map(SHORTCUT)
    p, s, strat = setup(m, "hpcc", [0])
    assert m.distances()[0, 2] == 2
    idle_at(strat, 10, {0: 9, 1: 3, 2: 3, 3: 3})  # (the edge's waypoints: never visited, 10)
    s.t = 9
    obs = world.begin_step(s, p)
    u = strat.utility(obs, 0, np.array([0]), np.array([0]))[0]
    # L: 1, 2, 3 (L_max 3); I: 3, 3, 3 (I_max 9, the robot's own cell)
    assert u[1:4] == pytest.approx([2 / 3 + 1 / 3, 1 / 3 + 1 / 3, 0 + 1 / 3])


def test_asked_off_a_target_it_heads_for_its_goal_without_a_route():
    """The world asks no strategy on a waypoint; asked all the same (inside the edge
    from the hub to 0, one move from each), the robot scores the targets from there
    (L_max 5: U(3) = 3/5 + 1 = 1.6 the greatest), plans no route and heads for its goal
    by a shortest path (through the hub: port 0 of a waypoint leads to the edge's first
    vertex)."""
    m = parse_map(GRAPH)
    way = int(m.neighbors[1, 0])
    p, s, strat = setup(m, "hpcc", [way])
    idle_at(strat, 20, HUB_IDLE)
    ask = decide_anywhere(p, s, strat, 20, 0.0)
    assert strat.goal[0, 0] == 3 and strat.hop[0, 0] == 3
    assert (strat.route[0, 0] == -1).all() and ask[0] == 0


#: Vertex 0 reaches 2 by an edge of 5 moves and through 1 in 2; 3 hangs off 2.
SHORTCUT = """; name: shortcut
; kind: graph
v 0 0 0
v 1 1 1
v 2 2 0
v 3 3 0
e 0 1 1
e 1 2 1
e 0 2 5
e 2 3 1
"""


def test_a_goal_in_a_held_pocket_is_never_taken():
    """The station 4 ends a dead-end edge: while robot 1 holds it, robot 0 on the hub
    does not take it even as the idlest target; a goal there is dropped."""
    m = parse_map(GRAPH)
    cfg = from_flat({"agents": 2, "policy": "hpcc", "runs": 1, "battery.capacity": 60})
    p = world.make_params(cfg, m)
    start = np.array([[1, 6]])
    s = world.init_state(p, start)
    strat = strategies.make("hpcc", cfg, m, p, start)
    assert p.pocket_of[4] == 0
    idle_at(strat, 10, {0: 1, 2: 1, 3: 1, 4: 9, 5: 1, 6: 1, 1: 1})
    decide(p, s, strat, 10, 0.0)
    assert strat.goal[0, 0] == 4 and route_of(strat, 0, 1, 4) == [1, 4]
    s.reserved[0, 0] = 1
    decide(p, s, strat, 10, 0.0)
    assert strat.goal[0, 0] == 3 and route_of(strat, 0, 1, 3) == [1, 3]


# ------------------------------------------------------------------ a grid ring, by hand


def test_the_route_goes_the_long_way_round_idle_cells():
    """From 0: moves 1, 2, 1, 3, 2, 3, 4 to cells 1..7 (L_max 4); idleness 1, 20, 14,
    20, 18, 20, 20 (I_max 20). U = (4 - L)/4 + I/20: 0.8, 1.5, 1.45, 1.25, 1.4, 1.25,
    1.0: the goal is 2. Staleness (20 - I)/20: 1 0.95, 3 0.3, 5 0.1, the others 0. The
    short way 0-1-2 costs 0.95, the long way 0-3-5-6-7-4-2 0.4: the route takes it,
    south first (a shortest path goes east)."""
    m = parse_map(RING)
    p, s, strat = setup(m, "hpcc", [0])
    idle_at(strat, 30, {0: 1, 1: 1, 2: 20, 3: 14, 4: 20, 5: 18, 6: 20, 7: 20})
    ask = decide(p, s, strat, 30, 0.0)
    assert strat.goal[0, 0] == 2
    assert route_of(strat, 0, 0, 2) == [0, 3, 5, 6, 7, 4, 2]
    assert ask[0] == SOUTH


def test_goal_ties_go_to_the_stream_and_route_ties_to_the_first_path_found():
    """Cells 4 and 6 tie as goals (3 moves, I_max): u = 0 takes 4, u = 0.99 takes 6.
    With 7 the goal and both ways round equally stale, the route is patrolling_sim's
    Dijkstra's first: 7 is reached from 4 (settled before 6, the lower cell), so the
    route goes east, whatever u."""
    m = parse_map(RING)
    for u, goal in ((0.0, 4), (0.99, 6)):
        p, s, strat = setup(m, "hpcc", [0])
        idle_at(strat, 30, {0: 1, 1: 2, 2: 2, 3: 2, 4: 20, 5: 2, 6: 20, 7: 2})
        decide(p, s, strat, 30, u)
        assert strat.goal[0, 0] == goal
    for u in (0.0, 0.99):
        p, s, strat = setup(m, "hpcc", [0])
        idle_at(strat, 30, {0: 1, 1: 4, 2: 4, 3: 4, 4: 4, 5: 4, 6: 4, 7: 20})
        ask = decide(p, s, strat, 30, u)
        assert strat.goal[0, 0] == 7
        assert route_of(strat, 0, 0, 7) == [0, 1, 2, 4, 7] and ask[0] == EAST


def test_a_blocked_robot_insists_on_its_route():
    """Robot 0 on 0 routes 0-1-2 with robot 1 standing on 1: it asks east (blocked)
    rather than the open south."""
    m = parse_map(RING)
    p, s, strat = setup(m, "hpcc", [0, 1])
    idle_at(strat, 30, {0: 1, 1: 1, 2: 20, 3: 2, 4: 2, 5: 2, 6: 2, 7: 2})
    obs = world.begin_step(s, p)
    assert not obs.open[0, 0, EAST] and obs.open[0, 0, SOUTH]
    ask = decide(p, s, strat, 30, 0.0)
    assert strat.goal[0, 0] == 2 and route_of(strat, 0, 0, 2) == [0, 1, 2]
    assert ask[0] == EAST


@pytest.mark.parametrize("communication", [True, False])
def test_each_robot_reads_its_own_record(communication):
    """As patrolling_sim's cognitive agents (their messages carry nothing), each robot
    reads its own record of its visits, communication on or off: robot 1 on 7 takes
    cell 1, idlest in its record, though the team's map says cell 0 and robot 0's
    record says cell 2."""
    m = parse_map(RING)
    p, s, strat = setup(m, "hpcc", [3, 7], **{"team.communication": communication})
    rest = dict.fromkeys(range(8), 2)
    for c, i in {**rest, 0: 25}.items():
        s.last[0, 0, c] = 30 - i
    idle_at(strat, 30, {**rest, 2: 25}, robot=0)
    idle_at(strat, 30, {**rest, 1: 25}, robot=1)
    decide(p, s, strat, 30, 0.0)
    assert strat.goal[0, 1] == 1


def test_a_robot_remembers_the_cells_it_enters():
    """``learn``: each robot that moved records the step in its own memory, and nothing
    else changes."""
    m = parse_map(RING)
    p, s, strat = setup(m, "hpcc", [0, 7])
    obs = world.begin_step(s, p)
    out = world.step(s, p, obs, np.array([[1, 3]]))
    strat.learn(out)
    assert strat.memory[0, 0].tolist() == [0, out.t, 0, 0, 0, 0, 0, 0]
    assert strat.memory[0, 1].tolist() == [0, 0, 0, 0, 0, 0, out.t, 0]


@pytest.mark.parametrize(
    "weights, u, goal, route",
    [
        ({}, 0.0, 2, [0, 3, 5, 6, 7, 4, 2]),
        ({"hpcc.distance_weight": 0.0}, 0.99, 7, [0, 3, 5, 6, 7]),
        ({"hpcc.idleness_weight": 0.0}, 0.0, 1, [0, 1]),
        ({"hpcc.distance_weight": 3.0}, 0.0, 3, [0, 3]),
    ],
)
def test_the_weights(weights, u, goal, route):
    """The ring of the long-way test (near = (4 - L)/4 and I/20 of cells 1..7: 0.75 and
    0.05, 0.5 and 1, 0.75 and 0.7, 0.25 and 1, 0.5 and 0.9, 0.25 and 1, 0 and 1).
    Idleness alone: 2, 4, 6 and 7 tie (u = 0.99: 7), reached round 3, 5, 6 (staleness
    0.3, 0.1, 0) rather than 1 (0.95). Nearness alone: 1 and 3 tie (u = 0: 1), and
    every arc costs 0: the first path found. Nearness weighing 3: 3 x 0.75 + 0.7 = 2.95
    for 3, above 2.5 for 2."""
    m = parse_map(RING)
    p, s, strat = setup(m, "hpcc", [0], **weights)
    idle_at(strat, 30, {0: 1, 1: 1, 2: 20, 3: 14, 4: 20, 5: 18, 6: 20, 7: 20})
    decide(p, s, strat, 30, u)
    assert strat.goal[0, 0] == goal and route_of(strat, 0, 0, goal) == route


# ------------------------------------------------------------------ engines, checkpoints

#: (map, agents, battery, communication, collisions avoided)
ENGINE_CASES = [
    ("graph", 4, True, True, True),
    ("graph", 2, False, False, True),
    ("graph", 1, True, True, True),
    ("graph", 4, True, False, False),
    ("map_a", 4, True, True, True),
    ("map_a", 2, True, False, True),
    ("map_a", 1, False, True, True),
    ("map_a", 4, False, True, False),
    ("rooms", 4, True, False, True),
    ("rooms", 2, False, True, True),
]


@pytest.mark.parametrize("case", ENGINE_CASES, ids=lambda c: "-".join(map(str, c)))
def test_engines_agree(tmp_path, rooms_map, case):
    """Files and the strategy's arrays (goals, hops, routes) to the bit."""
    pytest.importorskip("numba")
    from test_engines import both

    name, k, battery, comm, avoid = case
    where = {"graph": str(graph_file(tmp_path)), "rooms": str(rooms_map)}
    flat = {
        "runs": 2,
        "seed": 5,
        "steps": 400,
        "record.trajectory": 400,
        "map": where.get(name, name),
        "agents": k,
        "policy": "hpcc",
        "battery.enabled": battery,
        "battery.capacity": {"graph": 60, "rooms": 40}.get(name, 200),
        "battery.charge_steps": 5,
        "team.communication": comm,
        "team.avoid_collisions": avoid,
    }
    assert both(flat, tmp_path, strategy=True) == ("numba", "")


def test_engines_agree_on_the_weights(tmp_path):
    """Weights other than 1: the distance term outweighs idleness (ties of utility and
    of route costs more often)."""
    pytest.importorskip("numba")
    from test_engines import both

    flat = {
        "runs": 2, "seed": 9, "steps": 300, "record.trajectory": 300,
        "map": str(graph_file(tmp_path)), "agents": 3, "policy": "hpcc",
        "battery.capacity": 60, "hpcc.idleness_weight": 0.25, "hpcc.distance_weight": 2.0,
    }  # fmt: skip
    assert both(flat, tmp_path, strategy=True) == ("numba", "")


def test_a_checkpoint_resumes_on_either_engine(tmp_path):
    """Stopped at step 37 of a graph with waypoints (robots mid-route, inside edges) and
    resumed: the files of the uninterrupted run, saved on either engine and resumed on
    the other."""
    from test_checkpoint import folder, stop_at

    from qpatrol import engines
    from qpatrol.config import from_mapping
    from qpatrol.run import checkpoint as ck
    from qpatrol.run import simulate

    flat = {
        "map": str(graph_file(tmp_path)), "policy": "hpcc", "agents": 3, "runs": 2,
        "seed": 3, "steps": 90, "battery": {"capacity": 60, "charge_steps": 3},
        "record": {"trajectory": 9},
    }  # fmt: skip
    cfg = {e: from_mapping({**flat, "engine": e}) for e in ("numpy", "numba")}
    whole = folder(simulate(cfg["numpy"]), tmp_path / "whole")
    pairs = [("numpy", "numpy")]
    if engines.numba_installed():
        pairs = [("numpy", "numba"), ("numba", "numpy")]
    for first, then in pairs:
        cp = tmp_path / f"cp-{first}-{then}"
        stop_at(cfg[first], cp, 37)
        resumed = ck.Checkpointer(cp, every=0)
        rest = simulate(cfg[then], checkpoint=resumed)
        assert rest.engine == then
        assert folder(rest, tmp_path / f"rest-{first}-{then}") == whole, (first, then)


@pytest.mark.parametrize("name", ["map_a", "graph"])
@pytest.mark.parametrize("k", [1, 2, 4])
@pytest.mark.parametrize("battery", [True, False])
def test_safe_and_live(name, k, battery):
    """No shared cell, no swap, no jump at any step; no wait past the bound (battery off
    on the numpy engine, which checks every step: see test_field_strategies)."""
    m = get_map("map_a") if name == "map_a" else parse_map(GRAPH)
    seed = sum(map(ord, name + "hpcc")) + k
    extra = {} if battery else {"battery.enabled": False}
    engine = FAST if battery else "numpy"
    stall, bound, _ = drive(m, "hpcc", k, seed, steps=600, engine=engine, **extra)
    assert stall.max() <= bound, f"{name} K={k} hpcc: max_stall {stall} > {bound}"
