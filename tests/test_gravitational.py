"""``gravitational`` (Sampaio, Ramalho and Tedesco 2010; SimPatrol's gravitational clients).

Decisions computed by hand, masses, forces and the port chosen, for every propagation,
combination and growth, on the hub graph of tests/test_field_strategies.py (hub 1 with
edges of 2, 3, 1 and 2 moves to vertices 0, 2, 3 and 4, waypoints inside) and on a
small grid; the goals' zero mass; open ports first; the two engines to the bit (grids and
graphs with waypoints, 1/2/4 robots, battery, communication and collision avoidance on
and off, every variant); a checkpoint resumed on the other engine; safety and liveness.

Distances between the hub graph's vertices, in moves (row: from)::

        0  1  2  3  4  5  6
    0   0  2  5  3  4  2  6
    1   2  0  3  1  2  3  4
    2   5  3  0  4  5  6  2
    3   3  1  4  0  3  2  3
    4   4  2  5  3  0  5  6

From the hub, the shortest paths start by port 0 to 0; port 1 to 2; port 2 to 3, 5 and 6
(5 and 6 lie past 3); port 3 to 4.
"""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
from test_field_strategies import GRAPH, graph_file, idle_at, setup
from test_liveness import drive

from qpatrol import world
from qpatrol.config import ConfigError, from_flat
from qpatrol.maps import get_map, parse_map
from qpatrol.strategies import gravitational
from qpatrol.world import battery

FAST = "numba" if importlib.util.find_spec("numba") else "numpy"

#: Idleness at step 10 of the hub graph's vertices (the hub 1 just visited).
IDLE = {0: 8, 1: 1, 2: 9, 3: 2, 4: 4, 5: 10, 6: 12}

#: A one-wide U of five cells: (2,1) (1,1) (1,2) (1,3) (2,3), a path.
U_GRID = """; name: u
#####
#...#
#.#.#
#####
"""

#: Two loops around two pillars, a station in the middle of the bottom row.
LOOP_GRID = """; name: loop
#######
#.....#
#.#.#.#
#..H..#
#######
"""


def keys(propagation: str = "edge", combination: str = "sum", growth: str = "arithmetic", **more):
    return {
        "gravity.propagation": propagation,
        "gravity.combination": combination,
        "gravity.growth": growth,
        **more,
    }


def forces_at(p, s, strat, t: int, k: int = 0) -> np.ndarray:
    """Robot k's masses and forces of step ``t`` (run 0): ``(mass [T], force [D])``."""
    s.t = t - 1
    obs = world.begin_step(s, p)
    rows = np.array([0])
    mass = strat.masses(obs, k, rows)
    return mass[0], strat.forces(s.pos[rows, k], mass)[0]


def ask_at(p, s, strat, t: int, u: float = 0.0) -> np.ndarray:
    """Every robot's ask at step ``t`` (run 0), every tie-break uniform ``u``."""
    s.t = t - 1
    obs = world.begin_step(s, p)
    return strat.act(obs, np.full((1, p.n_agents, 2), u))[0]


def hub(k: int = 1, starts=(1,), **flat):
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "gravitational", list(starts)[:k], **flat)
    for g in range(p.n_groups):
        idle_at(s, 10, IDLE, group=g)
    return p, s, strat


# ----------------------------------------------------------------------------- masses


def test_masses_grow_with_idleness():
    idle = np.array([[0, 1, 2, 10]])
    assert gravitational.growth_of(idle, gravitational.ARITHMETIC, 1.05).tolist() == [
        [0.0, 1.0, 2.0, 10.0]
    ]
    geo = gravitational.growth_of(idle, gravitational.GEOMETRIC, 1.05)[0]
    assert geo[0] == 0.0 and geo[1] == 1.0 and geo[2] == 1.05
    assert geo[3] == math.pow(1.05, 9)
    assert gravitational.growth_of(idle, gravitational.NO_GROWTH, 1.05).tolist() == [[1.0] * 4]
    # past the largest float the geometric mass is infinite, not an error
    assert gravitational.growth_of(np.array([30000]), gravitational.GEOMETRIC, 1.05)[0] == math.inf


def test_inverse_powers_of_the_moves():
    inv = gravitational.inverse_powers(4, 2.0)
    assert inv.tolist() == [1.0, 1.0, 0.25, 1 / 9, 1 / 16]
    assert gravitational.inverse_powers(3, 0.0).tolist() == [1.0] * 4


def test_keys_are_checked():
    with pytest.raises(ConfigError, match="gravity.propagation"):
        from_flat({"policy": "gravitational", "gravity.propagation": "faces"})
    with pytest.raises(ConfigError, match="gravity.exponent"):
        from_flat({"policy": "gravitational", "gravity.exponent": -1.0})
    cfg = from_flat({"policy": "gravitational"})
    assert (cfg["gravity.propagation"], cfg["gravity.growth"], cfg["gravity.combination"]) == (
        "edge",
        "arithmetic",
        "sum",
    )
    assert (cfg["gravity.exponent"], cfg["gravity.growth_rate"]) == (2.0, 0.05)


# ------------------------------------------------------------ decisions on the hub graph


def test_edge_sum_pulls_through_the_nearest_vertex():
    """Arithmetic masses 8, 9, 2, 4 at vertices 0, 2, 3, 4 and 10, 12 at 5, 6 past 3:
    port 0: 8/2^2 = 2; port 1: 9/3^2 = 1; port 2: 2/1 + 10/3^2 + 12/4^2 = 3.861; port 3:
    4/2^2 = 1. Port 2 wins though vertex 3 is the least idle of the four: the hub's own
    mass acts on no port."""
    p, s, strat = hub()
    mass, force = forces_at(p, s, strat, 10)
    assert mass.tolist() == [8.0, 1.0, 9.0, 2.0, 4.0, 10.0, 12.0]
    assert force == pytest.approx([2.0, 1.0, 2 + 10 / 9 + 12 / 16, 1.0], rel=1e-15)
    assert ask_at(p, s, strat, 10)[0] == 2 and strat.goal[0, 0] == 3


def test_exponent_one():
    """Pulls fall as 1/L: 8/2, 9/3, 2/1 + 10/3 + 12/4, 4/2."""
    p, s, strat = hub(**{"gravity.exponent": 1.0})
    _, force = forces_at(p, s, strat, 10)
    assert force == pytest.approx([4.0, 3.0, 2 + 10 / 3 + 3.0, 2.0], rel=1e-15)


@pytest.mark.parametrize("u, port, goal", [(0.0, 0, 0), (0.49, 0, 0), (0.5, 2, 3), (0.99, 2, 3)])
def test_edge_max_keeps_the_strongest_pull_and_ties_go_to_the_stream(u, port, goal):
    """Max: port 0 max(8/4) = 2, port 2 max(2/1, 10/9, 12/16) = 2: an exact tie of ports 0
    and 2, the floor(2u)-th of them taken."""
    p, s, strat = hub(**keys("edge", "max"))
    _, force = forces_at(p, s, strat, 10)
    assert force.tolist() == [2.0, 1.0, 2.0, 1.0]
    assert ask_at(p, s, strat, 10, u)[0] == port and strat.goal[0, 0] == goal


NODE = {
    # combined masses C(y) = sum over z of mass(z) / L(y, z)^2, y's own mass whole
    "sum": [
        8 + 1 / 4 + 9 / 25 + 2 / 9 + 4 / 16 + 10 / 4 + 12 / 36,
        8 / 25 + 1 / 9 + 9 + 2 / 16 + 4 / 25 + 10 / 36 + 12 / 4,
        8 / 9 + 1 / 1 + 9 / 16 + 2 + 4 / 9 + 10 / 4 + 12 / 9,
        8 / 16 + 1 / 4 + 9 / 25 + 2 / 9 + 4 + 10 / 25 + 12 / 36,
    ],
    "max": [8.0, 9.0, 10 / 4, 4.0],
}


@pytest.mark.parametrize(
    "propagation, combination, port",
    [
        ("node", "sum", 2),
        ("node", "max", 0),
        ("node_no_distance", "sum", 1),
        ("node_no_distance", "max", 1),
    ],
)
def test_node_propagation_by_hand(propagation, combination, port):
    """Node: each far vertex's combined mass (11.92, 12.99, 8.73, 6.07 summed; 8, 9, 2.5, 4
    at most) over the port's length 2, 3, 1, 2: 5.96, 4.33, 8.73, 3.03 (port 2) and 4, 3,
    2.5, 2 (port 0); not divided (node_no_distance): vertex 2 both ways (port 1)."""
    p, s, strat = hub(**keys(propagation, combination))
    _, force = forces_at(p, s, strat, 10)
    combined = np.array(NODE[combination])
    want = combined / np.array([2, 3, 1, 2]) if propagation == "node" else combined
    assert force == pytest.approx(want, rel=1e-14)
    assert ask_at(p, s, strat, 10)[0] == port


def test_mixed_propagation_by_hand():
    """Mixed: every vertex but the hub pulls every port over the port's length plus its
    distance from the far vertex; port 2 (length 1 to vertex 3): 8/4^2 + 9/5^2 + 2/1^2 +
    4/4^2 + 10/3^2 + 12/4^2 = 4.971, the greatest. With max: 2 at ports 0 (8/2^2) and 2
    (2/1^2), a tie."""
    p, s, strat = hub(**keys("mixed", "sum"))
    _, force = forces_at(p, s, strat, 10)
    want = [
        8 / 4 + 9 / 49 + 2 / 25 + 4 / 36 + 10 / 16 + 12 / 64,
        8 / 64 + 9 / 9 + 2 / 49 + 4 / 64 + 10 / 81 + 12 / 25,
        8 / 16 + 9 / 25 + 2 / 1 + 4 / 16 + 10 / 9 + 12 / 16,
        8 / 36 + 9 / 49 + 2 / 25 + 4 / 4 + 10 / 49 + 12 / 64,
    ]
    assert force == pytest.approx(want, rel=1e-14)
    assert ask_at(p, s, strat, 10)[0] == 2
    p, s, strat = hub(**keys("mixed", "max"))
    _, force = forces_at(p, s, strat, 10)
    assert force.tolist() == [2.0, 1.0, 2.0, 1.0]
    assert ask_at(p, s, strat, 10, 0.0)[0] == 0 and ask_at(p, s, strat, 10, 0.7)[0] == 2


@pytest.mark.parametrize(
    "growth, port, want",
    [
        ("arithmetic", 0, [9 / 4, 12 / 9, 1 + 3 / 9 + 3 / 16, 6 / 4]),
        ("geometric", 1, [2**8 / 4, 2**11 / 9, 1 + 2**2 / 9 + 2**2 / 16, 2**5 / 4]),
        ("none", 2, [1 / 4, 1 / 9, 1 + 1 / 9 + 1 / 16, 1 / 4]),
    ],
)
def test_growths_by_hand(growth, port, want):
    """Idleness 9, 12, 1, 6, 3, 3 at vertices 0, 2, 3, 4, 5, 6, edge propagation, sum:
    arithmetic (mass I) takes vertex 0 (9/4); geometric with rate 1 (mass 2^(I - 1)) the
    far and idlest vertex 2 (2^11/9); without growth (mass 1) the nearest, 3 (1/1 plus
    5 and 6 behind it)."""
    p, s, strat = hub(**keys(growth=growth, **{"gravity.growth_rate": 1.0}))
    idle_at(s, 10, {0: 9, 2: 12, 3: 1, 4: 6, 5: 3, 6: 3})
    _, force = forces_at(p, s, strat, 10)
    assert force == pytest.approx(want, rel=1e-15)
    assert ask_at(p, s, strat, 10)[0] == port


# --------------------------------------------------------------------------- the goals


def test_goals_weigh_nothing_with_communication():
    """Robot 1 (on vertex 6) is heading for vertex 3: vertex 3 weighs nothing, port 2 falls
    to 10/9 + 12/16 = 1.861 and robot 0 takes port 0 (2). Without communication it does
    not know, and takes port 2. Robot 0's own goal (the hub it reached) weighs nothing
    either, which the node propagation sees (the hub's mass in vertex 0's combined mass)."""
    p, s, strat = hub(2, (1, 6))
    strat.goal[0, 1] = 3
    mass, force = forces_at(p, s, strat, 10)
    assert mass[3] == 0.0 and force == pytest.approx([2.0, 1.0, 10 / 9 + 12 / 16, 1.0])
    assert ask_at(p, s, strat, 10)[0] == 0 and strat.goal[0, 0] == 0
    p, s, strat = hub(2, (1, 6), **{"team.communication": False})
    strat.goal[0, 1] = 3
    assert forces_at(p, s, strat, 10)[0][3] == 2.0
    assert ask_at(p, s, strat, 10)[0] == 2
    # its own goal: the hub, reached; node propagation, vertex 0's combined mass loses
    # the hub's mass 1 over 2^2
    p, s, strat = hub(**keys("node_no_distance"))
    before = forces_at(p, s, strat, 10)[1][0]
    strat.goal[0, 0] = 1
    mass, force = forces_at(p, s, strat, 10)
    assert mass[1] == 0.0 and force[0] == pytest.approx(before - 1 / 4)


def test_robots_choose_in_order_and_see_the_goals_chosen_before():
    """Idleness 2, 1, 9, 8, 5, 1, 12 at vertices 0..6. Robot 0 on vertex 5 (edges of 2
    moves to 0 and 3): 2/2^2 = 0.5 to 0 against 8/2^2 + 1/3^2 + 9/6^2 + 5/5^2 + 12/5^2 =
    3.0 through 3: its goal is 3. Robot 1 on the hub, deciding after it, finds vertex 3
    weightless: ports 2/2^2 = 0.5, 9/3^2 = 1, 0 + 1/9 + 12/16 = 0.86, 5/2^2 = 1.25, and
    takes port 3 (vertex 4), where alone it takes port 2 (8 + 1/9 + 12/16 = 8.86)."""
    m = parse_map(GRAPH)
    idle = {0: 2, 1: 1, 2: 9, 3: 8, 4: 5, 5: 1, 6: 12}
    p, s, strat = setup(m, "gravitational", [5, 1])
    idle_at(s, 10, idle)
    ask = ask_at(p, s, strat, 10)
    assert strat.goal[0].tolist() == [3, 4] and ask[1] == 3
    p, s, strat = setup(m, "gravitational", [1])
    idle_at(s, 10, idle)
    assert ask_at(p, s, strat, 10)[0] == 2 and strat.goal[0, 0] == 3


def test_a_robot_that_leaves_patrolling_announces_no_goal():
    p, s, strat = hub(2, (1, 6))
    strat.goal[0] = [3, 2]
    s.mode[0, 1] = battery.HOMING
    ask_at(p, s, strat, 10)
    assert strat.goal[0, 1] == -1
    strat.goal[0, 1] = 2
    s.mode[0, 1] = battery.GONE
    ask_at(p, s, strat, 10)
    assert strat.goal[0, 1] == -1


def test_it_decides_at_vertices_only_and_keeps_its_goal_on_the_way():
    """Inside the hub's edge to vertex 2 the world moves the robot on: no decision, the
    goal kept (it weighs nothing for the others on the way)."""
    p, s, strat = hub()
    m = parse_map(GRAPH)
    way = int(m.neighbors[1, 1])
    s.occ[0, 1], s.pos[0, 0], s.occ[0, way] = -1, way, 0
    s.head[0, 0] = int(m.entry[1, 1])
    strat.goal[0, 0] = 2
    assert ask_at(p, s, strat, 10)[0] < 0 and strat.goal[0, 0] == 2


# --------------------------------------------------------------------------- on a grid


#: Robot on the middle of the U (ports W and E): idleness 3 and 10 on its west (1 and 2
#: moves), 4 and 2 on its east, 1 on its own cell.
U_CASES = [
    # propagation, combination, (force W, force E), port
    ("edge", "sum", (3 + 10 / 4, 4 + 2 / 4), 3),
    ("edge", "max", (3.0, 4.0), 1),
    ("node", "sum", (3 + 10 + 1 + 4 / 4 + 2 / 9, 4 + 2 + 1 + 3 / 4 + 10 / 9), 3),
    ("node_no_distance", "max", (10.0, 4.0), 3),
    ("mixed", "sum", (3 + 10 / 4 + 4 / 9 + 2 / 16, 4 + 2 / 4 + 3 / 9 + 10 / 16), 3),
    ("mixed", "max", (3.0, 4.0), 1),
]


@pytest.mark.parametrize("propagation, combination, forces, port", U_CASES)
def test_on_a_grid_by_hand(propagation, combination, forces, port):
    """Every move is 1 long (node = node_no_distance). Edge: W gathers (1,1) and (2,1), E
    (1,3) and (2,3); node: the combined mass of the neighbour, the robot's own cell
    included; mixed: every cell but the robot's on both ports."""
    m = parse_map(U_GRID)
    here, w, ww, e, ee = (m.state_at(*rc) for rc in [(1, 2), (1, 1), (2, 1), (1, 3), (2, 3)])
    p, s, strat = setup(m, "gravitational", [here], **keys(propagation, combination))
    idle_at(s, 20, {here: 1, w: 3, ww: 10, e: 4, ee: 2})
    _, force = forces_at(p, s, strat, 20)
    assert force[[3, 1]] == pytest.approx(forces, rel=1e-14)
    assert force[[0, 2]].tolist() == [0.0, 0.0]  # walls
    assert ask_at(p, s, strat, 20)[0] == port


def test_edge_force_takes_the_lowest_port_of_tied_shortest_paths():
    """From the corner (1,1) of the loop grid, E (port 1) and S (port 2) both start
    shortest paths to (3,3), (3,4) and (3,5): their pulls act on E. Idleness 300 at (3,5)
    (6 moves) and 30 at (3,1) (2 moves), 1 elsewhere: E = 300/36 + the row and column of
    ones = 10.00 beats S = 1 + 30/4 + 1/9 = 8.61; on S, (3,5) would have made S win."""
    m = parse_map(LOOP_GRID)
    corner = m.state_at(1, 1)
    p, s, strat = setup(m, "gravitational", [corner])
    s.last[0, 0, :] = 19  # idleness 1 everywhere at step 20
    idle_at(s, 20, {m.state_at(3, 5): 300, m.state_at(3, 1): 30})
    _, force = forces_at(p, s, strat, 20)
    east = 1 + 1 / 4 + 1 / 9 + 1 / 16 + 1 / 9 + 1 / 25 + 1 / 16 + 1 / 25 + 300 / 36
    south = 1 + 30 / 4 + 1 / 9
    assert force[[1, 2]] == pytest.approx([east, south], rel=1e-14)
    assert ask_at(p, s, strat, 20)[0] == 1


def test_only_open_ports_unless_none_is():
    """On the U, W pulls harder (edge, sum: 5.5 against 4.5). Another robot on the west
    cell closes W, and the robot goes E; with no move open it asks for the strongest
    legal port, W, so that the world can make room (the reactive strategies' rule)."""
    from dataclasses import replace

    m = parse_map(U_GRID)
    here, w, ww, e, ee = (m.state_at(*rc) for rc in [(1, 2), (1, 1), (2, 1), (1, 3), (2, 3)])
    idle = {here: 1, w: 3, ww: 10, e: 4, ee: 2}
    p, s, strat = setup(m, "gravitational", [here])
    idle_at(s, 20, idle)
    assert ask_at(p, s, strat, 20)[0] == 3
    p, s, strat = setup(m, "gravitational", [here, w])
    idle_at(s, 20, idle)
    s.t = 19
    obs = world.begin_step(s, p)
    assert not obs.open[0, 0, 3] and obs.open[0, 0, 1]
    u = np.zeros((1, 2, 2))
    assert strat.act(obs, u)[0, 0] == 1
    shut = replace(obs, open=np.zeros_like(obs.open))
    assert strat.act(shut, u)[0, 0] == 3


def reference_forces(strat, m, x: int, mass: list[float], propagation: str) -> list[float]:
    """The forces on each port of target x, in plain Python, target by target in cell
    order (sum): the rules of the module's docstring, with its table of 1 / L^e."""
    dist = m.distances()
    targets = np.flatnonzero(m.target).tolist()
    far, length = strat.params.far_cells, strat.tcost
    out = [0.0] * m.n_ports
    for i, z in enumerate(targets):
        if propagation == "edge" and z != x and dist[x, z] > 0:
            for d in range(m.n_ports):
                n = int(m.neighbors[x, d])
                if n >= 0 and dist[n, z] == dist[x, z] - 1:
                    out[d] += mass[i] * strat.inv[dist[x, z]]
                    break
    if propagation == "edge":
        return out
    for d in range(m.n_ports):
        y = int(far[x, d])
        if y < 0:
            continue
        acc = 0.0
        for i, z in enumerate(targets):
            if dist[y, z] < 0 or (propagation == "mixed" and z == x):
                continue
            reach = dist[y, z] + (length[x, d] if propagation == "mixed" else 0)
            acc += mass[i] * strat.inv[reach]
        out[d] = acc / length[x, d] if propagation == "node" else acc
    return out


@pytest.mark.parametrize("propagation", gravitational.PROPAGATIONS)
@pytest.mark.parametrize("name", ["map_a", "graph"])
def test_forces_are_summed_target_by_target_in_cell_order(name, propagation):
    """To the bit, against plain Python on random idleness: the order the compiled twin
    sums in (numpy's pairwise ``sum`` would round differently on map A's 185 targets)."""
    m = get_map("map_a") if name == "map_a" else parse_map(GRAPH)
    rng = np.random.default_rng(3)
    cells = [c for c in np.flatnonzero(m.target).tolist() if (m.neighbors[c] >= 0).sum() >= 2]
    for x in cells[:: max(1, len(cells) // 6)]:
        extra = keys(propagation, "sum", **{"gravity.exponent": 1.5})
        p, s, strat = setup(m, "gravitational", [x], **extra)
        s.last[0, 0] = 500 - rng.integers(1, 400, size=m.n_cells)
        mass, force = forces_at(p, s, strat, 500)
        assert force.tolist() == reference_forces(strat, m, x, mass.tolist(), propagation), x


def test_the_hand_check_catches_a_strategy_that_ignores_the_goals(monkeypatch):
    """The deliberate break: masses without the goals' zero (SimPatrol's coordinator
    zeroes the mass of every vertex an agent is heading for), and the goal test above
    fails."""
    real = gravitational.Strategy.masses

    def no_goals(self, obs, k, rows):
        saved = self.goal.copy()
        self.goal[:] = -1
        try:
            return real(self, obs, k, rows)
        finally:
            self.goal[:] = saved

    monkeypatch.setattr(gravitational.Strategy, "masses", no_goals)
    with pytest.raises(AssertionError):
        test_goals_weigh_nothing_with_communication()


# ------------------------------------------------------------------- engines, liveness


#: (map, agents, battery, communication, avoid collisions, variant keys): graphs with
#: waypoints and grids; each team size, each boolean both ways, every propagation,
#: combination and growth.
ENGINE_CASES = [
    ("graph", 4, True, True, True, keys("edge", "sum", "arithmetic")),
    ("graph", 2, False, False, True, keys("node", "max", "geometric")),
    ("graph", 1, True, True, True, keys("mixed", "sum", "none")),
    # runs that stop at an episode quota sit out while the others go on
    ("graph", 4, False, True, False, keys("node_no_distance", "max", episodes=30)),
    (
        "graph",
        2,
        True,
        False,
        False,
        keys("mixed", "max", "geometric", **{"gravity.exponent": 1.0}),
    ),
    ("map_a", 4, True, True, True, keys("node", "sum", "arithmetic")),
    (
        "map_a",
        2,
        True,
        False,
        True,
        keys("edge", "max", "geometric", **{"gravity.growth_rate": 0.2}),
    ),
    (
        "map_a",
        1,
        False,
        True,
        True,
        keys("mixed", "sum", "arithmetic", **{"gravity.exponent": 0.5}),
    ),
    ("map_a", 4, False, False, False, keys("edge", "sum", "none")),
    ("loop", 4, True, True, True, keys("node_no_distance", "sum", "geometric")),
]


@pytest.mark.parametrize(
    "case",
    ENGINE_CASES,
    ids=lambda c: "-".join(str(v) for v in c[:5]) + "-" + "-".join(str(v) for v in c[5].values()),
)
def test_engines_agree(tmp_path, case):
    pytest.importorskip("numba")
    from test_engines import both

    name, k, bat, comm, avoid, extra = case
    if name == "graph":
        where = str(graph_file(tmp_path))
    elif name == "loop":
        where = tmp_path / "loop.txt"
        where.write_text(LOOP_GRID)
        where = str(where)
    else:
        where = name
    flat = {
        "runs": 2,
        "seed": 5,
        "steps": 400,
        "record.trajectory": 400,
        "map": where,
        "agents": k,
        "policy": "gravitational",
        "battery.enabled": bat,
        "battery.capacity": {"graph": 60, "loop": 40}.get(name, 200),
        "battery.charge_steps": 5,
        "team.communication": comm,
        "team.avoid_collisions": avoid,
        **extra,
    }
    assert both(flat, tmp_path, strategy=True) == ("numba", "")


def test_resumes_on_the_other_engine_to_the_same_files(tmp_path):
    """Stopped at step 37 on a graph with waypoints (robots inside edges, their goals
    saved) and resumed on the other engine: the uninterrupted run's files."""
    from test_checkpoint import folder, stop_at

    from qpatrol import engines
    from qpatrol.run import checkpoint as ck
    from qpatrol.run import simulate

    flat = {
        "map": str(graph_file(tmp_path)),
        "policy": "gravitational",
        "agents": 3,
        "runs": 2,
        "seed": 3,
        "steps": 90,
        "battery.capacity": 60,
        "battery.charge_steps": 3,
        "record.trajectory": 9,
        **keys("mixed", "max", "geometric"),
    }
    cfg = {e: from_flat({**flat, "engine": e}) for e in ("numpy", "numba")}
    whole = folder(simulate(cfg["numpy"]), tmp_path / "whole")
    pairs = [("numpy", "numpy")]
    if engines.numba_installed():
        pairs = [("numpy", "numba"), ("numba", "numpy")]
    for first, then in pairs:
        cp = tmp_path / f"cp-{first}-{then}"
        stop_at(cfg[first], cp, 37)
        resumed = ck.Checkpointer(cp, every=0)
        assert resumed.load().position == 37
        rest = simulate(cfg[then], checkpoint=resumed)
        assert rest.engine == then
        assert folder(rest, tmp_path / f"rest-{first}-{then}") == whole, (first, then)


@pytest.mark.parametrize("name", ["map_a", "graph"])
@pytest.mark.parametrize("k", [1, 2, 4])
@pytest.mark.parametrize("bat", [True, False])
def test_safe_and_live(name, k, bat):
    """No shared cell, no swap, no jump at any step; no wait past the bound (it chooses
    among its open moves, so the liveness theorem covers it without battery)."""
    m = get_map("map_a") if name == "map_a" else parse_map(GRAPH)
    extra = {} if bat else {"battery.enabled": False}
    engine = FAST if bat else "numpy"
    stall, bound, _ = drive(m, "gravitational", k, 7 + k, steps=400, engine=engine, **extra)
    assert stall.max() <= bound, f"{name} K={k}: max_stall {stall} > {bound}"
