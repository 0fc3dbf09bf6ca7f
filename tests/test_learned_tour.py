"""``learned-tour``: its search by hand, its invariants, and its routes on unseen maps.

The search's moves and the route's repair are checked against hand values on small
maps, in numpy and (when numba is installed) in the compiled twin on its own; the
bookkeeping (order length, inverse positions, best order) is checked after thousands of
random proposals; and one robot's learned route is compared with the closed walk
``cyclic`` computes, on generated maps no shipped file has.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mazes import random_maze

from qpatrol.config import ConfigError, from_flat
from qpatrol.engines import numba_installed
from qpatrol.maps import get_map, parse_map, walks
from qpatrol.run import simulate
from qpatrol.strategies import learned_tour as lt

RING = "; name: ring\n#####\n#...#\n#.#.#\n#...#\n#####\n"  # 8 cells around a pillar
LINE = "; name: line\n######\n#....#\n######\n"


def _arrays(text: str):
    m = parse_map(text)
    return m, m.neighbors.astype(np.int64), np.ascontiguousarray(m.distances(), dtype=np.int64)


def _compiled():
    if not numba_installed():
        pytest.skip("numba not installed")
    from qpatrol.engines.compiled import tour

    return tour


def _moves_ok(m, w: np.ndarray) -> None:
    """Consecutive cells one move apart (closing too), every target in, no move twice."""
    nxt = np.roll(w, -1)
    assert (m.distances()[w, nxt] == 1).all() or w.size == 1
    assert set(np.flatnonzero(m.target)) <= set(w.tolist())
    assert len(set(zip(w.tolist(), nxt.tolist(), strict=True))) == w.size


def test_repair_by_hand():
    """Two laps of the ring make every move twice; the first repeat (0 -> 1 at positions
    0 and 8) turns ``a b Y a b`` into ``a Y' b``, 2 moves shorter, every cell still in:
    one lap one way, then back the other way, which repeats no move, so it stops."""
    m, nbrs, dist = _arrays(RING)
    lap = [0, 1, 2, 4, 7, 6, 5, 3]  # the ring's cells in order (ports N, E, S, W)
    assert all(dist[a, b] == 1 for a, b in zip(lap, np.roll(lap, -1), strict=True))
    w = np.array(lap * 2)
    once = np.concatenate([w[:1], w[2:8][::-1], w[9:]])  # the first repair, by the rule
    assert once.tolist() == [0, 3, 5, 6, 7, 4, 2, 1, 2, 4, 7, 6, 5, 3]
    out = lt.repair(w, nbrs)
    _moves_ok(m, out)
    np.testing.assert_array_equal(out, once)
    # a walk that repeats no move is left as it is
    np.testing.assert_array_equal(lt.repair(np.array(lap), nbrs), lap)
    # out and back along a line: each move is made once each way, nothing to repair
    ml, nl, _ = _arrays(LINE)
    np.testing.assert_array_equal(lt.repair(np.array([0, 1, 2, 3, 2, 1]), nl), [0, 1, 2, 3, 2, 1])


def test_route_repairs_by_hand():
    """The ring's order 0 2 1 4 7 6 5 3 expands to 0 1 2 1 2 4 7 6 5 3 (0 -> 2 through 1,
    1 -> 4 through 2): the move 1 -> 2 is made twice (positions 1 and 3), and the
    repair leaves the ring 0 1 2 4 7 6 5 3, in each engine."""
    m, nbrs, dist = _arrays(RING)
    order = np.array([0, 2, 1, 4, 7, 6, 5, 3])
    np.testing.assert_array_equal(lt.expand(nbrs, dist, order), [0, 1, 2, 1, 2, 4, 7, 6, 5, 3])
    np.testing.assert_array_equal(lt.route_of(nbrs, dist, order), [0, 1, 2, 4, 7, 6, 5, 3])
    if numba_installed():
        tour = _compiled()
        w = np.zeros(16, dtype=np.int64)
        first = np.full(m.n_cells * 4, -1, dtype=np.int64)
        n = tour._route(order, 8, nbrs, dist, w, np.zeros(16, dtype=np.int64), first)
        assert w[:n].tolist() == [0, 1, 2, 4, 7, 6, 5, 3]
        assert (first == -1).all()  # left clean for the next call


def test_route_by_hand():
    """The line's depth-first order 0 1 2 3 joined by shortest paths: out and back,
    6 moves (3 -> 0 expands to 3 2 1); no move repeats, so no repair."""
    m, nbrs, dist = _arrays(LINE)
    order = lt.depth_first_order(nbrs, m.target, 0)
    assert order.tolist() == [0, 1, 2, 3]
    assert lt.order_length(dist, order) == 6
    np.testing.assert_array_equal(lt.route_of(nbrs, dist, order), [0, 1, 2, 3, 2, 1])


def test_two_opt_by_hand():
    """On the ring, order 0 2 1 4 ... has a crossing: 2-opt from a = 0 (i = 0) to its
    nearest c = 1 reverses b..c = (2 1): 0 1 2 4 ..., the order 2 shorter."""
    m, nbrs, dist = _arrays(RING)
    order = np.array([0, 2, 1, 4, 7, 6, 5, 3])
    pos = np.empty(m.n_cells, dtype=np.int64)
    pos[order] = np.arange(order.size)
    near = lt.nearest_targets(dist, np.flatnonzero(m.target), 2)
    assert near[0].tolist() == [1, 3]  # distance 1 both; lower cell first
    before = lt.order_length(dist, order)
    x = 0 + 8 * 0  # i = 0, then the first nearest target
    assert lt.two_opt(order, pos, dist, near, x) == -2
    assert order.tolist() == [0, 1, 2, 4, 7, 6, 5, 3]
    assert lt.order_length(dist, order) == before - 2
    assert (pos[order] == np.arange(8)).all()
    # a move that would lengthen the order is not made
    assert lt.two_opt(order, pos, dist, near, 0) == 0  # c = 1 is b already
    if numba_installed():
        tour = _compiled()
        o2 = np.array([0, 2, 1, 4, 7, 6, 5, 3])
        p2 = np.empty(m.n_cells, dtype=np.int64)
        p2[o2] = np.arange(8)
        assert tour._two_opt(o2, p2, 8, dist, near, x) == -2
        assert o2.tolist() == [0, 1, 2, 4, 7, 6, 5, 3]


def test_or_opt_by_hand():
    """On the ring, order 0 1 5 2 4 7 6 3: the target 5 (i = 2, one target, not turned)
    is carried next to its nearest target 3 (between 3 and 0): d(1,2) + d(3,5) + d(5,0)
    - d(1,5) - d(5,2) - d(3,0) = 1 + 1 + 2 - 3 - 4 - 1 = -4."""
    m, nbrs, dist = _arrays(RING)
    order = np.array([0, 1, 5, 2, 4, 7, 6, 3])
    pos = np.empty(m.n_cells, dtype=np.int64)
    pos[order] = np.arange(8)
    near = lt.nearest_targets(dist, np.flatnonzero(m.target), 2)
    assert near[5].tolist() == [3, 6]
    expect = dist[1, 2] + dist[3, 5] + dist[5, 0] - dist[1, 5] - dist[5, 2] - dist[3, 0]
    assert expect == -4
    # x: i = 2, then n_seg = 1 (0), rev = 0, then the first nearest (3)
    x = 2 + 8 * (0 + 3 * (0 + 2 * 0))
    before = lt.order_length(dist, order)
    assert lt.or_opt(order, pos, dist, near, x) == -4
    assert lt.order_length(dist, order) == before - 4
    # rebuilt from n = 2 round to c = 3, then the carried target, then d .. p
    assert order.tolist() == [2, 4, 7, 6, 3, 5, 0, 1]
    if numba_installed():
        tour = _compiled()
        o2 = np.array([0, 1, 5, 2, 4, 7, 6, 3])
        p2 = np.empty(m.n_cells, dtype=np.int64)
        p2[o2] = np.arange(8)
        assert tour._or_opt(o2, p2, 8, dist, near, x, np.zeros(8, dtype=np.int64)) == -4
        assert o2.tolist() == [2, 4, 7, 6, 3, 5, 0, 1]


def test_double_bridge_by_hand():
    """x = i + T (a - 1 + (w - 2) (b - a - 1)) with i = 2, a = 2, b = 4, window 40 on 8
    targets (w = 7): the order rotated to start at position 2, then [1..2] and [3..4]
    swapped."""
    order = np.arange(8)
    pos = np.arange(8)
    x = 2 + 8 * ((2 - 1) + (7 - 2) * (4 - 2 - 1))
    lt.double_bridge(order, pos, x, 40)
    assert order.tolist() == [2, 5, 6, 3, 4, 7, 0, 1]
    assert (pos[order] == np.arange(8)).all()


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), loops=st.sampled_from([0.0, 0.2, 0.5]))
def test_search_keeps_its_books(seed: int, loops: float):
    """After 3,000 random proposals (kicks every 50) on a generated maze: ``cur_len`` is
    the order's length, ``pos`` its inverse, ``best_len`` the best order's length (never
    above the first), and the route of the best order is a closed walk through every
    cell that makes no move twice and is no longer than the order."""
    m = parse_map(random_maze(4, 5, seed, loops=loops))
    nbrs = m.neighbors.astype(np.int64)
    dist = np.ascontiguousarray(m.distances(), dtype=np.int64)
    targets = np.flatnonzero(m.target)
    near = lt.nearest_targets(dist, targets, 8)
    order = lt.depth_first_order(nbrs, m.target, int(targets[0]))
    pos = np.zeros(m.n_cells, dtype=np.int64)
    pos[order] = np.arange(order.size)
    cur = first = lt.order_length(dist, order)
    best, best_len = order.copy(), cur
    rng = np.random.default_rng(seed)
    for step in range(3000):
        x = int(np.floor(rng.random() * lt.DRAW))
        if step % 50 == 49:
            order[:] = best
            pos[order] = np.arange(order.size)
            lt.double_bridge(order, pos, x, lt.KICK_WINDOW)
            cur = lt.order_length(dist, order)
            continue
        move = lt.two_opt if x % 2 == 0 else lt.or_opt
        cur += move(order, pos, dist, near, x // 2)
        assert cur == lt.order_length(dist, order)
        assert (pos[order] == np.arange(order.size)).all()
        assert sorted(order.tolist()) == targets.tolist()
        if cur < best_len:
            best, best_len = order.copy(), cur
    assert best_len <= first
    route = lt.route_of(nbrs, dist, best)
    _moves_ok(m, route)
    assert route.size <= best_len


def test_keys_are_checked():
    for key, bad in (("tour.neighbours", 0), ("tour.kick_after", 0), ("tour.learn_steps", -1)):
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
            from_flat({"policy": "learned-tour", key: bad})


def _learned(text_or_name: str, steps: int, **flat) -> list[dict]:
    cfg = from_flat(
        {
            "map": text_or_name,
            "policy": "learned-tour",
            "agents": 1,
            "runs": 2,
            "steps": steps,
            "battery.enabled": False,
            "security.attack_steps": [],
            **flat,
        }
    )
    return simulate(cfg).summary


def test_learning_stops_at_learn_steps():
    """With ``tour.learn_steps`` the route changes only in the first steps, each change
    to a shorter route; 3 robots on one route keep ``floor(n / 3)`` steps apart."""
    cfg = from_flat(
        {
            "map": "map_a",
            "policy": "learned-tour",
            "agents": 3,
            "runs": 2,
            "steps": 3000,
            "battery.enabled": False,
            "security.attack_steps": [],
            "tour.learn_steps": 1500,
        }
    )
    result = simulate(cfg)
    for r, run in enumerate(result.summary):
        assert len(run["tour_changes"]) > 1 and max(run["tour_changes"]) < 1500
        assert run["tour_lengths"][-1] == run["tour_length"]
        assert (np.diff(run["tour_lengths"]) < 0).all()
        assert (result.strategy.spacing[r] == run["tour_length"] // 3).all()


@pytest.mark.parametrize("seed", [101, 202, 303, 404])
def test_unseen_maps_one_robot_within_1_3_of_the_computed_walk(tmp_path, seed: int):
    """On generated mazes (trees, one with rooms knocked through), one robot's learned
    route after 100,000 team steps covers every cell, makes no move twice and is within
    1.3 times the closed walk ``qpatrol`` computes for ``cyclic``."""
    if not numba_installed():
        pytest.skip("100,000 steps want the compiled engine")
    loops = {101: 0.0, 202: 0.15, 303: 0.3, 404: 0.6}[seed]
    path = tmp_path / "maze.txt"
    path.write_text(random_maze(7, 9, seed, loops=loops))
    m = parse_map(path.read_text())
    L = walks.closed_walk(m).size
    result = simulate(
        from_flat(
            {
                "map": str(path),
                "policy": "learned-tour",
                "agents": 1,
                "runs": 2,
                "steps": 100_000,
                "battery.enabled": False,
                "security.attack_steps": [],
            }
        )
    )
    for r, run in enumerate(result.summary):
        n = run["tour_length"]
        route = result.strategy.walk[r, 0, :n]
        _moves_ok(m, route)
        assert n <= 1.3 * L, (seed, n, L)


def test_shipped_map_route_is_short():
    """map_a, one robot, 30,000 steps: the route is within 1.1 x cyclic's walk."""
    if not numba_installed():
        pytest.skip("wants the compiled engine")
    L = walks.closed_walk(get_map("map_a")).size
    for run in _learned("map_a", 30_000):
        assert run["tour_length"] <= 1.1 * L


@pytest.mark.parametrize(
    "flat",
    [
        {"map": "map_b", "agents": 1, "battery.enabled": False, "tour.kick_after": 200},
        {"map": "map_a", "agents": 4, "tour.kick_after": 100, "record.trajectory": 1500},
        {"map": "pacman", "agents": 3, "team.communication": False, "tour.kick_after": 50},
        {"map": "ps_example", "agents": 2, "tour.learn_steps": 700},
        {"map": "map_a", "agents": 4, "failures.robots": 1, "failures.at": 600},
    ],
    ids=["lone", "team-battery", "private", "graph-learn-steps", "failure"],
)
def test_engines_agree(tmp_path, flat):
    """Both engines give the same files and the same strategy arrays (orders, routes,
    histories) to the bit, with route changes, kicks, the battery, private tables, a
    graph and a failure."""
    if not numba_installed():
        pytest.skip("numba not installed")
    from test_engines import both

    base = {"policy": "learned-tour", "runs": 2, "steps": 1500, "security.attack_steps": []}
    assert both({**base, **flat}, tmp_path, strategy=True) == ("numba", "")


@pytest.mark.parametrize("engine", ["numpy", "numba"])
def test_checkpoint_resumes_the_same(tmp_path, stop_and_resume, engine):
    """Stopped at step 900 and resumed from its checkpoint, a run learns the same orders,
    routes and route history as one uninterrupted run."""
    if engine == "numba" and not numba_installed():
        pytest.skip("numba not installed")
    cfg = from_flat(
        {
            "map": "map_a",
            "policy": "learned-tour",
            "agents": 3,
            "runs": 2,
            "steps": 2000,
            "engine": engine,
            "tour.kick_after": 200,
            "security.attack_steps": [],
        }
    )
    whole = simulate(cfg)
    rest = stop_and_resume(cfg, tmp_path / "cp", 900)
    assert rest.summary == whole.summary
    for name in ("order", "best", "pos", "walk", "length", "target", "spacing"):
        np.testing.assert_array_equal(getattr(rest.strategy, name), getattr(whole.strategy, name))
    assert rest.strategy.history == whole.strategy.history
    assert all(len(run["tour_changes"]) > 1 for run in whole.summary)
