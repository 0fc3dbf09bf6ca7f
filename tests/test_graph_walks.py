"""Closed walks, bounds and partitions of qpatrol.maps.walks on patrol graphs.

On a graph the walk must visit every target (vertex); it steps on waypoints only as it
travels edges, and an edge nobody needs is never walked. Grid maps keep their walks
to the cell (tests/test_walks.py pins them).
"""

from __future__ import annotations

from collections import deque
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qpatrol.config import from_flat
from qpatrol.maps import parse_map
from qpatrol.maps.walks import (
    closed_walk,
    closed_walk_lower_bound,
    partition_regions,
    region_walks,
    walk_is_closed_cover,
)
from qpatrol.run import simulate


def grid_graph(n: int, moves=None, name: str = "grid") -> str:
    """Graph map text of an n x n grid of vertices (vertex r n + c at column c, row r),
    each edge ``moves(a, b)`` moves long (default 1); agent 0 starts on vertex 0."""
    lines = [f"; name: {name}", "; kind: graph"]
    for r in range(n):
        for c in range(n):
            v = r * n + c
            lines.append(f"v {v} {c} {-r}" + (" start=0" if v == 0 else ""))
    for r in range(n):
        for c in range(n):
            v = r * n + c
            for w in ([v + 1] if c + 1 < n else []) + ([v + n] if r + 1 < n else []):
                lines.append(f"e {v} {w} {moves(v, w) if moves else 1}")
    return "\n".join(lines) + "\n"


def graph(vertices: int, edges: list[tuple[int, int, int]]) -> str:
    """Graph map text: vertices 0..vertices-1 on a line, the edges (a, b, moves)."""
    lines = ["; kind: graph"] + [f"v {v} {v} 0" for v in range(vertices)]
    return "\n".join(lines + [f"e {a} {b} {k}" for a, b, k in edges]) + "\n"


def shortest_closed_walk_through_targets(m) -> int:
    """Exact optimum by BFS over (cell, targets visited) from the first target."""
    targets = [int(c) for c in np.flatnonzero(m.target)]
    bit = {c: 1 << i for i, c in enumerate(targets)}
    full = (1 << len(targets)) - 1
    start = (targets[0], bit[targets[0]])
    seen = {start}
    queue = deque([(*start, 0)])
    while queue:
        cell, mask, d = queue.popleft()
        for nb in m.neighbors[cell]:
            nb = int(nb)
            if nb < 0:
                continue
            key = (nb, mask | bit.get(nb, 0))
            if key == (targets[0], full):
                return d + 1
            if key not in seen:
                seen.add(key)
                queue.append((*key, d + 1))
    raise AssertionError("graph not connected")


def travels_edges(m, walk: np.ndarray) -> bool:
    """True if the closed walk never turns back on a waypoint (it only travels edges
    through them, turning at vertices)."""
    prev, nxt = np.roll(walk, 1), np.roll(walk, -1)
    on_waypoint = ~m.target[walk]
    return bool((prev[on_waypoint] != nxt[on_waypoint]).all())


# --- the acceptance case: patrolling_sim's 5 x 5 grid graph ------------------------------

# patrolling_sim's grid.graph: 5 x 5 vertices, every edge the same length (one move).
# The graph is bipartite by (row + col) % 2, with 13 vertices of the corners' colour and
# 12 of the other. A closed walk alternates colours, so its L moves put L / 2 positions
# on each colour; the 13 corner-colour vertices each need a position of their own:
# L >= 2 x 13 = 26. GRID5_WALK reaches it: a Hamiltonian cycle of the 24 vertices other
# than corner 0, entered from 0 at vertex 1 and left back to 0 from vertex 1 (vertex 1
# is visited twice, 26 positions in all). So the shortest closed walk through all 25
# vertices has exactly 26 moves.
GRID5_OPTIMUM = 26
GRID5_WALK = [0, 1, 2, 3, 4, 9, 14, 19, 24, 23, 18, 13, 8, 7, 12, 17, 22, 21, 20, 15, 16]
GRID5_WALK += [11, 10, 5, 6, 1]


def test_five_by_five_grid_graph_walk_is_the_proven_optimum():
    m = parse_map(grid_graph(5))
    assert m.is_graph and m.n_cells == m.n_targets == 25
    # the proof's two halves: the colour classes, and a closed walk of 26
    corner_colour = np.array([(v // 5 + v % 5) % 2 == 0 for v in range(25)])
    assert corner_colour.sum() == 13
    assert len(GRID5_WALK) == GRID5_OPTIMUM == 2 * 13
    assert walk_is_closed_cover(m, np.array(GRID5_WALK))
    # the bound qpatrol proves and the walk it finds both equal the optimum
    assert closed_walk_lower_bound(m) == GRID5_OPTIMUM
    walk = closed_walk(m)
    assert walk_is_closed_cover(m, walk)
    assert len(walk) == GRID5_OPTIMUM


def test_one_cyclic_robot_on_the_five_by_five_grid_graph(tmp_path: Path):
    """One ``cyclic`` robot, numpy engine, battery off: after a warm-up of a few laps
    every vertex is revisited within 26 moves (measured: max interval 26, worst
    idleness 25). Every cell of this graph is a vertex (unit edges), so the measures
    over all cells are the measures over the vertices."""
    path = tmp_path / "grid5.txt"
    path.write_text(grid_graph(5, name="grid5"))
    flat = {"map": str(path), "agents": 1, "policy": "cyclic", "battery.enabled": False}
    flat.update({"steps": 400, "record.warmup": 100, "runs": 2, "engine": "numpy"})
    res = simulate(from_flat(flat))
    assert res.map.is_graph and res.map.n_cells == res.map.n_targets
    assert res.strategy.describe()["walk_length"] == GRID5_OPTIMUM
    assert res.strategy.describe()["walk_lower_bound"] == GRID5_OPTIMUM
    for row in res.summary:
        assert row["coverage"] == 1.0
        assert row["max_interval"] <= GRID5_OPTIMUM
        assert row["worst_idleness"] <= GRID5_OPTIMUM


# --- graphs with waypoints ----------------------------------------------------------------


def waypoint_grid(n: int, seed: int) -> str:
    """An n x n grid graph whose edges take 1-3 moves, drawn with ``seed``."""
    rng = np.random.default_rng(seed)
    return grid_graph(n, lambda a, b: int(rng.integers(1, 4)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_walk_through_waypoints_visits_every_vertex_along_edges(seed):
    m = parse_map(waypoint_grid(4, seed))
    assert m.n_cells > m.n_targets  # there are waypoints
    walk = closed_walk(m)
    assert walk[0] == 0  # starts on the lowest vertex
    assert set(np.flatnonzero(m.target).tolist()) <= set(walk.tolist())  # every vertex
    nxt = np.roll(walk, -1)  # closed: the last step leads back to walk[0]
    assert (m.neighbors[walk] == nxt[:, None]).any(axis=1).all()  # every step one move
    assert travels_edges(m, walk)
    assert walk_is_closed_cover(m, walk)
    assert closed_walk_lower_bound(m) <= len(walk)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 3), extra=st.integers(0, 2))
def test_graph_walk_and_bound_against_brute_force(seed, n, extra):
    """Small grid graphs with edges of 1-3 moves and a few extra long diagonals: the
    bound is at most the exact optimum, the walk reaches it."""
    rng = np.random.default_rng(seed)
    text = grid_graph(n, lambda a, b: int(rng.integers(1, 4)))
    squares = rng.choice((n - 1) ** 2, min(extra, (n - 1) ** 2), replace=False)
    for r, c in (divmod(int(q), n - 1) for q in squares):  # a diagonal, 2-4 moves
        text += f"e {r * n + c} {(r + 1) * n + c + 1} {int(rng.integers(2, 5))}\n"
    m = parse_map(text)
    opt = shortest_closed_walk_through_targets(m)
    walk = closed_walk(m)
    assert walk_is_closed_cover(m, walk) and travels_edges(m, walk)
    assert closed_walk_lower_bound(m) <= opt == len(walk)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), v=st.integers(3, 8), extra=st.integers(0, 3))
def test_sparse_graph_walk_and_bound_against_brute_force(seed, v, extra):
    """Random trees of 3-8 vertices with edges of 1-3 moves, plus a few extra edges
    (bridges, dead ends and cycles of waypoints): the bound is at most the exact
    optimum, the walk reaches it."""
    rng = np.random.default_rng(seed)
    edges = {(int(rng.integers(0, b)), b): int(rng.integers(1, 4)) for b in range(1, v)}
    for _ in range(extra):
        a, b = sorted(int(x) for x in rng.choice(v, 2, replace=False))
        edges.setdefault((a, b), int(rng.integers(1, 4)))
    m = parse_map(graph(v, [(a, b, k) for (a, b), k in edges.items()]))
    opt = shortest_closed_walk_through_targets(m)
    walk = closed_walk(m)
    assert walk_is_closed_cover(m, walk) and travels_edges(m, walk)
    assert closed_walk_lower_bound(m) <= opt == len(walk)


def test_bridges_of_long_edges_count_twice():
    # two triangles of unit edges (0 1 2 and 3 4 5) joined by a 3-move edge 2 - 3: the
    # bridge's 3 moves are walked both ways, each triangle once round: 3 + 3 + 2 x 3
    m = parse_map(
        graph(6, [(0, 1, 1), (1, 2, 1), (2, 0, 1), (2, 3, 3)] + [(3, 4, 1), (4, 5, 1), (5, 3, 1)])
    )
    assert len(closed_walk(m)) == 12 == closed_walk_lower_bound(m)
    # a star of three 2-move edges and one 4-move edge: twice every move, 2 x 10
    m = parse_map(graph(5, [(0, 1, 2), (0, 2, 2), (0, 3, 2), (0, 4, 4)]))
    assert len(closed_walk(m)) == 20 == closed_walk_lower_bound(m)


# a tree of 17 vertices and 29 moves on which the Held-Karp bound alone stays at 56
TREE17 = [(0, 1, 3), (0, 2, 2), (0, 3, 2), (1, 4, 3), (0, 5, 1), (0, 6, 1), (4, 7, 2)]
TREE17 += [(7, 8, 2), (3, 9, 1), (7, 10, 2), (2, 11, 1), (5, 12, 1), (12, 13, 2), (0, 14, 1)]
TREE17 += [(4, 15, 2), (13, 16, 3)]


def test_a_tree_of_long_edges_is_bounded_exactly():
    """Every edge of a tree is a bridge between targets: the bound splits over them and
    is exact, twice the moves (the Held-Karp bound of the tour over the vertices alone is
    56). The same in a region whose cells include a dead-end part of an edge to a vertex
    outside it: those waypoints are dropped before the bridges are counted."""
    m = parse_map(graph(17, TREE17))
    assert len(closed_walk(m)) == 58 == closed_walk_lower_bound(m) == 2 * 29
    m = parse_map(graph(18, [*TREE17, (16, 17, 4)]))  # its waypoints: 31 32 33 from 16
    assert m.n_cells == 34
    cells = np.array([c for c in range(33) if c != 17])  # without 17 and 33: 31-32 dead end
    walk = closed_walk(m, cells)
    assert walk_is_closed_cover(m, walk, cells) and not set(walk.tolist()) & {31, 32}
    assert len(walk) == 58 == closed_walk_lower_bound(m, cells)


def test_an_edge_nobody_needs_is_never_walked():
    # a path 0 - 1 - 2 of unit edges, and a 6-move edge 0 - 2 (5 waypoints): the walk
    # goes 0 1 2 1 (4 moves), not round the 8-move cycle, and enters no waypoint
    m = parse_map(graph(3, [(0, 1, 1), (1, 2, 1), (0, 2, 6)]))
    assert m.n_cells == 8
    walk = closed_walk(m)
    assert walk.tolist() == [0, 1, 2, 1]
    assert closed_walk_lower_bound(m) == 4
    # the same with a 2-move edge 0 - 2: the 4-move cycle is as short, both are fine
    m = parse_map(graph(3, [(0, 1, 1), (1, 2, 1), (0, 2, 2)]))
    assert len(closed_walk(m)) == 4 == closed_walk_lower_bound(m)


def test_a_long_edge_is_walked_there_and_back():
    # two vertices joined by a 4-move edge: the walk is the edge out and back
    m = parse_map(graph(2, [(0, 1, 4)]))
    walk = closed_walk(m)
    assert walk.tolist() == [0, 2, 3, 4, 1, 4, 3, 2]
    assert closed_walk_lower_bound(m) == 8


def test_odd_cycles_are_not_rounded_to_even():
    # a triangle and a pentagon of unit edges: not bipartite, so the walk round the
    # cycle (odd) is the optimum and the bound may not round it up to even
    for k in (3, 5):
        m = parse_map(graph(k, [(v, (v + 1) % k, 1) for v in range(k)]))
        walk = closed_walk(m)
        assert len(walk) == k == closed_walk_lower_bound(m)
        assert walk_is_closed_cover(m, walk)
    # a triangle whose edges take 2, 1 and 3 moves: a 6-move cycle (even, not bipartite)
    m = parse_map(graph(3, [(0, 1, 2), (1, 2, 1), (2, 0, 3)]))
    assert len(closed_walk(m)) == 6 == closed_walk_lower_bound(m)


def test_one_vertex_regions_and_errors():
    m = parse_map(graph(2, [(0, 1, 3)]))  # cells: vertices 0 1, waypoints 2 3
    # one target: out along its edge to the vertex at the other end and back (changed
    # on purpose: standing on it would never visit it again; robots turn at vertices)
    assert closed_walk(m, np.array([0, 2])).tolist() == [0, 2, 3, 1, 3, 2]
    assert closed_walk_lower_bound(m, np.array([0, 2])) == 6
    assert walk_is_closed_cover(m, np.array([0, 2, 3, 1, 3, 2]), np.array([0, 2]))
    assert not walk_is_closed_cover(m, np.array([0]), np.array([0, 2]))
    assert not walk_is_closed_cover(m, np.array([0, 2]), np.array([0, 2]))  # turns in the edge
    assert not walk_is_closed_cover(m, np.array([2]), np.array([0, 2]))  # 0 not visited
    with pytest.raises(ValueError, match="no target"):
        closed_walk(m, np.array([2, 3]))
    with pytest.raises(ValueError, match="not form a connected region"):
        closed_walk(m, np.array([0, 1]))
    with pytest.raises(ValueError, match="between 1 and the 2 targets"):
        partition_regions(m, 3)


def test_walks_of_two_graphs_are_not_confused():
    """Walks are cached by map: two graphs (no grid text, both with kind graph) must not
    share their cache entries."""
    a = parse_map(graph(3, [(0, 1, 1), (1, 2, 1)]))
    b = parse_map(graph(3, [(0, 1, 1), (1, 2, 1), (2, 0, 1)]))
    assert closed_walk(a).tolist() == [0, 1, 2, 1]
    assert closed_walk(b).tolist() == [0, 1, 2]
    assert closed_walk_lower_bound(a) == 4 and closed_walk_lower_bound(b) == 3


# --- partition on a graph -----------------------------------------------------------------


@pytest.mark.parametrize("k", [1, 2, 3, 5, 16])
def test_partition_of_a_graph(k):
    m = parse_map(waypoint_grid(4, 7))
    labels = partition_regions(m, k)
    assert labels.shape == (m.n_cells,)
    assert set(labels.tolist()) == set(range(k))
    walks = region_walks(m, labels)
    covered = []
    for r, walk in enumerate(walks):
        cells = np.flatnonzero(labels == r)
        assert m.target[cells].any()  # a region holds a target
        assert walk_is_closed_cover(m, walk, cells)  # connected, its walk stays inside
        assert travels_edges(m, walk)
        covered += [int(c) for c in walk if m.target[c]]
    assert sorted(set(covered)) == list(range(m.n_targets))  # every vertex patrolled
    # a region is its vertices plus waypoints: an edge inside it whole, an edge to another
    # region split, each waypoint with the nearer end (waypoints numbered after the
    # vertices, edge by edge in file order, from a's end)
    first = m.n_targets
    for a, b, moves in m.edges.tolist():
        for j in range(1, moves):
            near = a if labels[a] == labels[b] or 2 * j <= moves else b
            assert labels[first + j - 1] == labels[near]
        first += moves - 1
    whole = closed_walk_lower_bound(m)
    # measured: longest region walk / (whole-map bound / k) = 1.0, 1.1, 1.35, 1.61
    if k < 16:
        assert max(len(w) for w in walks) <= 2.0 * whole / k
    else:
        # one vertex each, out along its shortest edge and back (changed on purpose:
        # standing on it would never visit it again)
        assert all(m.target[w].sum() == 2 for w in walks)
        assert [len(w) for w in walks] == [2 * shortest_edge(m, int(w[0])) for w in walks]


# --- the dot-eating walk (qpatrol.maps.tours) on a graph ---------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_dot_walk_on_a_graph_eats_every_vertex_dot_optimally(seed):
    """Dots sit on vertices only; the walk from vertex 0 eats them all along the edges,
    as short as the exact search over (cell, dots eaten)."""
    from test_tours import exact_optimum

    from qpatrol.maps.tours import dot_walk_lower_bound, dot_walk_tour, walk_is_valid

    m = parse_map(waypoint_grid(3, seed))
    assert (m.dot_kind[~m.target] == 0).all() and (m.dot_kind[m.target] > 0).all()
    moves, walk = dot_walk_tour(m, 0)
    assert walk_is_valid(m, 0, walk)
    assert dot_walk_lower_bound(m, 0) <= exact_optimum(m, 0) == moves


def shortest_edge(m, v: int) -> int:
    """Moves of vertex v's shortest edge."""
    return int(min(n for a, b, n in m.edges.tolist() if v in (a, b)))
