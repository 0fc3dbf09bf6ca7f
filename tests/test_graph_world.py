"""The world and both engines on patrol graphs: cells with D ports (D = 1..8).

Tiny graph maps written here (edges of several moves, so they have waypoints; a degree-5
centre, a vertex of degree 7, a station at the end of a long edge) run every strategy
with 1, 2 and 4 robots, battery on and off, on both engines: the run folders are equal
to the byte (the harness of ``tests/test_engines.py``), and at every step the safety
rules of ``tests/test_liveness.py`` hold (no shared cell, no swap, no jump along a
non-edge, charge >= 0). Then rules by hand: the heading after entering a vertex is the
port it was entered through (both engines), a waypoint has two ports, and the learner's
table has D heading slots.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from test_engines import both
from test_liveness import check_steps

from qpatrol import strategies, world
from qpatrol.config import from_flat
from qpatrol.engines.numpy_loop import advance
from qpatrol.maps import parse_map
from qpatrol.maps.core import far_targets
from qpatrol.strategies.qlearning import Strategy as QLearning
from qpatrol.world.rng import Streams, run_seeds

HAS_NUMBA = importlib.util.find_spec("numba") is not None

#: A triangle 0-1-2 with edges of 2, 1 and 3 moves (three waypoints) and a tail 2-3 of
#: 2 moves; its station, vertex 1, lies on the ring. D = 3 (vertex 2).
TRIANGLE = """\
; name: triangle
; kind: graph
v 0 0 0 start=0
v 1 4 0 station
v 2 2 3
v 3 5 4
e 0 1 2
e 1 2 1
e 2 0 3
e 2 3 2
"""

#: A star: centre 0 of degree 5, two leaves joined by a second path so that it has a
#: cycle, and a station at the end of a spur of 4 moves (a pocket of waypoints). D = 5.
STAR = """\
; name: star
; kind: graph
v 0 0 0
v 1 2 0
v 2 0 2 big
v 3 -2 0
v 4 0 -2
v 5 3 3 station
e 0 1 1
e 0 2 2
e 0 3 1
e 0 4 3
e 0 5 4
e 1 2 2
e 3 4 2
"""

#: A hub of degree 7 on a wheel: the rim 1..7 is a ring of edges of 1 and 2 moves, the
#: hub's spokes 1 or 2 moves; the station is a rim vertex. D = 7.
WHEEL = (
    "; name: wheel\n; kind: graph\nv 0 0 0\n"
    + "".join(
        f"v {i} {np.cos(i):.3f} {np.sin(i):.3f}{' station' if i == 4 else ''}\n"
        for i in range(1, 8)
    )
    + "".join(f"e 0 {i} {1 + i % 2}\n" for i in range(1, 8))
    + "".join(f"e {i} {i % 7 + 1} {1 + (i + 1) % 2}\n" for i in range(1, 8))
)

#: A ring of four vertices (edges of 2 moves) and a spur of 5 moves from vertex 0 to the
#: station vertex 4: the station ends a long dead-end edge. D = 3.
SPUR = """\
; name: spur
; kind: graph
v 0 0 0
v 1 2 0
v 2 2 2
v 3 0 2
v 4 -5 0 station
e 0 1 2
e 1 2 2
e 2 3 2
e 3 0 2
e 0 4 5
"""

MAPS = {"triangle": TRIANGLE, "star": STAR, "wheel": WHEEL, "spur": SPUR}
PORTS = {"triangle": 3, "star": 5, "wheel": 7, "spur": 3}
POLICIES = strategies.NAMES

#: Every strategy on every map; team size and battery take turns over the table (each
#: strategy meets 1, 2 and 4 robots and both battery settings on some map). A triangle
#: has 9 cells, so 4 robots (which need 8 cells to yield) do not fit there.
CASES = [
    (name, policy, k, battery)
    for i, name in enumerate(MAPS)
    for j, policy in enumerate(POLICIES)
    for k, battery in [((1, 2, 4)[(i + j) % 3], (i + j) % 2 == 0)]
    if not (name == "triangle" and k == 4)
]


def write(tmp_path: Path, name: str) -> Path:
    path = tmp_path / f"{name}.txt"
    path.write_text(MAPS[name])
    return path


def flat_of(path: Path, policy: str, k: int, battery: bool) -> dict:
    return {
        "map": str(path),
        "policy": policy,
        "agents": k,
        "runs": 2,
        "seed": 5,
        "steps": 150,
        "max_episode_steps": 50,
        "record.trajectory": 150,
        "battery.enabled": battery,
        "battery.capacity": 40,
        "battery.charge_steps": 3,
    }


def test_the_maps_have_the_ports_they_are_written_for():
    for name, text in MAPS.items():
        m = parse_map(text)
        assert m.is_graph and m.n_ports == PORTS[name], name
    assert {k for _, _, k, _ in CASES} == {1, 2, 4}
    assert {(p, b) for _, p, _, b in CASES} == {(p, b) for p in POLICIES for b in (True, False)}


@pytest.mark.skipif(not HAS_NUMBA, reason="numba not installed")
@pytest.mark.parametrize("name, policy, k, battery", CASES)
def test_both_engines_agree_on_graphs_and_the_rules_hold(tmp_path, name, policy, k, battery):
    """Both engines write the same files to the byte; the compiled run's trajectory
    keeps the safety rules at every step and no charge went below 0."""
    from qpatrol.config import from_flat as ff
    from qpatrol.run import simulate

    flat = flat_of(write(tmp_path, name), policy, k, battery)
    assert both(flat, tmp_path) == ("numba", "")
    result = simulate(ff({**flat, "engine": "numba"}))
    p = world.make_params(ff(flat), parse_map(MAPS[name]))
    for _, run in result.trajectory.groupby("run"):
        check_steps(run["cell"].to_numpy().reshape(-1, k), p)
    if battery:
        assert min(s["min_charge"] for s in result.summary) >= 0


@pytest.mark.parametrize("name", ["star", "wheel"])
def test_numpy_engine_keeps_the_safety_rules_step_by_step(name):
    """The reference engine, stepped here: every state after every step (4 robots,
    battery on, random moves so that robots meet and push)."""
    m = parse_map(MAPS[name])
    cfg = from_flat(flat_of(Path("x"), "random", 4, True))
    p = world.make_params(cfg, m)
    streams = Streams(run_seeds(2, range(2)), 4)
    starts = np.stack([world.place_agents(p, m, g) for g in streams.generators])
    s = world.init_state(p, starts)
    strat = strategies.make("random", cfg, m, p, starts)
    for _ in range(300):
        before = s.pos.copy()
        advance(s, p, strat, streams.next())
        check_steps(np.stack([before, s.pos], axis=1), p)
        assert (s.charge >= 0).all()


def test_a_waypoint_has_two_ports_and_a_vertex_its_degree():
    m = parse_map(TRIANGLE)
    waypoints = np.flatnonzero(~m.target)
    assert waypoints.size == 1 + 0 + 2 + 1
    assert ((m.neighbors[waypoints] >= 0).sum(axis=1) == 2).all()
    assert (m.neighbors[waypoints, :2] >= 0).all()
    assert (m.degree[:4] == [2, 2, 3, 1]).all()


def _heading_after_entering(engine: str) -> tuple[int, int, int]:
    """One robot on the star steps into leaf 1 from the waypoint of edge 1-2 next to it.
    Leaf 1's ports in file order: edge 0-1 (port 0), edge 1-2 (port 1), so it enters
    through port 1. Returns ``(cell, heading, the port back)`` after the step."""
    m = parse_map(STAR)
    cfg = from_flat({"policy": "qlearning", "agents": 1, "runs": 1, "steps": 1})
    p = world.make_params(cfg, m)
    wp = int(m.neighbors[1, 1])  # the waypoint of edge 1-2 next to leaf 1
    assert not m.target[wp]
    s = world.init_state(p, np.array([[wp]]))
    assert s.head[0, 0] == 0  # port 0 before the first move
    port_to_1 = int(np.flatnonzero(m.neighbors[wp] == 1)[0])
    if engine == "numpy":
        # it came along the edge from vertex 2's side, so it travels on to leaf 1
        s.head[0, 0] = 1 - port_to_1
        obs = world.begin_step(s, p)
        assert not obs.choosing[0, 0] and obs.travel[0, 0] == port_to_1
        world.step(s, p, obs, np.array([[port_to_1]]))
        return int(s.pos[0, 0]), int(s.head[0, 0]), int(m.back[wp, port_to_1])
    from qpatrol.engines.compiled import bundles, enter

    entry = bundles.compiled_entry(p.neighbors, p.entry)
    assert entry is not None  # a graph's: headings read from entry

    grp = (s.dots[0, 0], s.last[0, 0], s.ep_seen[0, 0], s.ep_seen_state[0, 0])
    cnt = (s.dots_left[0, 0], s.ep_dots[0, 0], s.ep_visits[0, 0])
    for asked in (port_to_1, -1):  # as asked, and pushed (the port found from the cells)
        heading, *_ = enter.enter(
            wp, 1, asked, 1, p.neighbors, entry, p.dot_value, grp, cnt, (1.0, 100.0, 1.0)
        )
        assert heading == m.back[wp, port_to_1]
    return 1, int(heading), int(m.back[wp, port_to_1])


@pytest.mark.parametrize(
    "engine", ["numpy", pytest.param("numba", marks=pytest.mark.skipif(not HAS_NUMBA, reason=""))]
)
def test_heading_after_entering_a_vertex_is_the_port_entered_through(engine):
    cell, heading, back = _heading_after_entering(engine)
    assert cell == 1 and back == 1  # leaf 1's port 1 is its edge to vertex 2
    assert heading == 1


@pytest.mark.skipif(not HAS_NUMBA, reason="numba not installed")
def test_compiled_learner_headings_are_ports_on_a_graph(tmp_path):
    """A lone learner on the wheel: every Q-update row runs from a vertex to the vertex
    at the far end of the port chosen, and its next heading is the port of that vertex
    that leads back along the edge (both engines write these rows to the byte: test
    above; here the rule itself, on the compiled rows)."""
    from qpatrol.run import simulate

    path = write(tmp_path, "wheel")
    m = parse_map(WHEEL)
    flat = {**flat_of(path, "qlearning", 1, False), "record.transitions": True}
    result = simulate(from_flat({**flat, "engine": "numba"}))
    tr = result.transitions
    assert len(tr) > 50
    far, moves = far_targets(m.neighbors, m.back, m.target)
    for c, a, c1, h1 in tr[["cell", "action", "next_cell", "next_heading"]].to_numpy():
        assert m.target[c] and far[c, a] == c1
        # the cell before c1 on the edge: c itself, or the edge's last waypoint
        before = c if moves[c, a] == 1 else m.neighbors[c1, h1]
        assert m.target[before] == (moves[c, a] == 1)
        assert m.neighbors[before, m.back[c1, h1]] == c1


def test_learner_tables_have_d_heading_slots_on_a_graph():
    for name in ("star", "wheel"):
        m = parse_map(MAPS[name])
        cfg = from_flat({"policy": "qlearning", "agents": 1, "runs": 1})
        p = world.make_params(cfg, m)
        starts = np.zeros((1, 1), dtype=np.int64)
        q = QLearning(cfg, m, p, starts).q
        d = PORTS[name]
        assert q.shape == (1, 1, m.n_cells, d, d)
        # ports have no compass: every move starts at multiplier x the largest q_init
        assert (q == 3 * 100).all()
        qi = strategies.make("qlearning-idleness", cfg, m, p, starts).q
        assert qi.shape[-3:] == (d, d, d)


def test_envs_act_by_port_on_a_graph(tmp_path):
    """Gymnasium/PettingZoo: a graph's action space is Discrete(D), observations fit
    their space, and a step by port moves the robot along that port."""
    pytest.importorskip("gymnasium")
    pytest.importorskip("pettingzoo")
    from qpatrol.envs import PatrolEnv, PatrolParallelEnv

    path = write(tmp_path, "star")
    m = parse_map(STAR)
    env = PatrolParallelEnv(None, ["runs=1"], map=str(path), agents=2, max_steps=40)
    obs, infos = env.reset(seed=1)
    for a in env.agents:
        assert env.action_space(a).n == 5
        assert env.observation_space(a).contains(obs[a])
        assert infos[a]["action_mask"].shape == (5,)
    single = PatrolEnv(None, ["runs=1"], map=str(path), max_steps=40)
    obs, info = single.reset(seed=1)
    assert single.action_space.n == 5 and single.observation_space.contains(obs)
    c = single.sim.state.pos[0, 0]
    port = int(np.flatnonzero(info["action_mask"])[0])
    obs, *_ = single.step(port)
    assert single.sim.state.pos[0, 0] == m.neighbors[c, port]
    assert single.sim.state.head[0, 0] == m.entry[c, port]
    assert single.observation_space.contains(obs)
    with pytest.raises(ValueError, match="0..4"):
        single.step(5)


#: A graph of D = 4 (vertex 0 has four edges): its headings are ports arrived through,
#: not the ports moved by, so the compiled loops must not take a grid's shortcut.
SQUARE = """\
; name: square
; kind: graph
v 0 0 0
v 1 2 0
v 2 2 2
v 3 0 2
v 4 1 1 station
e 0 1 2
e 1 2 2
e 2 3 1
e 3 0 2
e 0 4 2
e 0 2 3
"""


def test_the_compiled_grid_shortcut_is_taken_on_grids_only(tmp_path, rooms_map):
    """``bundles.compiled_entry``: a grid's (4 ports, heading = move) is None, which lets
    the compiled loops fix D = 4 and skip ``entry``; a graph's, even of D = 4, is its
    ``entry``; and the engines agree on that D = 4 graph."""
    pytest.importorskip("numba")
    from qpatrol.engines.compiled import bundles
    from qpatrol.maps import load_map

    grid = load_map(rooms_map)
    assert bundles.compiled_entry(grid.neighbors, grid.entry) is None
    square = parse_map(SQUARE)
    assert square.n_ports == 4 and (square.entry != np.arange(4)).any()
    assert bundles.compiled_entry(square.neighbors, square.entry) is square.entry
    path = tmp_path / "square.txt"
    path.write_text(SQUARE)
    for policy, k in (("qlearning", 1), ("qlearning", 2), ("qlearning-idleness", 2)):
        flat = {**flat_of(path, policy, k, False), "record.transitions": True}
        assert both(flat, tmp_path / f"{policy}{k}") == ("numba", "")


def test_a_station_at_the_end_of_a_long_edge_has_its_waypoints_as_pocket():
    """Pockets are corridors of degree-2 cells: on the spur the station's pocket is the
    edge's four waypoints and the station, cut off by vertex 0; a homing robot's first
    move there goes along the spur (home_dir over ports)."""
    m = parse_map(SPUR)
    cfg = from_flat({"agents": 1, "battery.enabled": True, "battery.capacity": 60})
    p = world.make_params(cfg, m)
    spur = [c for c in range(m.n_cells) if not m.target[c] and m.xy[c, 0] < 0]
    assert len(spur) == 4
    assert sorted(np.flatnonzero(p.pocket_of == 0).tolist()) == sorted([*spur, 4])
    assert p.pocket_entry.tolist() == [0]
    assert p.pocket_depth[4] == 5
    toward = int(p.home_dir[0, 0])
    assert m.neighbors[0, toward] in spur and p.home_dist[0, 0] == 5


def test_plain_python_reference_loop_gives_the_cores_q_table_on_a_graph(tmp_path):
    """``qpatrol.run.reference`` (the yardstick of ``qpatrol bench``) on the wheel: a lone
    learner's Q-table to the bit, so the core's headings on a graph are the ports
    arrived through (``entry``) as the plain loop has them."""
    from qpatrol.run import reference, simulate

    path = write(tmp_path, "wheel")
    cfg = from_flat(
        {"map": str(path), "agents": 1, "steps": 400, "seed": 2, "max_episode_steps": 90}
    )
    core = simulate(cfg.replace(engine="numpy"))
    streams = Streams(run_seeds(cfg["seed"], 1), 1)
    starts = world.place_agents(core.params, core.map, streams.generators[0]).tolist()
    q_init = core.strategy.q_init.tolist()
    assert len(q_init) == 7
    ref = reference.run(core.params, starts, streams.take(400)[0], q_init, cfg["learning.gamma"])
    q, n = ref.arrays(core.params.n_cells, 1, q_init)
    assert n.sum() > 0
    np.testing.assert_array_equal(n, core.strategy.n[0])
    assert np.array_equal(q, core.strategy.q[0])
    assert ref.pos == core.state.pos[0].tolist()


def test_watch_is_refused_on_a_graph_without_four_ports(tmp_path):
    """watch.csv has a grid cell's four Q-value columns: a D = 2 graph refuses record.watch
    at load, naming the key (one line, a ConfigError)."""
    from qpatrol.config import ConfigError, from_flat
    from qpatrol.maps import load_map
    from qpatrol.world import make_params

    path = tmp_path / "tri.txt"
    path.write_text("; kind: graph\nv 0 0 0\nv 1 1 0\nv 2 0 1\ne 0 1 1\ne 1 2 2\ne 2 0 1\n")
    m = load_map(path)
    assert m.n_ports == 2  # a triangle: every cell has two ports
    cfg = from_flat({"map": str(path), "battery.enabled": False, "agents": 1})
    make_params(cfg, m)  # accepted without a watched cell
    watched = from_flat(
        {"map": str(path), "battery.enabled": False, "agents": 1, "record.watch": [0]}
    )
    with pytest.raises(ConfigError, match=r"^record\.watch: .*2 ports"):
        make_params(watched, m)


def test_robots_beyond_the_starts_are_placed_on_vertices(tmp_path):
    """A path of three vertices with edges of 4 moves (6 waypoints) and no start: the
    first robot goes to any vertex (all tie), each next one to the vertex farthest from
    those placed, so the three always take the three vertices; placed over every cell the
    first could land on a waypoint."""
    from qpatrol.config import from_flat
    from qpatrol.maps import load_map
    from qpatrol.world import make_params, place_agents

    path = tmp_path / "path.txt"
    path.write_text("; kind: graph\nv 0 0 0\nv 1 4 0\nv 2 8 0\ne 0 1 4\ne 1 2 4\n")
    m = load_map(path)
    p = make_params(from_flat({"map": str(path), "battery.enabled": False, "agents": 3}), m)
    for seed in range(5):
        cells = place_agents(p, m, np.random.default_rng(seed))
        assert sorted(cells.tolist()) == [0, 1, 2], cells


@pytest.mark.parametrize(
    ("turns", "interaction", "turned"),
    [(True, "exclusive", True), (False, "exclusive", False), (True, "none", False)],
)
def test_a_walk_follower_travelling_an_edge_turns_round_when_it_asks_for_the_port_behind(
    turns, interaction, turned
):
    """A robot on the waypoint of the star's edge 1-2 next to leaf 1, travelling towards
    leaf 1, whose strategy asks for the port behind it: a strategy that plans on edges
    (``turns``, the walk followers) turns it round under ``exclusive``, and it steps back
    towards vertex 2 with its heading reversed; any other strategy, or robots that pass
    each other, travel on to leaf 1 whatever they ask."""
    m = parse_map(STAR)
    cfg = from_flat(
        {"policy": "cyclic", "agents": 1, "runs": 1, "steps": 1, "team.interaction": interaction}
    )
    p = world.make_params(cfg, m)
    wp = int(m.neighbors[1, 1])  # the waypoint of edge 1-2 next to leaf 1
    s = world.init_state(p, np.array([[wp]]))
    port_to_1 = int(np.flatnonzero(m.neighbors[wp] == 1)[0])
    behind = 1 - port_to_1
    s.head[0, 0] = behind  # it came from vertex 2's side
    obs = world.begin_step(s, p)
    assert obs.travel[0, 0] == port_to_1
    out = world.step(s, p, obs, np.array([[behind]]), None, turns)
    if turned:
        assert out.ask[0, 0] == behind and s.pos[0, 0] == m.neighbors[wp, behind]
        assert s.aim[0, 0] == 2  # the vertex ahead is now vertex 2
    else:
        assert out.ask[0, 0] == port_to_1 and s.pos[0, 0] == 1
        assert s.aim[0, 0] == 1
    assert out.prev_head[0, 0] == behind  # the heading before the step


def test_a_walk_follower_does_not_turn_round_into_a_taken_cell():
    """The same traveller, with another robot standing in the cell behind it: turning
    round would push that robot back along the edge, and two travellers pushed into
    each other's way turn and push for ever (4 ``cyclic`` robots with the battery on
    ps_example did, at a station); it travels on to leaf 1."""
    m = parse_map(STAR)
    flat = {"policy": "cyclic", "agents": 2, "runs": 1, "steps": 1, "team.interaction": "exclusive"}
    cfg = from_flat(flat)
    p = world.make_params(cfg, m)
    wp = int(m.neighbors[1, 1])
    port_to_1 = int(np.flatnonzero(m.neighbors[wp] == 1)[0])
    behind = 1 - port_to_1
    s = world.init_state(p, np.array([[wp, int(m.neighbors[wp, behind])]]))
    s.head[0, 0] = behind
    obs = world.begin_step(s, p)
    out = world.step(s, p, obs, np.array([[behind, -1]]), None, True)
    assert out.ask[0, 0] == port_to_1 and s.pos[0, 0] == 1


def test_a_grid_and_a_graph_share_the_general_loops_machine_code(monkeypatch, tmp_path, rooms_map):
    """The general loop and the recorders' loop take a grid's headings as an array, as a
    graph's: their arguments have the same types on both kinds of map, so numba compiles
    each once (a cold start would pay the general loop's compile twice otherwise). The
    lone and team learners keep the grid's constant D = 4 (their types differ)."""
    numba = pytest.importorskip("numba")
    from qpatrol.engines import numba_core
    from qpatrol.run import simulate

    made: list = []

    class Spy(numba_core.Loop):
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            made.append(self)

    monkeypatch.setattr(numba_core, "Loop", Spy)
    graph = "ps_grid"  # (unit edges: its learners take the recorders' loop, not the general)

    def types(path: Path | str, **keys) -> tuple:
        made.clear()
        flat = {**flat_of(path, "qlearning", 2, False), "engine": "numba", "steps": 5}
        flat.update({"record.trajectory": 0, **keys})
        simulate(from_flat(flat))
        (loop,) = made
        return loop.spec, tuple(numba.typeof(a) for a in (loop.spec_marker, *loop.args))

    for keys in ({"policy": "random"}, {"battery.enabled": True}, {"record.transitions": True}):
        assert types(rooms_map, **keys) == types(graph, **keys)
    # the team learner: a grid's entry None (D = 4 fixed), a graph's an array
    grid_team, graph_team = types(rooms_map), types(graph)
    assert grid_team[0] == graph_team[0] == numba_core.SPEC_QLEARNING_TEAM
    assert grid_team != graph_team
