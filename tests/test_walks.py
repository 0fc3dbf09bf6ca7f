"""Closed covering walks, their lower bound and balanced partitions (qpatrol.maps.walks)."""

from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mazes import reachable

from qpatrol.maps import bfs, get_map, parse_map, walks
from qpatrol.maps.walks import (
    closed_walk,
    closed_walk_lower_bound,
    partition_regions,
    region_walks,
    walk_is_closed_cover,
)

RING = """\
#######
#.....#
#.###.#
#.###.#
#.....#
#######
"""  # a 1-wide rectangular loop of 14 cells

T_SHAPE = """\
#######
#.....#
###.###
###.###
###.###
#######
"""  # 5 cells across, 3 down from the middle: a tree of 8 cells

DUMBBELL = """\
#########
#..###..#
#.......#
#########
"""  # two 2x2 blocks (4-cycles) joined by a 3-cell corridor: 4 bridges

ROOM = """\
#####
#...#
#...#
#...#
#####
"""  # an open 3x3 room: 5 cells of one colour, 4 of the other


def corridor(n: int) -> str:
    return "#" * (n + 2) + "\n#" + "." * n + "#\n" + "#" * (n + 2) + "\n"


def check(m, cells=None, expect=None):
    """Walk and bound of a region: valid, bound <= walk, and both == expect if given."""
    walk = closed_walk(m, cells)
    bound = closed_walk_lower_bound(m, cells)
    assert walk_is_closed_cover(m, walk, cells)
    assert bound <= len(walk)
    if expect is not None:
        assert len(walk) == expect
        assert bound == expect
    return walk, bound


def region_is_connected(m, cells) -> bool:
    inside = np.zeros(m.n_cells, dtype=bool)
    inside[cells] = True
    nb = np.where(inside[np.maximum(m.neighbors, 0)] & (m.neighbors >= 0), m.neighbors, -1)
    return bool((bfs(nb, int(cells[0]))[cells] >= 0).all())


def shortest_closed_cover(m, cells) -> int:
    """Exact optimum by BFS over (cell, cells visited) from the region's first cell."""
    cells = [int(c) for c in cells]
    bit = {c: 1 << i for i, c in enumerate(cells)}
    full = (1 << len(cells)) - 1
    start = (cells[0], bit[cells[0]])
    seen = {start}
    queue = deque([(*start, 0)])
    while queue:
        cell, mask, d = queue.popleft()
        for nb in m.neighbors[cell]:
            nb = int(nb)
            if nb not in bit:
                continue
            key = (nb, mask | bit[nb])
            if key == (cells[0], full):
                return d + 1
            if key not in seen:
                seen.add(key)
                queue.append((*key, d + 1))
    raise AssertionError("region not connected")


# --- walks and bounds on hand-solved maps ------------------------------------------


def test_ring_walk_and_bound_are_its_length():
    m = parse_map(RING)
    walk, _ = check(m, expect=14)
    assert sorted(walk.tolist()) == list(range(14))  # each cell once


@pytest.mark.parametrize("n", [3, 4, 7, 12])
def test_corridor_is_walked_there_and_back(n):
    m = parse_map(corridor(n))
    walk, _ = check(m, expect=2 * (n - 1))
    assert walk[0] == 0 and walk[n - 1] == n - 1  # out to the far end, then back


def test_tree_shaped_map():
    m = parse_map(T_SHAPE)
    assert m.n_cells == 8
    check(m, expect=2 * (8 - 1))


def test_bridges_count_twice():
    # 4 bridges crossed twice + each 4-cycle walked round once = 16 (n = 11)
    m = parse_map(DUMBBELL)
    check(m, expect=16)


def test_colour_bound_on_an_open_room():
    # 5 cells of one colour need 5 of the 10 positions: the border ring plus a detour
    m = parse_map(ROOM)
    check(m, expect=10)


def test_one_and_two_cells():
    """Changed on purpose: a region of one cell is patrolled out and back (to its first
    neighbour, east, of another region), not by standing on it, which never visits it
    again."""
    m = parse_map(corridor(5))
    assert closed_walk(m, np.array([3])).tolist() == [3, 4]
    assert closed_walk_lower_bound(m, np.array([3])) == 2
    assert walk_is_closed_cover(m, np.array([3, 4]), np.array([3]))
    assert not walk_is_closed_cover(m, np.array([3]), np.array([3]))
    assert closed_walk(m, np.array([4])).tolist() == [4, 3]  # the end: west
    assert closed_walk(m, np.array([4, 3])).tolist() == [3, 4]
    assert closed_walk_lower_bound(m, np.array([4, 3])) == 2


def test_region_walk_stays_in_its_cells():
    m = parse_map(RING)  # cells 0..4 top row, 5 and 6 below its ends
    cells = np.array([0, 1, 2, 3, 4, 5, 6])
    walk, _ = check(m, cells, expect=2 * (7 - 1))  # a tree inside the ring
    assert set(walk.tolist()) == set(cells.tolist())


@settings(max_examples=12)
@given(seed=st.integers(0, 2**32 - 1))
def test_bound_and_walk_against_brute_force(seed):
    # a random 4 x 5 grid, walled off where cut from its corner; the region is a BFS ball
    rng = np.random.default_rng(seed)
    grid = np.where(rng.random((4, 5)) < 0.3, "#", ".")
    grid[0, 0] = "."
    grid[~reachable(grid)] = "#"
    m = parse_map("\n".join("".join(r) for r in grid) + "\n")
    cells = np.flatnonzero(bfs(m.neighbors, 0) <= rng.integers(2, 8))
    opt = shortest_closed_cover(m, cells) if cells.size > 1 else 1
    walk, bound = check(m, cells)
    assert bound <= opt <= len(walk)
    assert len(walk) == opt  # tiny regions: the search finds the optimum


# --- shipped maps ------------------------------------------------------------------


@pytest.mark.parametrize("name", ["map_a", "map_b", "pacman", "facility"])
def test_shipped_maps(name, capsys):
    m = get_map(name)
    walk = closed_walk(m, effort="fast")
    bound = closed_walk_lower_bound(m)
    assert walk_is_closed_cover(m, walk)
    assert m.n_cells < bound <= len(walk) <= 1.2 * bound  # measured: 1.07-1.14
    assert capsys.readouterr() == ("", "")


def test_held_karp_lifts_the_bound_above_the_cell_count():
    # map_b has no bridge and balanced colours: everything above 124 is Held-Karp
    m = get_map("map_b")
    assert closed_walk_lower_bound(m) >= 132


def test_walk_is_deterministic_and_a_copy():
    m = get_map("map_b")
    a = closed_walk(m, seed=3, effort="fast")
    a[:] = -1
    walks._walk_cached.cache_clear()
    b = closed_walk(m, seed=3, effort="fast")
    assert (b >= 0).all()
    walks._walk_cached.cache_clear()
    assert (closed_walk(m, seed=3, effort="fast") == b).all()


# --- partition ---------------------------------------------------------------------


@pytest.mark.parametrize("k", [1, 2, 4, 8])
def test_partition_of_map_a(k):
    m = get_map("map_a")
    labels = partition_regions(m, k)
    assert labels.shape == (m.n_cells,)
    assert set(labels.tolist()) == set(range(k))
    for r in range(k):
        assert region_is_connected(m, np.flatnonzero(labels == r))
    region = region_walks(m, labels)
    assert len(region) == k
    for r, walk in enumerate(region):
        assert walk_is_closed_cover(m, walk, np.flatnonzero(labels == r))
    # measured: longest region walk / (whole-map bound / k) = 1.08, 1.28, 1.40, 1.60
    assert max(len(w) for w in region) <= 2.0 * closed_walk_lower_bound(m) / k


def test_partition_is_deterministic():
    m = get_map("map_b")
    a = partition_regions(m, 4, seed=1)
    walks._partition_cached.cache_clear()
    assert (partition_regions(m, 4, seed=1) == a).all()


def test_partition_into_single_cells():
    m = parse_map(T_SHAPE)
    labels = partition_regions(m, m.n_cells)
    assert sorted(labels.tolist()) == list(range(m.n_cells))
    # each robot steps out to its first neighbour and back (changed on purpose: standing
    # on its one cell would never visit it again)
    walks_ = region_walks(m, labels)
    assert [w.size for w in walks_] == [2] * m.n_cells
    assert all(
        walk_is_closed_cover(m, w, np.flatnonzero(labels == r)) for r, w in enumerate(walks_)
    )


# --- errors and the validity check -------------------------------------------------


def test_errors():
    m = parse_map(RING)
    with pytest.raises(ValueError, match="between 1 and the 14 free cells"):
        partition_regions(m, 15)
    with pytest.raises(ValueError, match="between 1"):
        partition_regions(m, 0)
    disconnected = np.array([0, 1, 3, 4])  # the top row without its middle cell
    with pytest.raises(ValueError, match="not form a connected region"):
        closed_walk(m, disconnected)
    with pytest.raises(ValueError, match="not form a connected region"):
        closed_walk_lower_bound(m, disconnected)
    with pytest.raises(ValueError, match="not a free cell"):
        closed_walk(m, np.array([0, 99]))
    with pytest.raises(ValueError, match="effort"):
        closed_walk(m, effort="hard")


def test_broken_walks_are_rejected():
    m = parse_map(RING)
    walk = closed_walk(m)
    assert walk_is_closed_cover(m, walk)
    assert not walk_is_closed_cover(m, walk[1:])  # a cell missing, and a jump
    assert not walk_is_closed_cover(m, np.concatenate([walk[:5], walk[6:], walk[5:6]]))
    assert not walk_is_closed_cover(m, walk, np.arange(7))  # steps outside the region
    assert not walk_is_closed_cover(m, np.array([], dtype=np.int64))
    t = parse_map(T_SHAPE)
    assert not walk_is_closed_cover(t, np.array([0, 1, 2, 3, 4, 5, 6, 7]))  # 4 -> 5 jumps


# --- grid walks pinned ---------------------------------------------------------------


def _digest(a) -> str:
    """First 16 hex digits of the sha256 of an int64 array's bytes."""
    import hashlib

    return hashlib.sha256(np.asarray(a, dtype=np.int64).tobytes()).hexdigest()[:16]


def test_grid_walks_and_partitions_are_pinned():
    """The walks and partitions of map_a and map_b cell by cell, as computed at commit
    c12d418 (before walks became port-generic): making them work on patrol graphs must not
    move a single cell on a grid."""
    m = get_map("map_a")
    walk = closed_walk(m)
    assert (len(walk), _digest(walk)) == (216, "3e542d17cd606dd4")
    walk = closed_walk(m, effort="fast")
    assert (len(walk), _digest(walk)) == (222, "c23c17a4e196112f")
    assert closed_walk_lower_bound(m) == 200
    labels = partition_regions(m, 4)
    region = region_walks(m, labels)
    assert _digest(labels) == "416a3227e22886bc"
    assert [len(w) for w in region] == [64, 60, 70, 64]
    assert _digest(np.concatenate(region)) == "eb64bd54510d49e9"
    b = get_map("map_b")
    walk = closed_walk(b)
    assert (len(walk), _digest(walk)) == (152, "905165cb45fac846")
    assert closed_walk_lower_bound(b) == 134
    labels = partition_regions(b, 8)
    region = region_walks(b, labels)
    assert _digest(labels) == "f815b419643bd76c"
    assert [len(w) for w in region] == [28, 26, 28, 28, 28, 28, 28, 26]
    assert _digest(np.concatenate(region)) == "95c83667d7a9b016"
