"""``cbls`` (patrolling_sim's Concurrent Bayesian Learning Strategy): one decision and
one judgement computed by hand on the small patrol graph of
``tests/test_field_strategies.py`` (hub 1 with four edges, D = 4), the visit tables, the
two engines to the bit, and safety and liveness with 1, 2 and 4 robots."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from test_field_strategies import FAST, GRAPH, decide, graph_file, setup
from test_liveness import drive

from qpatrol.maps import get_map, parse_map

# Hub 1's ports 0..3 lead to targets 0, 2, 3, 4 (2, 3, 1 and 2 moves). Target
# neighbours: 0: {1, 5}; 2: {1, 6}; 3: {1, 5, 6}; 4: {1} (degree 1).
IDLE = {0: 10, 1: 0, 2: 20, 3: 8, 4: 30, 5: 40, 6: 4}


def tables(strat, t: int, idle: dict[int, int], group: int = 0) -> None:
    """Never-counted targets with idleness ``idle[v]`` at step t (mean idleness = I)."""
    for v, i in idle.items():
        strat.seen[0, group, v] = t - i


def test_cbls_posterior_of_the_lookahead_prior_and_the_histogram():
    """Priors: 0: 0.75 x 10 + 0.25 x 40 (its neighbour 5) = 17.5; 2: 0.75 x 20 + 0.25 x 4
    = 16; 3: 0.75 x 8 + 0.25 x 40 = 16; 4 (one neighbour): 30."""
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "cbls", [1])
    assert strat.learns and strat.degree[[0, 2, 3, 4]].tolist() == [2, 2, 3, 1]
    tables(strat, 50, IDLE)
    decide(p, s, strat, 50, 0.0)
    assert strat.goal[0, 0] == 4
    post = np.array([17.5, 16, 16, 30]) / 79.5
    q = post / post.sum()
    assert strat.dec_ent[0, 0] == pytest.approx(-(q * np.log(q)).sum() / math.log(4))
    assert strat.dec_cell[0, 0] == 1 and strat.dec_ports[0, 0].all()
    # the histogram weighs the posterior: port 3 at 0.5 gives 15 < 17.5
    strat.hist[0, 0, 1, 3] = 0.5
    decide(p, s, strat, 50, 0.0)
    assert strat.goal[0, 0] == 0
    # 0 and 4 at 0.5: 2 and 3 tie at 16, the nearer (3, 1 move) wins
    strat.hist[0, 0, 1, 0] = 0.5
    decide(p, s, strat, 50, 0.0)  # (u = 0 would take 2, the first tied port)
    assert strat.goal[0, 0] == 3


def test_cbls_leaves_out_targets_others_intend():
    m = parse_map(GRAPH)
    for comm, want in ((True, 0), (False, 4)):
        p, s, strat = setup(m, "cbls", [1, 6], **{"team.communication": comm})
        tables(strat, 50, IDLE)
        strat.goal[0, 1] = 4  # robot 1 is heading for 4
        s.t = 49
        from qpatrol import world

        obs = world.begin_step(s, p)
        obs.choosing[:, 1] = False
        strat.act(obs, np.zeros((1, 2, 2)))
        assert strat.goal[0, 0] == want, comm
        assert strat.dec_ports[0, 0].tolist() == ([True, True, True, False] if comm else [True] * 4)


def test_cbls_rewards_the_idlest_and_punishes_the_freshest():
    """The last decision at 1 (all four ports, entropy 0.25); the robot is now on 4. With
    idleness 10, 20, 20, 1 at 0, 2, 3, 4: ports 1 and 2 gain 0.75 (port 1 from 1.5 is
    clipped to 2), port 3 loses 0.75 (clipped to 0.5), port 0 keeps 1."""
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "cbls", [4])
    strat.dec_cell[0, 0], strat.dec_ports[0, 0], strat.dec_ent[0, 0] = 1, True, 0.25
    strat.hist[0, 0, 1, 1] = 1.5
    tables(strat, 50, {0: 10, 2: 20, 3: 20, 4: 1, 1: 0, 5: 0, 6: 0})
    decide(p, s, strat, 50, 0.0)
    assert strat.hist[0, 0, 1].tolist() == [1.0, 2.0, 1.75, 0.5]
    assert strat.dec_cell[0, 0] == 4 and strat.goal[0, 0] == 1  # its one neighbour
    # a decision with a single candidate is not judged, nor one made where it stands
    before = strat.hist.copy()
    strat.dec_cell[0, 0] = 1
    strat.dec_ports[0, 0] = [False, False, True, False]
    decide(p, s, strat, 50, 0.0)
    assert (strat.hist == before).all()
    s.pos[0, 0], s.occ[0] = 1, -1
    s.occ[0, 1] = 0
    strat.dec_cell[0, 0], strat.dec_ports[0, 0] = 1, True
    decide(p, s, strat, 50, 0.0)
    assert (strat.hist == before).all()


def test_cbls_counts_visits_and_their_mean_idleness():
    m = parse_map(GRAPH)
    p, s, strat = setup(m, "cbls", [1, 6])
    for t in (10, 16):
        strat.learn(SimpleNamespace(t=t, moved=np.array([[True, False]]), pos=np.array([[3, 6]])))
    assert strat.count[0, 0, 3] == 2 and strat.avg[0, 0, 3] == 8.0 and strat.seen[0, 0, 3] == 16
    assert strat.count[0, 0, 6] == 0  # robot 1 did not move
    assert strat.mean_idleness(0, np.array([0]), np.array([3]), 20)[0] == (8.0 * 2 + 4) / 3


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


@pytest.mark.parametrize("case", ENGINE_CASES, ids=lambda c: "-".join(map(str, c)))
def test_engines_agree(tmp_path, case):
    pytest.importorskip("numba")
    from test_engines import both

    name, k, battery, comm = case
    flat = {
        "runs": 2,
        "seed": 11,
        "steps": 400,
        "record.trajectory": 400,
        "map": str(graph_file(tmp_path)) if name == "graph" else name,
        "agents": k,
        "policy": "cbls",
        "battery.enabled": battery,
        "battery.capacity": 60 if name == "graph" else 200,
        "battery.charge_steps": 5,
        "team.communication": comm,
    }
    assert both(flat, tmp_path, strategy=True) == ("numba", "")


@pytest.mark.parametrize("name", ["map_a", "graph"])
@pytest.mark.parametrize("k", [1, 2, 4])
@pytest.mark.parametrize("battery", [True, False])
def test_safe_and_live(name, k, battery):
    """No shared cell, no swap, no jump at any step (``check_steps``); no wait past the
    bound."""
    m = get_map("map_a") if name == "map_a" else parse_map(GRAPH)
    seed = sum(map(ord, name + "cbls")) + k
    extra = {} if battery else {"battery.enabled": False}
    engine = FAST if battery else "numpy"
    stall, bound, _ = drive(m, "cbls", k, seed, steps=600, engine=engine, **extra)
    assert stall.max() <= bound, f"{name} K={k} cbls: max_stall {stall} > {bound}"
