"""The walk and bound of regions above SEARCH_TARGETS whose cells are all targets
(qpatrol.maps.walks: the corridor walk, the corridor bound, their T-join parts), on
hand-solved maps, against brute force on tiny ones, and as properties of random mazes.
SEARCH_TARGETS is lowered to 0 where a small map must take the large-region path."""

from __future__ import annotations

import itertools
from collections import deque
from contextlib import contextmanager

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mazes import random_maze, reachable

from qpatrol.maps import parse_map, walks

SCALE = 1 << walks._PACKING_ROUNDS

THETA = """\
#######
#.....#
#.###.#
#.....#
#.###.#
#.....#
#######
"""  # junctions (3, 1) and (3, 5) joined by corridors of 7, 3 and 7 cells: 19 cells
# Both junctions have three corridors: odd. A closed walk runs each corridor an odd
# number of times (k + 1 moves at least) or an even number (then it walks in and back
# from the ends, 2 k moves at least, no fewer while it reaches every corridor cell), and
# the odd ones must be even in number at each junction: one corridor is walked in and
# back. Cheapest: the middle one, 2 x 3 = 6 instead of 4; the others once, 8 + 8. So
# 22, two above the colour count (10 cells of one colour: 20).

TWO_RINGS = """\
###########
#...###...#
#.#.....#.#
#...###...#
###########
"""  # two rings of 8 cells joined by a 3-cell corridor (4 bridges): 8 + 8 + 2 x 4 = 24

LADDER = """\
#######
#.....#
#.#.#.#
#.....#
#######
"""  # junctions (1, 3) and (3, 3) joined by corridors of 5, 1 and 5 cells: 13 cells.
# The 1-cell rung is walked in and back at no extra cost (2 = 1 + 1): 6 + 6 + 2 = 14.


def _clear() -> None:
    walks._walk_cached.cache_clear()
    walks._bound_cached.cache_clear()


@contextmanager
def every_region_large():
    """Every region takes the large-region path (SEARCH_TARGETS lowered to 0)."""
    old = walks.SEARCH_TARGETS
    walks.SEARCH_TARGETS = 0
    _clear()
    try:
        yield
    finally:
        walks.SEARCH_TARGETS = old
        _clear()


def large(m):
    """``(walk, bound, methods)`` of the whole map on the large-region path."""
    with every_region_large():
        return (
            walks.closed_walk(m),
            walks.closed_walk_lower_bound(m),
            walks.closed_walk_methods(m),
        )


def corridor_walk(m) -> tuple[np.ndarray, int]:
    """The corridor walk of the whole map (not the nearest-neighbour one, whichever is
    shorter), and the length its parts add up to."""
    cells = np.arange(m.n_cells)
    nb = walks._local_neighbors(m, cells)
    back = np.where(nb >= 0, m.back, -1)
    c = walks._Corridors(nb, back)
    walk = np.array(walks._corridor_walk(nb.tolist(), back.tolist(), c, 0), dtype=np.int64)
    parts = 2 * len(c.bridges) + sum(len(r) for r in c.rings)
    return walk, parts + c.cost(walks._corridor_parities(c))


def shortest_closed_cover(m) -> int:
    """Exact optimum by BFS over (cell, cells visited) from cell 0."""
    full = (1 << m.n_cells) - 1
    seen = {(0, 1)}
    queue = deque([(0, 1, 0)])
    while queue:
        cell, mask, d = queue.popleft()
        for nb in m.neighbors[cell].tolist():
            if nb < 0:
                continue
            key = (nb, mask | 1 << nb)
            if key == (0, full):
                return d + 1
            if key not in seen:
                seen.add(key)
                queue.append((*key, d + 1))
    raise AssertionError("map not connected")


def blob(rows: int, cols: int, seed: int, walls: float) -> str:
    """A random grid of open squares and walls, kept to the squares joined to the first."""
    rng = np.random.default_rng(seed)
    grid = np.where(rng.random((rows, cols)) < walls, "#", ".")
    grid[0, 0] = "."
    grid[~reachable(grid)] = "#"
    return "\n".join("".join(r) for r in grid) + "\n"


# --- hand-solved maps --------------------------------------------------------------


def test_theta_walks_the_middle_corridor_in_and_back():
    m = parse_map(THETA)
    cells = np.arange(m.n_cells)
    nb = walks._local_neighbors(m, cells)
    c = walks._Corridors(nb, np.where(nb >= 0, m.back, -1))
    assert (len(c.bridges), len(c.rings), sorted(c.k)) == (0, 0, [3, 7, 7])
    assert walks._corridor_bounds(c) == {0: 22}
    assert walks._parity_bound(m, cells, nb) == 20
    walk, bound, methods = large(m)
    assert walks.walk_is_closed_cover(m, walk)
    assert len(walk) == bound == 22  # the bound is met: the optimum
    assert corridor_walk(m)[0].size == 22
    assert "corridor walk" in methods["walk_method"]
    assert "corridor parities" in methods["walk_lower_bound_method"]


def test_rings_and_bridges():
    m = parse_map(TWO_RINGS)
    nb = walks._local_neighbors(m, np.arange(m.n_cells))
    c = walks._Corridors(nb, np.where(nb >= 0, m.back, -1))
    assert (len(c.bridges), sorted(len(r) for r in c.rings), c.k) == (4, [8, 8], [])
    walk, bound, _ = large(m)
    assert walks.walk_is_closed_cover(m, walk)
    assert len(walk) == bound == 24


def test_ladder_rung_costs_nothing_extra():
    m = parse_map(LADDER)
    walk, bound, _ = large(m)
    assert walks.walk_is_closed_cover(m, walk)
    assert len(walk) == bound == 14
    assert corridor_walk(m)[0].size == 14


def test_corridor_bound_lifts_held_karp():
    # Held-Karp's bound on this maze is 30; the corridor walk and bound meet at 32, the
    # optimum (checked by brute force)
    m = parse_map(random_maze(3, 4, 3, 0.2, 1, False))
    assert walks.closed_walk_lower_bound(m) == 30
    walk, bound, _ = large(m)
    assert len(walk) == bound == 32 == shortest_closed_cover(m)


@pytest.mark.parametrize("seed", [3, 4, 10])
def test_balls_meet_the_optimum_on_small_mazes(seed):
    # 3 x 4 mazes whose odd junctions are corridors apart: the balls round them add 2
    # moves, and the bound meets the walk and the brute-force optimum
    m = parse_map(random_maze(3, 4, seed, 0.3, 1, False))
    cells = np.arange(m.n_cells)
    nb = walks._local_neighbors(m, cells)
    c = walks._Corridors(nb, np.where(nb >= 0, m.back, -1))
    junctions, ea, eb, odd = c.junction_graph()
    weight, odd = c.base_parities(ea, eb, odd)
    piece = [c.label[v] for v in junctions]
    assert sum(walks._ball_packing(len(junctions), ea, eb, weight, odd, piece).values()) > 0
    walk, bound, _ = large(m)
    assert len(walk) == bound == shortest_closed_cover(m)


def test_open_room_walk_is_a_snake():
    # every move joins two junctions (k = 0): the spanning tree is a path, the walk the
    # optimum, once round the room
    m = parse_map("\n".join(["#" * 8] + ["#" + "." * 6 + "#"] * 6 + ["#" * 8]) + "\n")
    walk, length = corridor_walk(m)
    assert walks.walk_is_closed_cover(m, walk)
    assert walk.size == length == 36


def test_t_join_and_packing_by_hand():
    # a path 0 - 1 - 2 - 3 of weights 1, 10, 1, every node odd: the two end edges
    odd4 = [True] * 4
    assert walks._t_join(4, [0, 1, 2], [1, 2, 3], [1, 10, 1], odd4) == [True, False, True]
    assert walks._ball_packing(4, [0, 1, 2], [1, 2, 3], [1, 10, 1], odd4, [0] * 4) == {0: 2 * SCALE}
    # one edge of weight 4: radii 2 and 2
    assert walks._ball_packing(2, [0], [1], [4], [True, True], [7, 7]) == {7: 4 * SCALE}
    # a weight-0 edge merges 0 and 1 (odd together), 3 moves from odd node 2
    assert walks._t_join(3, [0, 1], [1, 2], [0, 3], [True, False, True]) == [True, True]
    assert walks._ball_packing(3, [0, 1], [1, 2], [0, 3], [True, False, True], [0] * 3) == {
        0: 3 * SCALE
    }
    # both odd nodes merged: nothing to pair
    assert walks._ball_packing(3, [0, 1], [1, 2], [0, 3], [True, True, False], [0] * 3) == {}
    # a star of four odd leaves round an even centre: every edge, balls of radius 1
    star = ([0, 0, 0, 0], [1, 2, 3, 4], [1, 1, 1, 1], [False] + [True] * 4)
    assert walks._t_join(5, *star) == [True] * 4
    assert walks._ball_packing(5, *star, [0] * 5) == {0: 4 * SCALE}


# --- brute force and properties ----------------------------------------------------


@settings(max_examples=40)
@given(
    n=st.integers(2, 7),
    edges=st.lists(
        st.tuples(st.integers(0, 6), st.integers(0, 6), st.integers(0, 5)), min_size=1, max_size=9
    ),
    odd_bits=st.integers(0, 127),
)
def test_t_join_and_packing_against_brute_force(n, edges, odd_bits):
    """On small graphs: the T-join evens out exactly the odd nodes, and the packing bound
    of each piece is at most the lightest T-join there (every subset of edges tried)."""
    edges = [(a % n, b % n, w) for a, b, w in edges]
    ea, eb, w = (list(x) for x in zip(*edges, strict=True))
    piece = _pieces(n, ea, eb)
    odd = [bool(odd_bits >> v & 1) for v in range(n)]
    for p in set(piece):  # an even number of odd nodes in every piece
        members = [v for v in range(n) if piece[v] == p and odd[v]]
        if len(members) % 2:
            odd[members[0]] = False
    join = walks._t_join(n, ea, eb, w, odd)
    degree = [0] * n
    for i, used in enumerate(join):
        if used and ea[i] != eb[i]:
            degree[ea[i]] += 1
            degree[eb[i]] += 1
    assert [d % 2 == 1 for d in degree] == odd
    best: dict[int, int] = {}
    for subset in itertools.product([False, True], repeat=len(edges)):
        deg = [0] * n
        for i, used in enumerate(subset):
            if used and ea[i] != eb[i]:
                deg[ea[i]] += 1
                deg[eb[i]] += 1
        if [d % 2 == 1 for d in deg] == odd:
            for p in set(piece):
                cost = sum(w[i] for i in range(len(edges)) if subset[i] and piece[ea[i]] == p)
                best[p] = min(best.get(p, cost), cost)
    for p, r in walks._ball_packing(n, ea, eb, w, odd, piece).items():
        assert r <= best[p] * SCALE


def _pieces(n: int, ea: list[int], eb: list[int]) -> list[int]:
    parent = list(range(n))
    for a, b in zip(ea, eb, strict=True):
        parent[walks._root(parent, a)] = walks._root(parent, b)
    return [walks._root(parent, v) for v in range(n)]


@settings(max_examples=30)
@given(
    shape=st.sampled_from([(2, 2), (2, 3), (3, 2), (3, 3), (3, 4), (4, 3)]),
    seed=st.integers(0, 2**16),
    walls=st.sampled_from([0.0, 0.15, 0.3]),
)
def test_bound_is_at_most_the_optimum_on_tiny_grids(shape, seed, walls):
    """Open squares and walls (rooms, k = 0 moves) and tiny mazes (corridors): the
    large-region bound <= the brute-force optimum <= the large-region walk."""
    m = parse_map(blob(*shape, seed, walls))
    if m.n_cells < 3:
        return
    opt = shortest_closed_cover(m)
    walk, bound, _ = large(m)
    assert walks.walk_is_closed_cover(m, walk)
    assert bound <= opt <= len(walk)
    maze = parse_map(random_maze(2, 3, seed, walls * 3, 1, False))
    walk, bound, _ = large(maze)
    assert bound <= shortest_closed_cover(maze) <= len(walk)


@settings(max_examples=25)
@given(
    rows=st.integers(2, 9),
    cols=st.integers(2, 9),
    seed=st.integers(0, 2**16),
    loops=st.sampled_from([0.0, 0.1, 0.3, 0.6, 1.0]),
    room=st.booleans(),
)
def test_corridor_walk_is_a_closed_cover_above_the_bound(rows, cols, seed, loops, room):
    """On random mazes (and open rooms cut by walls): the corridor walk visits every cell
    and closes, its length is what its parts add up to, and the bound is at most the walk
    taken (the shorter of it and the nearest-neighbour walk) and at least the counting
    bound."""
    text = blob(rows, cols, seed, loops / 2) if room else random_maze(rows, cols, seed, loops)
    m = parse_map(text)
    if m.n_cells < 3:
        return
    walk, length = corridor_walk(m)
    assert walks.walk_is_closed_cover(m, walk)
    assert walk.size == length
    taken, bound, _ = large(m)
    assert walks.walk_is_closed_cover(m, taken)
    assert taken.size == min(walk.size, taken.size)
    cells = np.arange(m.n_cells)
    assert walks._parity_bound(m, cells, walks._local_neighbors(m, cells)) <= bound
    assert bound <= taken.size
