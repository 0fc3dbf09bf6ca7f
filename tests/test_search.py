"""The searches that replaced the all-pairs table (qpatrol.maps.search), each against an
independent computation: rows and the diameter against ``all_pairs_distances`` on
generated mazes, graphs in pieces and both kernels (Python and compiled); the spread of
robots against the old farthest-point rule over the whole table."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mazes import random_maze

from qpatrol.config import from_flat
from qpatrol.maps import all_pairs_distances, parse_map, search
from qpatrol.world import make_params, place_agents


@pytest.fixture(params=["python", "compiled"])
def kernel(request, monkeypatch):
    """Both kernels: the compiled one on every map, whatever its size."""
    if request.param == "compiled":
        pytest.importorskip("numba")
        monkeypatch.setattr(search, "COMPILED_CELLS", 0)
    return request.param


def random_graph(rng: np.random.Generator, n: int, p: float) -> np.ndarray:
    """int ``[n, 4]`` neighbours of a random graph of at most 4 ports a cell, often in
    pieces (a map's moves need not be symmetric here: searches follow ports)."""
    nb = np.full((n, 4), -1, dtype=np.int64)
    for a in range(n):
        for b in range(a + 1, n):
            if rng.random() < p:
                fa, fb = np.flatnonzero(nb[a] < 0), np.flatnonzero(nb[b] < 0)
                if fa.size and fb.size:
                    nb[a, fa[0]], nb[b, fb[0]] = b, a
    return nb


@settings(max_examples=25, deadline=None)
@given(
    rows=st.integers(1, 9),
    cols=st.integers(1, 9),
    seed=st.integers(0, 2**16),
    loops=st.sampled_from([0.0, 0.1, 0.4, 1.0]),
)
def test_rows_and_diameter_equal_the_all_pairs_table_on_mazes(rows, cols, seed, loops):
    m = parse_map(random_maze(rows, cols, seed, loops, 1, False))
    table = all_pairs_distances(m.neighbors)
    default = search.COMPILED_CELLS
    for kernel in ("python", "compiled"):
        search.COMPILED_CELLS = 0 if kernel == "compiled" else 10**9
        try:
            assert search.diameter(m.neighbors) == table.max()
            src = [0, m.n_cells - 1, m.n_cells // 2]
            assert np.array_equal(search.bfs_rows(m.neighbors, src), table[src])
        finally:
            search.COMPILED_CELLS = default
    assert m.diameter() == table.max()


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 40), p=st.floats(0.0, 0.3), seed=st.integers(0, 2**16))
def test_diameter_and_relax_on_graphs_in_pieces(n, p, seed):
    nb = random_graph(np.random.default_rng(seed), n, p)
    table = all_pairs_distances(nb)
    assert search.diameter(nb) == table.max()
    labels = search.components(nb)
    assert np.array_equal(labels[:, None] == labels[None, :], table >= 0)
    rng = np.random.default_rng(seed + 1)
    big = 10**9
    near = np.full(n, big, dtype=np.int64)
    chosen = []
    for _ in range(min(n, 5)):
        chosen.append(int(rng.integers(n)))
        search.relax(nb, chosen[-1], near)
        rows = table[chosen]
        want = np.where(rows >= 0, rows, big).min(axis=0)
        assert np.array_equal(near, want)


def test_kernels_agree_on_a_large_maze(kernel):
    m = parse_map(random_maze(40, 40, 3, 0.25, 2, False))
    row = search.bfs(m.neighbors, 5)
    near = np.full(m.n_cells, 10**9, dtype=np.int64)
    search.relax(m.neighbors, 5, near)
    assert np.array_equal(row, near)
    assert (row >= 0).all() and row[5] == 0
    # each cell one move further than some neighbour, none two nearer
    nbr = np.where(m.neighbors >= 0, row[np.maximum(m.neighbors, 0)], 10**9)
    others = np.arange(m.n_cells) != 5
    assert (nbr.min(axis=1)[others] == row[others] - 1).all()


def old_place_agents(p, m, rng):
    """place_agents before the searches: the farthest cell over the whole table."""
    dist = all_pairs_distances(m.neighbors)
    placed = list(p.starts[: p.n_agents])
    while len(placed) < p.n_agents:
        far = dist[placed].min(axis=0) if placed else np.ones(p.n_cells, dtype=np.int64)
        far[placed] = -1
        far[~p.target] = -1
        best = np.flatnonzero(far == far.max())
        placed.append(int(best[rng.integers(best.size)]))
    return np.array(placed, dtype=np.int64)


@pytest.mark.parametrize("agents", [1, 3, 9])
@pytest.mark.parametrize("maze", [(6, 7, 1, 0.0), (8, 8, 2, 0.3), (3, 12, 5, 1.0)])
def test_placement_equals_the_farthest_point_rule_over_the_table(agents, maze):
    m = parse_map(random_maze(*maze, 1, False))
    p = make_params(from_flat({"agents": agents, "battery.enabled": False}), m)
    for seed in range(4):
        new = place_agents(p, m, np.random.default_rng(seed))
        old = old_place_agents(p, m, np.random.default_rng(seed))
        assert new.tolist() == old.tolist()


def test_placement_on_a_graph():
    lines = ["; kind: graph"] + [f"v {v} {v} 0" for v in range(7)]
    edges = ["e 0 1 1", "e 1 2 3", "e 2 3 1", "e 3 4 2", "e 4 5 1", "e 1 5 4", "e 5 6 2"]
    m = parse_map("\n".join(lines + edges) + "\n")
    p = make_params(from_flat({"agents": 3, "battery.enabled": False}), m)
    for seed in range(6):
        new = place_agents(p, m, np.random.default_rng(seed))
        old = old_place_agents(p, m, np.random.default_rng(seed))
        assert new.tolist() == old.tolist()


@settings(max_examples=20, deadline=None)
@given(
    rows=st.integers(2, 8),
    cols=st.integers(2, 8),
    seed=st.integers(0, 2**16),
    loops=st.sampled_from([0.0, 0.2, 1.0]),
)
def test_large_region_walks_cover_and_respect_the_bound(rows, cols, seed, loops):
    """The walk of a region above SEARCH_TARGETS (the limit lowered to 0 here) is a closed
    walk through every cell, no shorter than the table-free bound, no longer than twice
    the cells (a spanning tree walked around), and the methods say so. That bound is at
    least its counting part and at most the searched walk's length."""
    from qpatrol.maps import walks

    m = parse_map(random_maze(rows, cols, seed, loops, 1, False))
    old = walks.SEARCH_TARGETS
    walks.SEARCH_TARGETS = 0
    try:
        walks._walk_cached.cache_clear()
        walks._bound_cached.cache_clear()
        w = walks.closed_walk(m)
        bound = walks.closed_walk_lower_bound(m)
        methods = walks.closed_walk_methods(m)
    finally:
        walks.SEARCH_TARGETS = old
        walks._walk_cached.cache_clear()
        walks._bound_cached.cache_clear()
    assert walks.walk_is_closed_cover(m, w)
    assert bound <= w.size <= 2 * (m.n_cells - 1)
    cells = np.arange(m.n_cells)
    assert walks._parity_bound(m, cells, walks._local_neighbors(m, cells)) <= bound
    assert bound <= walks.closed_walk(m).size
    assert "above 0 targets" in methods["walk_method"]
    assert "corridor walk" in methods["walk_method"]
    assert "corridor parities" in methods["walk_lower_bound_method"]
    assert "Held-Karp skipped" in methods["walk_lower_bound_method"]
