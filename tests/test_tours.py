"""The dot-eating walk: hand-solved maps, an exact brute force on random tiny maps."""

from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qpatrol.maps import get_map, parse_map
from qpatrol.maps.tours import dot_walk_lower_bound, dot_walk_tour, terminal_problem, walk_is_valid


def exact_optimum(m, start):
    """Shortest walk eating every dot, by BFS over (cell, dots eaten) states."""
    dots = [int(c) for c in np.flatnonzero(m.dot_kind > 0)]
    bit = {c: 1 << i for i, c in enumerate(dots)}
    full = (1 << len(dots)) - 1
    seen = {(start, 0)}
    queue = deque([(start, 0, 0)])
    while queue:
        cell, mask, d = queue.popleft()
        if mask == full:
            return d
        for nb in m.neighbors[cell]:
            if nb < 0:
                continue
            nb = int(nb)
            key = (nb, mask | bit.get(nb, 0))
            if key not in seen:
                seen.add(key)
                queue.append((*key, d + 1))
    raise AssertionError("unreachable dots")


def check(m, start, expect=None):
    moves, walk = dot_walk_tour(m, start)
    lb = dot_walk_lower_bound(m, start)
    assert walk_is_valid(m, start, walk)
    assert moves == len(walk) - 1
    opt = exact_optimum(m, start)
    assert lb <= opt <= moves
    if expect is not None:
        assert opt == expect
        assert moves == expect
    return lb, opt, moves


def test_corridor_from_the_end():
    # cells 0..3, start 0 holds a dot: 0->1->0 eats the start dot, then 1->2->3: 5 moves
    m = parse_map("######\n#0...#\n######")
    assert check(m, 0, expect=5)[0] >= 4


def test_corridor_from_the_middle():
    # start 1: 1->0->1->2->3 eats everything in 4 moves (= number of dots, the bound)
    m = parse_map("######\n#.0..#\n######")
    assert check(m, 1, expect=4) == (4, 4, 4)


def test_corridor_without_start_dot():
    # '-' start cell: no dot there; 3 dots to the east: 3 moves
    m = parse_map("######\n#-...#\n######")
    assert check(m, 0, expect=3) == (3, 3, 3)


def test_t_junction():
    # 0 1 2 on top, 3 and 4 below 1; start 0. Of the three dead ends to finish (the
    # start dot, 2 and 4) two must be left again, one extra move each: 5 dots + 2 = 7.
    m = parse_map("#####\n#0..#\n##.##\n##.##\n#####")
    check(m, 0, expect=7)


def test_loop():
    # a 2x3 ring of 6 dots: round the ring back to the start, 6 moves
    m = parse_map("#####\n#0..#\n#...#\n#####")
    check(m, 0, expect=6)


def test_terminal_problem_start_dot_costs_two():
    m = parse_map("######\n#0...#\n######")
    cells, D = terminal_problem(m, 0)
    assert cells.tolist() == [0, 0, 1, 2, 3]
    assert D[0, 1] == 2 and D[1, 0] == 2 and D[0, 4] == 3


def random_map(rng, rows=5, cols=6, p_wall=0.3):
    """A random connected maze with 3..10 dots (walls removed until connected)."""
    while True:
        g = np.where(rng.random((rows, cols)) < p_wall, "#", ".")
        g[rng.random((rows, cols)) < 0.25] = "-"
        g[g == "-"] = np.where(rng.random((g == "-").sum()) < 0.5, "-", "H")
        lines = ["#" * (cols + 2)] + ["#" + "".join(r) + "#" for r in g] + ["#" * (cols + 2)]
        text = "\n".join(lines)
        try:
            m = parse_map(text)
        except ValueError:
            continue
        n_dots = int((m.dot_kind > 0).sum())
        if m.n_cells >= 2 and 3 <= n_dots <= 10:
            return m


@settings(max_examples=25)
@given(seed=st.integers(0, 2**32 - 1))
def test_random_tiny_maps(seed):
    rng = np.random.default_rng(seed)
    m = random_map(rng)
    start = int(rng.integers(m.n_cells))
    check(m, start)


def test_map_a_bounds_and_determinism():
    m = get_map("map_a")
    start = int(m.starts[0])
    moves, walk = dot_walk_tour(m, start, kicks=20)
    assert walk_is_valid(m, start, walk)
    assert dot_walk_tour(m, start, kicks=20) == (moves, walk)
    lb = dot_walk_lower_bound(m, start, upper=moves, iterations=100)
    dots = int((m.dot_kind > 0).sum())
    assert dots <= lb <= moves


def test_bad_start():
    m = parse_map("######\n#0...#\n######")
    with pytest.raises(ValueError):
        dot_walk_tour(m, 99)


def test_dot_walk_on_map_a_is_pinned():
    """The dot-eating walk of map_a from agent 0's start, cell by cell, as computed at
    commit c12d418 (before the walk modules became port-generic)."""
    import hashlib

    m = get_map("map_a")
    moves, walk = dot_walk_tour(m, int(m.starts[0]))
    digest = hashlib.sha256(np.asarray(walk, dtype=np.int64).tobytes()).hexdigest()[:16]
    assert (moves, digest) == (214, "00e1fbca5f325831")
