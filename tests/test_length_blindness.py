"""Idleness-paid rewards are blind to tour length (docs/model.md, "Idleness-paid rewards
are blind to tour length"), checked numerically on the shipped maps.

Independent of the engines: robots follow a closed walk in a plain loop, and the gap
(idleness) of every cell they enter is read from a last-visit map kept here, updated
robot by robot as the world does (all cells visited at step 0). On each shipped grid map
three closed covering walks of different lengths are used: the walk ``cyclic`` follows
(``walks.closed_walk``, length L), the same with one back-and-forth move added (L + 2),
and the walk forward then backward (2 L).

Checked: the identity ``sum of rewards = sum_c last_N(c)`` for any motion; every whole
period from the second lap on pays exactly ``C x L`` (integers), for one robot and for K
robots evenly, unevenly or identically placed; the capped reward ``min(g, h)`` obeys
cases (a), (b), (c) of claim 2, and ``qlearning-idleness``'s and the paper's reward
formulas pay what claim 2 says; on a patrol graph C counts the waypoints the walk
enters, not only the vertices; the paper's dot term is not length-blind.

Broken on purpose once each, and the tests failed: counting only the targets as C
(``test_graph_pays_every_cell_entered``), summing over a wrong period of L + 1 steps
or over the first lap (``test_linear_reward_pays_C_per_team_step``), and paying two
robots that enter one cell in the same step both the full gap (the K = 3 case with two
robots on one position).
"""

from __future__ import annotations

import numpy as np
import pytest

from qpatrol.maps import Map, get_map, walks

GRID_MAPS = ("map_a", "map_b", "pacman", "facility")


def variants(w: list[int]) -> dict[str, list[int]]:
    """Three closed walks through the cells of ``w`` (a closed walk of length L): itself,
    with one back-and-forth move after ``w[0]`` (L + 2), forward then backward (2 L)."""
    return {
        "walk": w,
        "walk + back-and-forth": w[:1] + [w[1], w[0]] + w[1:],
        "forward then backward": w + [w[0]] + w[:0:-1],
    }


def gaps_along(walk: list[int], phases: list[int], n_cells: int, steps: int) -> np.ndarray:
    """int ``[steps, K]``: the idleness of the cell robot k enters at team step t + 1.

    Robot k stands on ``walk[phases[k]]`` at step 0 and enters ``walk[(phases[k] + t) %
    L]`` at step t; one last-visit map for the team, 0 everywhere at step 0, updated
    robot by robot (a robot entering a cell entered earlier in the same step gets 0).
    """
    L = len(walk)
    last = np.zeros(n_cells, dtype=np.int64)
    g = np.zeros((steps, len(phases)), dtype=np.int64)
    for t in range(1, steps + 1):
        for k, p in enumerate(phases):
            c = walk[(p + t) % L]
            g[t - 1, k] = t - last[c]
            last[c] = t
    return g


def period(g: np.ndarray, start: int, length: int) -> np.ndarray:
    """The gaps of team steps ``start + 1 .. start + length`` (rows of ``g``)."""
    return g[start : start + length]


@pytest.fixture(scope="module")
def grid_walks() -> dict[str, tuple[Map, dict[str, list[int]]]]:
    out = {}
    for name in GRID_MAPS:
        m = get_map(name)
        out[name] = (m, variants(walks.closed_walk(m).tolist()))
    return out


def test_the_walks_are_closed_covers_of_different_lengths(grid_walks) -> None:
    for m, vs in grid_walks.values():
        lengths = [len(v) for v in vs.values()]
        assert len(set(lengths)) == 3
        for v in vs.values():
            assert walks.walk_is_closed_cover(m, np.array(v))


def test_reward_sum_is_the_sum_of_last_visits_for_any_motion() -> None:
    """``r_t = Phi_t - Phi_{t-1}``: K robots moving at random (waits included)."""
    m = get_map("map_a")
    rng = np.random.default_rng(0)
    pos = rng.choice(m.n_cells, 5, replace=False)
    last = np.zeros(m.n_cells, dtype=np.int64)
    total = 0
    for t in range(1, 3001):
        for k in range(pos.size):
            d = rng.integers(5)  # 4: wait
            nb = m.neighbors[pos[k], d] if d < 4 else -1
            if nb < 0:
                continue
            pos[k] = nb
            total += t - last[nb]
            last[nb] = t
        assert total == last.sum()


@pytest.mark.parametrize("name", GRID_MAPS)
def test_linear_reward_pays_C_per_team_step(grid_walks, name: str) -> None:
    m, vs = grid_walks[name]
    for v in vs.values():
        L, C = len(v), len(set(v))
        assert C == m.n_cells  # a grid: every cell pays
        rng = np.random.default_rng(L)
        teams = {
            "one": [0],
            "four even": [i * L // 4 for i in range(4)],
            "eight even": [i * L // 8 for i in range(8)],
            "three, two together": [5, 5, L // 3],
            "five uneven": sorted(rng.choice(L, 5, replace=False).tolist()),
        }
        for phases in teams.values():
            g = gaps_along(v, phases, m.n_cells, 3 * L)
            for T in (L, L + 1, L + 7, 2 * L - 1, 2 * L):
                assert period(g, T, L).sum() == C * L
            # the first lap counts gaps from step 0 and pays less
            assert period(g, 0, L).sum() < C * L
            # over N steps: C N minus the summed idleness after step N, at most C L
            n = 3 * L
            assert 0 <= C * n - g.sum() <= C * L


def claim2_case(gaps: np.ndarray, h: int, C: int, K: int, L: int) -> str:
    """Check claim 2 on one period's gaps; returns the case met ("a", "b" or "c")."""
    paid = np.minimum(gaps, h).sum()
    if gaps.max() <= h:
        assert paid == C * L
        return "a"
    if gaps.min() >= h:
        assert paid == K * L * h
        return "b"
    assert paid < min(C, K * h) * L
    return "c"


@pytest.mark.parametrize("name", GRID_MAPS)
def test_capped_reward(grid_walks, name: str) -> None:
    m, vs = grid_walks[name]
    seen = set()
    for v in vs.values():
        L, C = len(v), len(set(v))
        for K in (1, 4):
            phases = [i * L // K for i in range(K)]
            g = period(gaps_along(v, phases, m.n_cells, 2 * L), L, L)
            paper_h = 100  # reward.idle_horizon
            qidle_h = 3 * m.n_cells / K  # qidle.reward_cap x cells / robots
            for h in (paper_h, qidle_h, g.max(), g.min(), int(np.median(g)), 1, 10 * L):
                seen.add(claim2_case(g, h, C, K, L))
            # qlearning-idleness's reward as the strategy computes it: every walk here is
            # at most 2 L <= 3 x cells long, so one period pays K per team step
            scale = m.n_cells / K
            qidle = np.minimum(3.0, g / scale).sum()
            assert g.max() <= qidle_h
            assert qidle == pytest.approx(K * L, rel=1e-12)
            # the paper's idleness term: incremental_value * min(1, idle / idle_horizon)
            paper = (1.0 * np.minimum(1.0, g / 100.0)).sum()
            assert paper == pytest.approx(np.minimum(g, 100).sum() / 100, rel=1e-12)
            if K == 1:  # cells > idle_horizon: at most incremental_value per step
                assert C > paper_h
                assert paper <= L * (1 + 1e-12)
                assert (paper == pytest.approx(L, rel=1e-12)) == bool(g.min() >= paper_h)
    assert seen == {"a", "b", "c"}


def test_graph_pays_every_cell_entered() -> None:
    """On a patrol graph the waypoints pay too: C is the distinct cells a walk enters."""
    m = get_map("ps_example")
    assert m.is_graph
    w = walks.closed_walk(m).tolist()
    S = set(w)
    assert m.n_targets < len(S) < m.n_cells
    # an out-and-back into a waypoint the walk does not enter: one more cell pays
    i, extra = next(
        (i, int(nb)) for i, c in enumerate(w) for nb in m.neighbors[c] if nb >= 0 and nb not in S
    )
    longer = w[: i + 1] + [extra, w[i]] + w[i + 1 :]
    assert walks.walk_is_closed_cover(m, np.array(longer))
    for v in (w, longer):
        L, C = len(v), len(set(v))
        g = gaps_along(v, [0], m.n_cells, 3 * L)
        for T in (L, 2 * L - 3):
            assert period(g, T, L).sum() == C * L
    # the longer walk earns more per step: it enters one more cell
    assert len(set(longer)) == len(S) + 1


def dots_per_step(m: Map, walk: list[int], laps: int) -> float:
    """Dots one robot on ``walk`` eats per step over ``laps`` laps after 5 laps; all dots
    back when the last is eaten (a dot episode)."""
    has = m.dot_kind > 0
    dots = has.copy()
    L = len(walk)
    eaten = 0
    for t in range(1, (5 + laps) * L + 1):
        c = walk[t % L]
        if t > 5 * L:
            eaten += bool(dots[c])
        dots[c] = False
        if not dots.any():
            dots = has.copy()
    return eaten / (laps * L)


def test_paper_dot_term_is_not_covered(grid_walks) -> None:
    """The dot term pays per episode: here the 2-step detour lowers it, while the walk
    twice as long (forward then backward) keeps it."""
    m, vs = grid_walks["map_a"]
    rate = {k: dots_per_step(m, v, 15) for k, v in vs.items()}
    assert rate["walk + back-and-forth"] < rate["walk"] - 0.005
    assert rate["forward then backward"] == pytest.approx(rate["walk"], abs=2e-3)
