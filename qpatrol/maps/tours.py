"""The reference of the gamma figure: the shortest walk that eats every dot.

One agent stands on cell ``start`` of a map whose dot cells all hold their dot. Each
move enters a neighbouring free cell and eats the dot there, if any. The dot of the
start cell is eaten only by *re-entering* the start cell (standing on it does not eat
it, as in the simulator). How many moves does it take, at least, until every dot is
eaten? That is the steps of a perfect first episode (one agent, no battery stop).

The problem is a path version of the travelling salesman problem on the maze's
shortest-path metric (NP-hard in general), so this module gives two numbers around
the optimum ``OPT``:

* :func:`dot_walk_lower_bound` -- a proven bound ``<= OPT`` (Held-Karp 1-tree bound);
* :func:`dot_walk_tour` -- a feasible walk, so its length is ``>= OPT`` (nearest
  neighbour, 2-opt and or-opt, then iterated local search with double-bridge kicks).

Both work on the same *terminal problem*: node 0 is the start position, nodes
``1..n`` the dot cells (sorted by cell; the start cell is one of them if it holds a
dot), and ``D[i, j]`` the BFS distance between their cells, except ``D[0, s] = 2``
between the start position and the start cell's own dot ``s`` (leave, come back).
Every order ``0, x1, ..., xn`` of the nodes is a walk of length
``D[0, x1] + D[x1, x2] + ...`` (join consecutive cells by shortest paths) that eats
every dot, since each leg ends by entering its node's cell. Conversely, list the dots
that any such walk eats by the time each is eaten: that is an order of the nodes, and
each of its legs ``D[a, b]`` is at most the moves the walk spends between eating a and
eating b (at least 2 from the start position back to the start cell). So ``OPT`` is
exactly the length of the shortest Hamiltonian path from node 0 in ``D``.

Everything is deterministic: ties go to the lowest index and the local search's kicks
come from a fixed seed.
"""

from __future__ import annotations

import math

import numpy as np

from qpatrol.maps import Map

__all__ = ["dot_walk_lower_bound", "dot_walk_tour", "terminal_problem", "walk_is_valid"]


def terminal_problem(m: Map, start: int) -> tuple[np.ndarray, np.ndarray]:
    """``(cells, D)``: the terminal problem of the module docstring.

    ``cells`` int ``[n + 1]``: node 0 is ``start``, nodes 1..n the dot cells in
    increasing order. ``D`` int ``[n + 1, n + 1]``: BFS distances, with 2 between the
    start position and the start cell's own dot.
    """
    start = int(start)
    if not 0 <= start < m.n_cells:
        raise ValueError(f"start {start} is not a state of map {m.name} (0..{m.n_cells - 1})")
    dots = np.flatnonzero(m.dot_kind > 0)
    if dots.size == 0:
        raise ValueError(f"map {m.name} has no dot")
    if start in dots and not (m.neighbors[start] >= 0).any():
        raise ValueError(f"the start cell {start} has a dot and no neighbour to come back from")
    cells = np.concatenate([[start], dots]).astype(np.int64)
    dist = m.distances()
    D = dist[np.ix_(cells, cells)].astype(np.int64)
    own = np.flatnonzero(cells[1:] == start) + 1
    D[0, own] = 2
    D[own, 0] = 2
    return cells, D


# --- lower bound -------------------------------------------------------------------


def _mst(w: np.ndarray) -> tuple[float, np.ndarray]:
    """Prim on a dense symmetric matrix: ``(weight, degree [N])`` of a minimum spanning tree."""
    n = w.shape[0]
    in_tree = np.zeros(n, dtype=bool)
    in_tree[0] = True
    best = w[0].astype(np.float64).copy()
    parent = np.zeros(n, dtype=np.int64)
    degree = np.zeros(n, dtype=np.int64)
    total = 0.0
    for _ in range(n - 1):
        cand = np.where(in_tree, np.inf, best)
        v = int(np.argmin(cand))
        total += cand[v]
        degree[v] += 1
        degree[parent[v]] += 1
        in_tree[v] = True
        closer = ~in_tree & (w[v] < best)
        best[closer] = w[v, closer]
        parent[closer] = v
    return total, degree


def _one_tree_bound(D: np.ndarray, pi: np.ndarray) -> tuple[float, np.ndarray]:
    """``(L(pi), subgradient)`` of the Held-Karp bound for an open path from node 0."""
    w = D + pi[:, None] + pi[None, :]
    tree, degree = _mst(w)
    x = int(np.argmin(pi[1:])) + 1
    bound = tree + pi[0] + pi[x] - 2.0 * pi.sum()
    g = degree - 2
    g[0] += 1
    g[x] += 1
    return float(bound), g.astype(np.float64)


def dot_walk_lower_bound(
    m: Map, start: int, upper: int | None = None, iterations: int = 400
) -> int:
    """A lower bound on the moves of any walk from ``start`` that eats every dot.

    The bound is ``max(n, ceil(max_pi L(pi)))`` over the terminal problem (module
    docstring: nodes 0..n, matrix ``D``; ``OPT`` = shortest Hamiltonian path from node 0).

    Why it is valid:

    * ``n`` (the number of dot cells): each dot is eaten by its own move.
    * ``L(pi)``, for any real vector ``pi`` (Held & Karp's 1-tree bound, path form)::

          L(pi) = MST_pi + pi[0] + min_{x >= 1} pi[x] - 2 * sum(pi)

      where ``MST_pi`` is the weight of a minimum spanning tree of nodes 0..n under
      ``D[i, j] + pi[i] + pi[j]``. A Hamiltonian path P from node 0 to an end e is a
      spanning tree, with degree 1 at 0 and at e and 2 elsewhere, so its modified
      weight is ``len(P) + 2 * sum(pi) - pi[0] - pi[e] >= MST_pi``, i.e.
      ``len(P) >= MST_pi + pi[0] + pi[e] - 2 * sum(pi) >= L(pi)``. At ``pi = 0``
      this is the plain MST bound; subgradient ascent on ``pi`` (Polyak steps towards
      ``upper``) raises it. Every ``L(pi)`` evaluated is a valid bound; the best is kept.
    * ``OPT`` is an integer, so the bound may be rounded up (with a 1e-6 guard
      against floating-point error).

    Args:
        m: the map. start: the agent's cell.
        upper: a known walk length (steers the step size); default: the tour of
            :func:`dot_walk_tour`.
        iterations: subgradient steps (the bound only grows with more).
    """
    _, D = terminal_problem(m, start)
    n = D.shape[0] - 1
    if n == 1:
        return int(D[0, 1])
    if upper is None:
        upper = dot_walk_tour(m, start)[0]
    Df = D.astype(np.float64)
    pi = np.zeros(n + 1)
    best, _ = _one_tree_bound(Df, pi)
    mu, stale = 2.0, 0
    for _ in range(iterations):
        if math.ceil(best - 1e-6) >= upper or mu < 1e-4:
            break
        value, g = _one_tree_bound(Df, pi)
        if value > best + 1e-9:
            best, stale = value, 0
        else:
            stale += 1
            if stale >= 15:
                mu, stale = mu / 2.0, 0
        norm = float(g @ g)
        if norm == 0.0:  # the 1-tree is a Hamiltonian path: the bound is exact
            break
        pi = pi + mu * (upper - value) / norm * g
    return max(n, math.ceil(best - 1e-6))


# --- tour --------------------------------------------------------------------------


def _path_cost(D: np.ndarray, order: np.ndarray) -> int:
    return int(D[order[:-1], order[1:]].sum())


def _nearest_neighbour(D: np.ndarray) -> np.ndarray:
    n = D.shape[0]
    order = [0]
    left = np.ones(n, dtype=bool)
    left[0] = False
    for _ in range(n - 1):
        row = np.where(left, D[order[-1]], np.iinfo(np.int64).max)
        nxt = int(np.argmin(row))
        order.append(nxt)
        left[nxt] = False
    return np.array(order, dtype=np.int64)


def _two_opt_move(De: np.ndarray, p: np.ndarray) -> bool:
    """Apply the best improving segment reversal of ``p`` (in place); False if none.

    ``p`` ends with the virtual end node (0 distance to all), so reversing a tail of
    the path is the same formula as reversing an inner segment.
    """
    N = p.size - 1  # real nodes p[0..N-1], virtual end p[N]
    i = np.arange(1, N)[:, None]
    j = np.arange(1, N)[None, :]
    delta = (
        De[p[i - 1], p[j]] + De[p[i], p[j + 1]] - De[p[i - 1], p[i]] - De[p[j], p[j + 1]]
    ).astype(np.float64)
    delta[j <= i] = np.inf
    if delta.size == 0:
        return False
    k = int(np.argmin(delta))
    if delta.flat[k] >= 0:
        return False
    a, b = divmod(k, N - 1)
    a, b = a + 1, b + 1
    p[a : b + 1] = p[a : b + 1][::-1].copy()
    return True


def _or_opt_move(De: np.ndarray, p: np.ndarray, max_len: int = 3) -> bool:
    """Apply the best improving move of a segment of 1..3 nodes (maybe reversed); False if none."""
    N = p.size - 1
    best = (0, None)
    for L in range(1, max_len + 1):
        for i in range(1, N - L + 1):
            a, b = p[i], p[i + L - 1]  # segment p[i..i+L-1]
            prev, nxt = p[i - 1], p[i + L]
            gain = De[prev, a] + De[b, nxt] - De[prev, nxt]
            if gain <= 0:
                continue
            rest = np.concatenate([p[:i], p[i + L :]])  # still ends with the virtual end
            u, v = rest[:-1], rest[1:]  # insert between u and v
            base = De[u, v]
            fwd = De[u, a] + De[b, v] - base
            rev = De[u, b] + De[a, v] - base
            cost = np.minimum(fwd, rev)
            k = int(np.argmin(cost))
            delta = int(cost[k]) - int(gain)
            if delta < best[0]:
                seg = p[i : i + L]
                if rev[k] < fwd[k]:
                    seg = seg[::-1]
                best = (delta, np.concatenate([rest[: k + 1], seg, rest[k + 1 :]]))
    if best[1] is None:
        return False
    p[:] = best[1]
    return True


def _expand(m: Map, cells: np.ndarray, order: np.ndarray) -> list[int]:
    """The cell-by-cell walk through the nodes of ``order`` (shortest paths, lowest port
    first: N E S W on a grid)."""
    dist = m.distances()
    walk = [int(cells[order[0]])]
    for node in order[1:]:
        goal = int(cells[node])
        cur = walk[-1]
        if cur == goal:  # the start cell's own dot: out to the first neighbour and back
            nb = int(next(x for x in m.neighbors[cur] if x >= 0))
            walk += [nb, goal]
            continue
        while cur != goal:
            cur = int(
                next(x for x in m.neighbors[cur] if x >= 0 and dist[x, goal] == dist[cur, goal] - 1)
            )
            walk.append(cur)
    return walk


def _double_bridge(p: np.ndarray, rng: np.random.Generator, window: int | None) -> np.ndarray:
    """Swap two adjacent segments of the real nodes (node 0 and the virtual end stay put)."""
    N = p.size - 1
    if window is None:
        a, b, c = np.sort(rng.choice(np.arange(1, N), 3, replace=False))
    else:
        a = int(rng.integers(1, N - 2))
        b, c = np.sort(rng.choice(np.arange(a + 1, min(N, a + window)), 2, replace=False))
    return np.concatenate([p[:a], p[b:c], p[a:b], p[c:]])


def _local_search(De: np.ndarray, p: np.ndarray, max_rounds: int) -> None:
    for _ in range(max_rounds):
        if not (_two_opt_move(De, p) or _or_opt_move(De, p)):
            break


def dot_walk_tour(
    m: Map, start: int, kicks: int | None = None, seed: int = 0, max_rounds: int = 100000
) -> tuple[int, list[int]]:
    """A short walk from ``start`` that eats every dot: ``(moves, cells)``.

    Over the terminal problem (module docstring): nearest neighbour, then best-improvement
    2-opt and or-opt (segments of 1-3 dot cells, either way round) on the open path until
    neither improves; then iterated local search: ``kicks`` times, a double-bridge kick
    (two adjacent stretches of the order swapped; alternately anywhere and within 30
    nodes) followed by the same local search, keeping the result if it is no longer
    (equal lengths are accepted, to drift along plateaus, which graph metrics are full
    of). The kicks draw from ``numpy.random.default_rng(seed)``, so the result is
    deterministic. ``kicks`` defaults to ``min(1000, 200000 // dots, 20 * (dots + 1))``.

    ``cells`` is the walk cell by cell, ``cells[0] == start``, ``moves == len(cells) - 1``
    and consecutive cells are neighbours. Being a feasible walk, ``moves`` is an upper
    bound on the optimum.
    """
    cells, D = terminal_problem(m, start)
    n1 = D.shape[0]
    De = np.zeros((n1 + 1, n1 + 1), dtype=np.int64)  # + the virtual end node n1
    De[:n1, :n1] = D
    p = np.concatenate([_nearest_neighbour(D), [n1]])
    _local_search(De, p, max_rounds)
    best, best_cost = p, _path_cost(De, p)
    if kicks is None:
        kicks = min(1000, 200000 // max(1, n1 - 1), 20 * n1)
    rng = np.random.default_rng(seed)
    if n1 >= 5:
        for k in range(kicks):
            q = _double_bridge(best, rng, None if k % 2 == 0 else 30)
            _local_search(De, q, max_rounds)
            cost = _path_cost(De, q)
            if cost <= best_cost:
                best, best_cost = q, cost
    order = best[:-1]
    walk = _expand(m, cells, order)
    moves = _path_cost(D, order)
    assert moves == len(walk) - 1
    return moves, walk


def walk_is_valid(m: Map, start: int, walk: list[int]) -> bool:
    """True if ``walk`` starts on ``start``, moves between neighbours and eats every dot."""
    if not walk or walk[0] != start:
        return False
    nb = m.neighbors
    for a, b in zip(walk[:-1], walk[1:], strict=True):
        if b not in nb[a]:
            return False
    entered = set(walk[1:])
    return all(int(c) in entered for c in np.flatnonzero(m.dot_kind > 0))
