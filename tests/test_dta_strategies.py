"""The dynamic task assignment strategies of patrolling_sim: ``dta-greedy``, ``dta-ssi``,
``dta-ssi-part``.

One decision of each, computed by hand on the small patrol graph of
``tests/test_field_strategies.py`` (hub 1 with four edges, D = 4); the two engines to the
bit on it and on map A; and their safety and liveness with 1, 2 and 4 robots, battery on
and off.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_field_strategies import FAST, GRAPH, decide, graph_file, idle_at, setup
from test_liveness import drive

from qpatrol import world
from qpatrol.maps import get_map, parse_map
from qpatrol.strategies import dta

DTA = ("dta-greedy", "dta-ssi", "dta-ssi-part")

# The graph's targets are its vertices 0..6 (the station 4 too). Moves between them:
# from 0: 1:2 2:5 3:3 4:4 5:2 6:6; from 1: 0:2 2:3 3:1 4:2 5:3 6:4;
# from 2: 0:5 1:3 3:4 4:5 5:6 6:2; from 6: 0:6 1:4 2:2 3:3 4:6 5:5.


def idle_all(s, t: int, idle: dict[int, int]) -> None:
    """Every group's map: cell c has idleness ``idle[c]`` at step t."""
    for g in range(s.last.shape[1]):
        idle_at(s, t, idle, group=g)


def only_robot_0(p, s, strat, t: int, u: float) -> None:
    """Step t with robot 0 alone deciding (the others keep their goals)."""
    s.t = t - 1
    obs = world.begin_step(s, p)
    obs.choosing[:, 1:] = False
    strat.act(obs, np.full((1, p.n_agents, 2), u))


def test_dta_greedy_weighs_idleness_navigation_and_origin():
    m = parse_map(GRAPH)
    assert m.distances()[1, :7].tolist() == [2, 0, 3, 1, 2, 3, 4]
    p, s, strat = setup(m, "dta-greedy", [1])
    assert strat.theta.tolist() == [1.0, -0.5, -2.0]
    # U = I - 0.5 L - 2 L (started on 1: the origin's moves are L): 0: 20 - 5 = 15,
    # 2: 24 - 7.5 = 16.5, 3: 10 - 2.5 = 7.5, 4: -5, 5: 24 - 7.5 = 16.5, 6: I - 10
    for idle6, u, want in ((30, 0.0, 6), (27, 0.0, 6), (26, 0.0, 2), (26, 0.99, 5)):
        strat.goal[0, 0] = -1
        idle_all(s, 50, {0: 20, 1: 0, 2: 24, 3: 10, 4: 0, 5: 24, 6: idle6})
        decide(p, s, strat, 50, u)
        assert strat.goal[0, 0] == want, (idle6, u)
    # the origin's term: 2 and 5 equally idle (24), 0 and 6 fresh; from origin 6,
    # 2: 24 - 1.5 - 4 = 18.5 beats 5: 24 - 1.5 - 10 = 12.5; from origin 0 it is the reverse
    for origin, want in ((6, 2), (0, 5)):
        strat.goal[0, 0] = -1
        strat.origin[0, 0] = origin
        idle_all(s, 50, {0: 0, 1: 0, 2: 24, 3: 10, 4: 0, 5: 24, 6: 0})
        decide(p, s, strat, 50, 0.0)
        assert strat.goal[0, 0] == want, origin
    # its own cell is never a candidate, however idle its record
    strat.goal[0, 0] = -1
    idle_all(s, 50, {0: 0, 1: 90, 2: 24, 3: 10, 4: 0, 5: 24, 6: 0})
    decide(p, s, strat, 50, 0.0)
    assert strat.goal[0, 0] == 5
    # on its goal's way it keeps it, and moves towards it
    strat.goal[0, 0] = 6
    assert decide(p, s, strat, 50, 0.0)[0] == 2 and strat.goal[0, 0] == 6


def test_dta_greedy_does_not_take_another_robots_goal():
    """Robot 1 heads for 6, the best target of robot 0 (on 1): with communication robot 0
    takes the next best (2), alone it takes 6 too."""
    m = parse_map(GRAPH)
    for comm, want in ((True, 2), (False, 6)):
        p, s, strat = setup(m, "dta-greedy", [1, 0], **{"team.communication": comm})
        idle_all(s, 50, {0: 0, 1: 0, 2: 24, 3: 10, 4: 0, 5: 0, 6: 30})
        strat.goal[0] = [-1, 6]
        strat.origin[0, 1] = 1
        only_robot_0(p, s, strat, 50, 0.0)
        assert strat.goal[0, 0] == want, comm


def test_dta_ssi_bids_and_auctions():
    """Robot 1 stands on 6 heading for 2 (2 moves): it bids 0 for 2 and 2 + L(2, x) for
    the others."""
    m = parse_map(GRAPH)
    dist = m.distances()
    p, s, strat = setup(m, "dta-ssi", [0, 6])
    strat.goal[0] = [-1, 2]
    b = dta.bids(dist, s.pos, strat.goal, 0, s.pos[:, 0])[0]
    assert b[0, :7].tolist() == [0, 2, 5, 3, 4, 2, 6]  # robot 0: its moves from 0
    assert b[1, :7].tolist() == [7, 5, 0, 6, 7, 8, 4]
    # utility = idleness (ssi_navigation 0): 2 (30) is robot 1's, and robot 1 bids less
    # for 6 (28): 4 < 6; robot 0 wins 5 (25), not 1 (20)
    idle_all(s, 50, {0: 0, 1: 20, 2: 30, 3: 10, 4: 0, 5: 25, 6: 28})
    only_robot_0(p, s, strat, 50, 0.0)
    assert strat.goal[0, 0] == 5
    # from 1 robot 0 bids 4 for 6, as robot 1 does: the auctioneer keeps a tie
    p, s, strat = setup(m, "dta-ssi", [1, 6])
    strat.goal[0] = [-1, 2]
    idle_all(s, 50, {0: 0, 1: 0, 2: 30, 3: 10, 4: 0, 5: 25, 6: 28})
    only_robot_0(p, s, strat, 50, 0.0)
    assert strat.goal[0, 0] == 6
    # alone, it takes the idlest target, robot 1's goal
    p, s, strat = setup(m, "dta-ssi", [0, 6], **{"team.communication": False})
    strat.goal[0] = [-1, 2]
    idle_all(s, 50, {0: 0, 1: 20, 2: 30, 3: 10, 4: 0, 5: 25, 6: 28})
    only_robot_0(p, s, strat, 50, 0.0)
    assert strat.goal[0, 0] == 2


def test_dta_ssi_navigation_weighs_the_moves():
    """``dta.ssi_navigation = -2``, from 1: 3 (idleness 24, 1 move: 22) beats 6 (28, 4
    moves: 20) and 5 (25, 3 moves: 19); without 3's idleness, 6 beats 5."""
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "dta-ssi", [1], **{"dta.ssi_navigation": -2.0})
    idle_all(s, 50, {0: 0, 1: 0, 2: 0, 3: 24, 4: 0, 5: 25, 6: 28})
    decide(p, s, strat, 50, 0.0)
    assert strat.goal[0, 0] == 3
    strat.goal[0, 0] = -1
    idle_all(s, 50, {0: 0, 1: 0, 2: 0, 3: 0, 4: 0, 5: 25, 6: 28})
    decide(p, s, strat, 50, 0.0)
    assert strat.goal[0, 0] == 6


def test_dta_ssi_part_bids_from_the_center_times_the_tasks():
    """Robot 0 on 1 (center 0, no tasks) auctions; robot 1 on 6 heads for 3, center 6.
    Idleness: 2 (30), 6 (28), 5 (25), the rest less."""
    m = parse_map(GRAPH)
    idle = {0: 0, 1: 0, 2: 30, 3: 10, 4: 0, 5: 25, 6: 28}
    # robot 1 owns 2: it bids 2 moves x 2 = 4 < 5 (robot 0: 5 moves x 1) and keeps it;
    # for 6 it bids 0 x 3 (owning 2) < 6: it wins 6; for 5, 5 x 3 = 15 > 2: robot 0 wins
    p, s, strat = setup(m, "dta-ssi-part", [1, 6])
    strat.goal[0], strat.center[0] = [-1, 3], [0, 6]
    strat.owner[0, 2] = 1
    idle_all(s, 50, idle)
    only_robot_0(p, s, strat, 50, 0.0)
    assert strat.goal[0, 0] == 5
    assert strat.owner[0, [2, 5, 6]].tolist() == [1, 0, 1]
    # centers: robot 0's its one task, 5; robot 1's stays on its cell 6 (sum 2 to {2, 6},
    # as from 2: its cell first on a tie)
    assert strat.center[0].tolist() == [5, 6]
    # robot 1 owning 2, 0 and 4 bids 2 x 4 = 8 > 5 for 2: robot 0 wins 2; robot 1's
    # center moves to 0 (sums to {0, 4}: 0 from 0: 4, from 6: 12; 4 ties 0)
    p, s, strat = setup(m, "dta-ssi-part", [1, 6])
    strat.goal[0], strat.center[0] = [-1, 3], [0, 6]
    strat.owner[0, [0, 2, 4]] = 1
    idle_all(s, 50, idle)
    only_robot_0(p, s, strat, 50, 0.0)
    assert strat.goal[0, 0] == 2
    assert strat.owner[0, [0, 2, 4]].tolist() == [1, 0, 1]
    assert strat.center[0].tolist() == [2, 0]
    # a tie of bids stays with the auctioneer: for 3, 3 moves x 1 from either center
    p, s, strat = setup(m, "dta-ssi-part", [1, 6])
    strat.goal[0], strat.center[0] = [-1, 4], [0, 6]
    idle_all(s, 50, {**idle, 3: 40})
    only_robot_0(p, s, strat, 50, 0.0)
    assert strat.goal[0, 0] == 3 and strat.owner[0, 3] == 0
    # alone: no auction, the idlest target; equal utilities in cell order from floor(u C)
    p, s, strat = setup(m, "dta-ssi-part", [1, 6], **{"team.communication": False})
    strat.goal[0] = [-1, 3]
    strat.owner[0, [0, 2, 4]] = 1
    idle_all(s, 50, {**idle, 5: 30})
    for u, want in ((0.0, 2), (0.25, 5)):  # C = 16 cells: o = 0, then 4 (5 before 2)
        strat.goal[0, 0] = -1
        only_robot_0(p, s, strat, 50, u)
        assert strat.goal[0, 0] == want, u
    assert strat.owner[0, [0, 2, 4]].tolist() == [1, 1, 1]


#: (map, agents, battery, communication)
ENGINE_CASES = [
    ("graph", 4, True, True),
    ("graph", 2, False, False),
    ("graph", 1, True, True),
    ("map_a", 4, True, True),
    ("map_a", 4, False, False),
    ("map_a", 2, True, False),
    ("map_a", 1, False, True),
]


@pytest.mark.parametrize("policy", DTA)
@pytest.mark.parametrize("case", ENGINE_CASES, ids=lambda c: "-".join(map(str, c)))
def test_engines_agree(tmp_path, policy, case):
    pytest.importorskip("numba")
    from test_engines import both

    name, k, battery, comm = case
    flat = {
        "runs": 2,
        "seed": 7,
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


def test_engines_agree_on_the_dta_keys(tmp_path):
    pytest.importorskip("numba")
    from test_engines import both

    for policy, keys in (
        ("dta-greedy", {"dta.greedy_origin": 0.0, "dta.greedy_navigation": -1.5}),
        ("dta-ssi", {"dta.ssi_navigation": -0.5, "dta.theta_idleness": 2.0}),
    ):
        flat = {
            "runs": 2,
            "seed": 9,
            "steps": 300,
            "record.trajectory": 300,
            "map": str(graph_file(tmp_path)),
            "agents": 3,
            "policy": policy,
            "battery.capacity": 60,
            **keys,
        }
        assert both(flat, tmp_path, strategy=True) == ("numba", "")


@pytest.mark.parametrize("policy", DTA)
@pytest.mark.parametrize("name", ["map_a", "graph"])
@pytest.mark.parametrize("k", [1, 2, 4])
@pytest.mark.parametrize("battery", [True, False])
def test_safe_and_live(policy, name, k, battery):
    """No shared cell, no swap, no jump at any step (``check_steps``); no wait past the
    bound."""
    m = get_map("map_a") if name == "map_a" else parse_map(GRAPH)
    seed = sum(map(ord, name + policy)) + k
    extra = {} if battery else {"battery.enabled": False}
    engine = FAST if battery else "numpy"
    stall, bound, _ = drive(m, policy, k, seed, steps=600, engine=engine, **extra)
    assert stall.max() <= bound, f"{name} K={k} {policy}: max_stall {stall} > {bound}"
