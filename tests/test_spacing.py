"""Walk followers keep their spacing (``docs/model.md``, Strategies, walk followers).

K ``cyclic`` robots on one closed walk of L moves, battery off, collisions avoided: the
worst interval between two visits of a cell (``max_interval``, measured after the robots
have gathered) stays within ``1.1 L/K + 2`` on every map where no dead end is deeper
than ``L/(2K)`` (shipped maps, generated rings and loops), and within the bound stated in
the model on floors of one-wide corridors with deeper dead ends, where robots must meet
head-on. Switching off the spacing rule, or the exchange of plans before a meeting,
breaks the bound on a case. The rule itself is checked step by step on a ring: a robot
that lost steps is waited for, one robot after the other, and the spacing comes back.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mazes
import numpy as np
import pytest

from qpatrol import strategies, world
from qpatrol.config import from_flat
from qpatrol.engines import numpy_loop
from qpatrol.maps import Map, get_map, parse_map, walks
from qpatrol.run import simulate
from qpatrol.strategies import follow

#: the compiled engine where numba is installed
FAST = "numba" if importlib.util.find_spec("numba") else "numpy"
STEPS, WARMUP = 2500, 1000


def dead_end_depth(m: Map, walk: np.ndarray) -> float:
    """How deep the walk goes into a dead end: over the bridges of the map (moves whose
    removal cuts it in two) that the walk crosses both ways, the largest ``(g + 1) / 2``,
    ``g`` the walk steps between the two crossings on the shorter side (a corridor of d
    cells: d). Robots ``L/K`` apart on the walk never face each other in a dead end of
    depth at most ``L/(2K)``."""
    nb = walks._local_neighbors(m, np.arange(m.n_cells))
    bridges = {(int(a), int(b)) for a, b in walks._bridges(nb)}
    bridges |= {(b, a) for a, b in bridges}
    L = walk.size
    crossings: dict[tuple[int, int], list[int]] = {}
    for i, (u, v) in enumerate(zip(walk.tolist(), np.roll(walk, -1).tolist(), strict=True)):
        crossings.setdefault((u, v), []).append(i)
    depth = 0.0
    for (u, v), there in crossings.items():
        if (u, v) not in bridges:
            continue
        for i in there:
            for j in crossings.get((v, u), []):
                g = (j - i) % L
                depth = max(depth, (min(g, L - g) + 1) / 2)
    return depth


def ring_floor() -> str:
    """An 8 x 8 one-wide ring with dead-end corridors of 12, 10 and 4 cells (L = 80)."""
    h = w = 8
    pad = 12
    grid = np.full((h + 2 * pad + 2, w + 2 * pad + 2), "#", dtype="<U1")
    r0 = c0 = pad + 1
    grid[r0, c0 : c0 + w] = grid[r0 + h - 1, c0 : c0 + w] = "."
    grid[r0 : r0 + h, c0] = grid[r0 : r0 + h, c0 + w - 1] = "."
    grid[r0 - 12 : r0, c0 + 3] = "."  # north, 12 deep
    grid[r0 + h : r0 + h + 10, c0 + 5] = "."  # south, 10 deep
    grid[r0 + 3, c0 + w : c0 + w + 4] = "."  # east, 4 deep
    return "; name: ring-floor\n" + "\n".join("".join(r) for r in grid) + "\n"


#: name -> map text (shipped maps by name)
MAPS = {
    "ring": lambda: mazes.corridor_ring(40),
    "ring-spur": lambda: mazes.corridor_ring(40, spur=4),
    "loops": lambda: mazes.random_maze(5, 6, 0, loops=0.2, dead_end_stations=False),
    "loops-1": lambda: mazes.random_maze(5, 6, 1, loops=0.2, dead_end_stations=False),
    "ring-floor": ring_floor,
    "maze-loops": lambda: mazes.random_maze(6, 8, 4, loops=0.15, dead_end_stations=False),
    "tree": lambda: mazes.random_maze(5, 6, 0),
    "comb": lambda: mazes.comb(6, 5),
}


def load(name: str, tmp_path: Path) -> tuple[str, Map]:
    """(config value of ``map``, the map)."""
    if name not in MAPS:
        return name, get_map(name)
    path = tmp_path / f"{name}.txt"
    path.write_text(MAPS[name]())
    return str(path), parse_map(path.read_text())


def worst_interval(
    name: str, k: int, tmp_path: Path, policy: str = "cyclic", engine: str = FAST
) -> tuple:
    """(L, depth, worst max_interval over 2 runs) of K robots, battery off. On the
    compiled engine by default (the engines agree to the bit: ``tests/test_engines.py``
    runs walk followers on a dead-end floor); the rule switched off below is the numpy
    engine's."""
    where, m = load(name, tmp_path)
    cfg = from_flat(
        {
            "map": where,
            "policy": policy,
            "agents": k,
            "runs": 2,
            "steps": STEPS,
            "record.warmup": WARMUP,
            "battery.enabled": False,
            "engine": engine,
        }
    )
    result = simulate(cfg)
    walk = walks.closed_walk(m)
    return walk.size, dead_end_depth(m, walk), max(s["max_interval"] for s in result.summary)


SHALLOW = [
    ("map_a", 2),
    ("map_a", 4),
    ("map_a", 8),
    ("map_b", 4),
    ("map_b", 8),
    ("ring", 2),
    ("ring", 4),
    ("ring", 8),
    ("ring-spur", 2),
    ("ring-spur", 4),
    ("loops", 2),
    ("loops", 4),
    ("loops", 8),
    ("loops-1", 4),
    ("ring-floor", 2),
]


@pytest.mark.parametrize("name, k", SHALLOW)
def test_no_deep_dead_end_worst_interval_within_a_tenth_of_l_over_k(name, k, tmp_path):
    L, depth, worst = worst_interval(name, k, tmp_path)
    assert depth <= L / (2 * k), "the map must have no dead end deeper than L/(2K)"
    assert worst <= 1.1 * L / k + 2, (L, k, worst)


#: Dead-end floors (one-wide corridors, dead ends deeper than L/(2K)) and the bound
#: reached there (docs/model.md): 1.1 L/K + 2 up to 4 robots and with 8 on the ring
#: floor and the maze with loops; 1.5 L/K + 2 with 8 robots crowding a tree of 59 cells
#: and a comb of 41.
DEEP = [
    ("ring-floor", 4, 1.1),
    ("ring-floor", 8, 1.1),
    ("maze-loops", 4, 1.1),
    ("maze-loops", 8, 1.1),
    ("tree", 4, 1.1),
    ("tree", 8, 1.5),
    ("comb", 4, 1.1),
    ("comb", 8, 1.5),
]


@pytest.mark.parametrize("name, k, factor", DEEP)
def test_dead_end_floors_worst_interval_within_the_stated_bound(name, k, factor, tmp_path):
    L, depth, worst = worst_interval(name, k, tmp_path)
    assert depth > L / (2 * k), "the floor must have a dead end deeper than L/(2K)"
    assert worst <= factor * L / k + 2, (L, k, worst)


@pytest.mark.parametrize("name, k", [("loops", 8), ("map_a", 8)])
def test_partition_is_not_slowed_by_the_rule(name, k, tmp_path):
    """A robot alone on its walk (``partition``) never waits: its worst interval is its
    region walk's length (plus the steps a meeting on the way in may cost)."""
    where, m = load(name, tmp_path)
    _, _, worst = worst_interval(name, k, tmp_path, policy="partition")
    lengths = [w.size for w in walks.region_walks(m, walks.partition_regions(m, k))]
    assert worst <= max(lengths) + 1


@pytest.mark.parametrize(
    "switch, name, k",
    [("keep_spacing", "maze-loops", 8), ("exchange_early", "maze-loops", 4)],
)
def test_the_bound_fails_without_the_rules(switch, name, k, tmp_path, monkeypatch):
    """Deliberately broken: without the spacing rule, or without the exchange before a
    meeting, the bound fails on a dead-end floor."""
    L, _, worst = worst_interval(name, k, tmp_path, engine="numpy")
    assert worst <= 1.1 * L / k + 2
    monkeypatch.setattr(follow.WalkFollower, switch, False)
    L, _, worst = worst_interval(name, k, tmp_path, engine="numpy")
    assert worst > 1.1 * L / k + 2, (switch, worst)


# a one-wide ring of 12 cells: walks.closed_walk gives 0 4 6 8 9 10 11 7 5 3 2 1
RING12 = "....\n.##.\n.##.\n....\n"


def test_robots_behind_a_late_robot_wait_for_it_one_after_the_other():
    """Three cyclic robots on the 12-ring, gathered on slots 0, 4, 8 (walk cells 0, 9, 5;
    spacing 4 each). After the first step robot 1's target is set back from index 5 to 3
    (as if pushed back): it walks back to cell 8 and goes on from there. Robot 0, behind
    it, waits on its target until robot 1's target is 4 walk steps ahead again; robot 2,
    behind robot 0, then waits its turn, robot 1 stays clear of it. Within 8 steps every
    target is again 4 steps behind the next, robots 0 and 2 skipped as many advances
    (their lateness is robot 1's), and all advance one cell per step."""
    cfg = from_flat({"agents": 3, "policy": "cyclic", "battery.enabled": False})
    m = parse_map(RING12)
    walk = walks.closed_walk(m)
    p = world.make_params(cfg, m)
    starts = np.array([walk[[0, 4, 8]]])
    s = world.init_state(p, starts)
    strat = strategies.make("cyclic", cfg, m, p, starts)
    assert strat.spacing[0].tolist() == [4, 4, 4]
    u = np.zeros((1, 3, 2))
    numpy_loop.advance(s, p, strat, u)  # gathered: released, all advance
    assert strat.target[0].tolist() == [1, 5, 9]
    strat.target[0, 1] = 3
    moves = []
    for _ in range(8):
        before = strat.target[0].copy()
        out = numpy_loop.advance(s, p, strat, u)
        moves.append(((strat.target[0] - before) % 12).tolist())
        assert (out.blocked_by[0] < 0).all()  # nobody runs into anybody
    gaps = (np.roll(strat.target[0], -1) - strat.target[0]) % 12
    assert gaps.tolist() == [4, 4, 4]
    done = np.array(moves).sum(axis=0)
    assert done[0] == done[2] == done[1] - 2, moves
    assert moves[0][0] == 0 and moves[-1] == [1, 1, 1], moves  # robot 0 waits at once
    for _ in range(12):
        before = strat.target[0].copy()
        out = numpy_loop.advance(s, p, strat, u)
        assert ((strat.target[0] - before) % 12).tolist() == [1, 1, 1]
        assert out.as_asked[0].all()


def test_on_a_tie_the_robot_standing_on_the_slot_is_ahead():
    """Two robots with targets on one index (a robot on a graph's waypoint advances
    without the spacing rule, and may catch up): the one standing on the target cell is
    ahead, whatever the indices, so it never waits for a robot that must pass it to
    reach the slot (with the lower index ahead, three ``learned-tour`` robots on a comb
    froze: one on a dead end's last cell waiting for the one above it, which asked for
    that cell); between two that both stand or both do not, the lower index."""
    m = get_map("map_a")
    cfg = from_flat({"map": "map_a", "policy": "cyclic", "agents": 3, "battery.enabled": False})
    p = world.make_params(cfg, m)
    strat = strategies.make("cyclic", cfg, m, p, np.flatnonzero(p.target)[None, :3])
    L = int(strat.length[0, 0])
    strat.target[0] = [4, 4, 10]
    counted = np.ones((1, 3), dtype=bool)
    on = np.array([[False, True, False]])  # robot 1 stands on the slot, robot 0 does not
    assert strat.gap_ahead(counted, on)[0].tolist() == [0, 6, L - 6]
    # neither stands: the lower index is ahead
    assert strat.gap_ahead(counted, np.zeros((1, 3), dtype=bool))[0].tolist() == [6, 0, L - 6]


def test_the_planned_wait_is_the_longest_walk_two_robots_share(tmp_path, monkeypatch):
    """``stall_bound`` adds a walk follower's planned wait: the length of the longest walk
    two robots or more share at the start. Three ``cyclic`` robots on the 12-ring share
    its walk of 12 moves: the summary's bound is K (D + 2) + 12 = 3 x 8 + 12; with the
    spacing rule off no robot waits for its spacing, and the bound is K (D + 2) alone;
    ``partition`` gives two robots a walk each (nothing shared: 0); ``learned-tour``
    counts its first route, however short the routes it learns later."""
    m = parse_map(RING12)
    path = tmp_path / "ring12.txt"
    path.write_text(RING12)
    flat = {"map": str(path), "agents": 3, "policy": "cyclic", "battery.enabled": False}
    flat |= {"runs": 1, "steps": 50, "engine": "numpy"}
    walk = walks.closed_walk(m)
    assert walk.size == 12
    (row,) = simulate(from_flat(flat)).summary
    assert row["stall_bound"] == 3 * (6 + 2) + 12
    monkeypatch.setattr(follow.WalkFollower, "keep_spacing", False)
    (row,) = simulate(from_flat(flat)).summary
    assert row["stall_bound"] == 3 * (6 + 2)
    monkeypatch.undo()
    cfg = from_flat({**flat, "agents": 2, "policy": "partition"})
    p = world.make_params(cfg, m)
    starts = np.array([walk[[0, 6]]])
    strat = strategies.make("partition", cfg, m, p, starts)
    assert len(set(strat.wid[0].tolist())) == 2 and strat.planned_wait().tolist() == [0]
    cfg = from_flat({**flat, "policy": "learned-tour"})
    p = world.make_params(cfg, m)
    starts = np.array([walk[[0, 4, 8]]])
    strat = strategies.make("learned-tour", cfg, m, p, starts)
    first = int(strat.length[0, 0])
    strat.length[0, 0] = first - 2  # as if a shorter route had been learned
    assert strat.planned_wait().tolist() == [first]
