"""Closed walks that visit every target of a region, and maps cut into balanced regions.

Two patrol strategies use these, once per map:

* ``cyclic`` (Chevaleyre 2004) puts the whole team on one short closed walk through
  every target: :func:`closed_walk`, reported beside the proven
  :func:`closed_walk_lower_bound` on the shortest one;
* ``partition`` gives each robot its own connected region
  (:func:`partition_regions`) and the closed walk of that region
  (:func:`region_walks`).

The *targets* are the cells the measures count (:attr:`qpatrol.maps.Map.target`): every
cell of a grid maze, the vertices of a patrol graph (not the waypoint cells inside its
edges). A *region* is a set of cells whose induced subgraph (cells of the set, moves
between two cells of the set) is connected and that holds at least one target. A
*closed walk* of a region is an int array ``w`` of ``L`` cells of the region such that
``w[i + 1]`` is one move from ``w[i]`` and ``w[0]`` one move from ``w[L - 1]``, visiting
every target of the region; its length is ``L`` moves, the period of an agent that
cycles it. It steps on the region's other cells (waypoints) only as it travels between
targets, and need not visit them all. A region with one target has no closed walk of
positive length: by convention its walk is ``[c]`` with ``L = 1``, the agent staying on
``c``.

The shortest closed walk through every target is a travelling salesman tour over the
region's targets in the shortest-path metric of the region (join consecutive targets by
shortest paths; conversely list the targets of any covering walk by their first visit),
an NP-hard problem, hence a heuristic tour and a lower bound. Nothing here uses grid
geometry: moves are the map's ports (``neighbors`` [C, D]), colours come from a
breadth-first 2-colouring, so grids and patrol graphs take the same code (on a grid,
where every cell is a target, it is exactly the tour over all cells).

Results are cached in-process by (map, cells, seed, ...), so repeated calls are free;
the arrays returned are fresh copies.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from functools import lru_cache

import numpy as np

from qpatrol.maps import Map, all_pairs_distances, bfs
from qpatrol.maps.search import components
from qpatrol.maps.tours import _double_bridge, _mst, _nearest_neighbour

__all__ = [
    "EFFORTS",
    "closed_walk",
    "closed_walk_lower_bound",
    "closed_walk_methods",
    "partition_regions",
    "region_walks",
    "walk_is_closed_cover",
]

#: Double-bridge kicks of the tour search per region cell, and their cap, by effort.
EFFORTS = {"fast": (1, 300), "normal": (10, 2500), "thorough": (30, 20000)}
_CANDIDATES = 10  # neighbour-list size of the local search
_KICK_WINDOW = 40  # kicks swap two segments within this many tour positions
_HK_ITERATIONS = 120  # subgradient steps of the Held-Karp bound
_DELAY_ROUNDS = 40  # rounds of delay tuning in partition_regions
_DELAY_STEP = 4.0  # delay added per unit of relative cost excess
_PACKING_ROUNDS = 6  # growth rounds of the corridor bound's balls (radii in 1/64 moves)
#: Most targets of a region whose walk is searched over the metric closure of its targets
#: (a [t, t] table; 695 on the largest shipped map): larger regions take the table-free
#: walk of :func:`_large_walk`, and if all their cells are targets the corridor bound
#: (:func:`_large_bound`). Also the most cells of a piece whose lower bound adds the
#: Held-Karp bound (:func:`closed_walk_lower_bound`); larger pieces keep the other
#: bounds and say so (:func:`closed_walk_methods`).
SEARCH_TARGETS = 2000


class _MapKey:
    """A map that hashes and compares by its grid text, moves and targets, so lru_cache can
    take it (a graph has no grid text: its ``neighbors`` and ``target`` tell it apart)."""

    __slots__ = ("m", "_hash")

    def __init__(self, m: Map):
        self.m = m
        self._hash = hash((m.grid, m.neighbors.tobytes(), m.target.tobytes()))

    def __hash__(self) -> int:
        return self._hash

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, _MapKey):
            return False
        a, b = self.m, other.m
        return (
            a.grid == b.grid
            and np.array_equal(a.neighbors, b.neighbors)
            and np.array_equal(a.target, b.target)
        )


# --- regions -----------------------------------------------------------------------


def _cell_set(m: Map, cells: np.ndarray | None) -> tuple[int, ...]:
    """The sorted distinct cells of ``cells`` (all cells if None), checked."""
    if cells is None:
        return tuple(range(m.n_cells))
    arr = np.asarray(cells)
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(
            f"cells must be a non-empty 1-D array of cell numbers, got shape {arr.shape}"
        )
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"cells must hold integer cell numbers, got dtype {arr.dtype}")
    bad = arr[(arr < 0) | (arr >= m.n_cells)]
    if bad.size:
        raise ValueError(
            f"cell {int(bad[0])} is not a free cell of map {m.name} (0..{m.n_cells - 1})"
        )
    return tuple(int(c) for c in np.unique(arr))


def _local_neighbors(m: Map, cells: np.ndarray) -> np.ndarray:
    """int ``[n, D]``: for node i (cell ``cells[i]``), the node one move away by each port
    (N/E/S/W on a grid), -1 if none or outside ``cells``."""
    local = np.full(m.n_cells, -1, dtype=np.int64)
    local[cells] = np.arange(cells.size)
    nb = m.neighbors[cells]
    return np.where(nb >= 0, local[np.maximum(nb, 0)], -1)


def _where(m: Map, c: int) -> str:
    """`` at (row, col)`` of a grid cell; on a graph, which vertex or waypoint it is."""
    if not m.is_graph:
        return f" at {tuple(int(x) for x in m.coords[c])}"
    return " (a vertex)" if m.target[c] else " (a waypoint)"


def _require_connected(m: Map, cells: np.ndarray, nb: np.ndarray) -> None:
    label = components(nb)
    if label.max() > 0:
        a, b = cells[0], cells[int(np.argmax(label > 0))]
        raise ValueError(
            f"the {cells.size} cells do not form a connected region of map {m.name}: "
            f"{label.max() + 1} pieces; cell {b}{_where(m, b)} cannot be reached "
            f"from cell {a}{_where(m, a)} through cells of the region"
        )


def _region_targets(m: Map, cells: np.ndarray) -> np.ndarray:
    """int ``[t]``: the nodes (indices into ``cells``) that are targets; ValueError if none."""
    tgt = np.flatnonzero(m.target[cells])
    if tgt.size == 0:
        raise ValueError(
            f"the {cells.size} cells hold no target of map {m.name} (a region needs a vertex)"
        )
    return tgt


def _colours(nb: np.ndarray, label: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(colour [n], bipartite [pieces])``: a breadth-first 2-colouring of each piece.

    Pieces are the values of ``label`` (default: the connected components of ``nb``); only
    moves inside a piece count. ``colour`` is 0 on the lowest node of each piece and
    alternates along moves; ``bipartite[p]`` is False if piece p has an odd cycle (its
    colours are then meaningless). On a grid the colour is ``(row + col) % 2`` up to a
    swap in each piece.
    """
    if label is None:
        label = components(nb)
    n = nb.shape[0]
    adj, lab = nb.tolist(), label.tolist()
    colour = [-1] * n
    bipartite = np.ones(int(label.max()) + 1 if n else 0, dtype=bool)
    for s in range(n):
        if colour[s] >= 0:
            continue
        colour[s] = 0
        queue = deque([s])
        while queue:
            v = queue.popleft()
            for w in adj[v]:
                if w < 0 or lab[w] != lab[v]:
                    continue
                if colour[w] < 0:
                    colour[w] = 1 - colour[v]
                    queue.append(w)
                elif colour[w] == colour[v]:
                    bipartite[lab[v]] = False
    return np.array(colour, dtype=np.int64), bipartite


def _prune_dead_ends(m: Map, cells: np.ndarray) -> np.ndarray:
    """The cells of ``cells`` left after dropping, again and again, non-target cells with at
    most one neighbour in the set: no shortest closed walk through the targets enters them
    (the excursion could be cut out). On a grid, where every cell is a target, all cells."""
    is_target = m.target[cells]
    if is_target.all():
        return cells
    keep = np.ones(cells.size, dtype=bool)
    nb = _local_neighbors(m, cells)
    deg = (nb >= 0).sum(axis=1)
    stack = [int(v) for v in np.flatnonzero(~is_target & (deg <= 1))]
    while stack:
        v = stack.pop()
        if not keep[v]:
            continue
        keep[v] = False
        for w in nb[v]:
            if w >= 0 and keep[w]:
                deg[w] -= 1
                if not is_target[w] and deg[w] <= 1:
                    stack.append(int(w))
    return cells[keep]


def _bridges(nb: np.ndarray) -> list[tuple[int, int]]:
    """The bridges ``(u, v)`` of the graph ``nb`` (iterative Tarjan low-link search)."""
    n = nb.shape[0]
    adj = nb.tolist()
    disc = [-1] * n
    low = [0] * n
    out: list[tuple[int, int]] = []
    clock = 0
    for root in range(n):
        if disc[root] >= 0:
            continue
        disc[root] = low[root] = clock
        clock += 1
        stack = [(root, -1, iter(adj[root]))]
        while stack:
            v, parent, it = stack[-1]
            for w in it:
                if w < 0 or w == parent:
                    continue
                if disc[w] < 0:
                    disc[w] = low[w] = clock
                    clock += 1
                    stack.append((w, v, iter(adj[w])))
                    break
                low[v] = min(low[v], disc[w])
            else:
                stack.pop()
                if parent >= 0:
                    low[parent] = min(low[parent], low[v])
                    if low[v] > disc[parent]:
                        out.append((parent, v))
    return out


def _two_edge_components(nb: np.ndarray) -> tuple[int, np.ndarray]:
    """``(bridges, label [n])``: bridge count and 2-edge-connected component of each node."""
    bridges = _bridges(nb)
    cut = {(u, v) for u, v in bridges} | {(v, u) for u, v in bridges}
    return len(bridges), components(nb, cut)


def _parity_bound(m: Map, cells: np.ndarray, nb: np.ndarray) -> int:
    """The cheap part of :func:`closed_walk_lower_bound` (bridges, counts and colours),
    counting every cell of ``cells`` as one to visit."""
    if cells.size <= 2:
        return cells.size
    n_bridges, label = _two_edge_components(nb)
    colour, bipartite = _colours(nb, label)
    size = np.bincount(label)
    black = np.bincount(label, weights=colour, minlength=size.size).astype(np.int64)
    each = np.where(bipartite, np.maximum(size, 2 * np.maximum(black, size - black)), size)
    return 2 * n_bridges + int(each[size >= 2].sum())


# --- tour search -------------------------------------------------------------------


class _TourSearch:
    """A closed tour over nodes ``0..n-1`` of a metric, improved by 2-opt and or-opt.

    First-improvement local search over neighbour lists (the ``_CANDIDATES`` nearest
    nodes) with a queue of nodes to look at ("don't look bits"): 2-opt reverses a
    stretch of the tour; or-opt moves a stretch of 1-3 nodes elsewhere, either way
    round. ``t`` is the tour (a list of nodes), ``pos[v]`` the index of v in ``t``,
    ``cost`` its length; ``D`` is the metric as nested lists (fast scalar look-ups).
    """

    def __init__(self, D: np.ndarray, order: np.ndarray):
        self.metric = D
        self.D = D.tolist()
        self.n = D.shape[0]
        k = min(_CANDIDATES, self.n - 1)
        self.cand = np.argsort(D, axis=1, kind="stable")[:, 1 : k + 1].tolist()
        self.set_tour(order)

    def set_tour(self, order: np.ndarray) -> None:
        self.t = [int(v) for v in order]
        self.pos = [0] * self.n
        for i, v in enumerate(self.t):
            self.pos[v] = i
        self.cost = self.length(np.asarray(order))

    def length(self, order: np.ndarray) -> int:
        return int(self.metric[order, np.roll(order, -1)].sum())

    def succ(self, v: int) -> int:
        return self.t[(self.pos[v] + 1) % self.n]

    def pred(self, v: int) -> int:
        return self.t[self.pos[v] - 1]

    def _reverse(self, a: int, b: int) -> None:
        """Reverse the stretch of the tour going forward from node a to node b."""
        t, pos, n = self.t, self.pos, self.n
        i, j = pos[a], pos[b]
        size = (j - i) % n + 1
        if 2 * size > n:  # reversing the rest gives the same cyclic tour, cheaper
            i, j, size = (j + 1) % n, (i - 1) % n, n - size
        for _ in range(size // 2):
            t[i], t[j] = t[j], t[i]
            pos[t[i]], pos[t[j]] = i, j
            i, j = (i + 1) % n, (j - 1) % n

    def _two_opt(self, a: int) -> list[int] | None:
        D = self.D
        for forward in (True, False):
            b = self.succ(a) if forward else self.pred(a)
            for c in self.cand[a]:
                gain = D[a][b] - D[a][c]
                if gain <= 0:
                    break
                d = self.succ(c) if forward else self.pred(c)
                if c == b or d == a:
                    continue
                delta = gain + D[c][d] - D[b][d]
                if delta > 0:  # a-b, c-d become a-c, b-d
                    if forward:
                        self._reverse(b, c)
                    else:
                        self._reverse(a, d)
                    self.cost -= delta
                    return [a, b, c, d]
        return None

    def _or_opt(self, a: int) -> list[int] | None:
        D, t, n = self.D, self.t, self.n
        for size in (1, 2, 3):
            if size > n - 3:
                break
            for first in sorted({self.pos[a], (self.pos[a] - size + 1) % n}):
                seg = [t[(first + j) % n] for j in range(size)]
                p, nx = t[first - 1], t[(first + size) % n]
                gain = D[p][seg[0]] + D[seg[-1]][nx] - D[p][nx]
                if gain <= 0:
                    continue
                ends = [(seg[0], seg[-1]), (seg[-1], seg[0])][: 1 if size == 1 else 2]
                for x, y in ends:  # x goes next to a candidate c
                    for c in self.cand[x]:
                        if D[x][c] >= gain:
                            break
                        if c in seg:
                            continue
                        for u, v in ((c, self.succ(c)), (self.pred(c), c)):
                            if u in seg or v in seg:
                                continue
                            head = x if u == c else y  # the segment end placed after u
                            tail = y if u == c else x
                            delta = gain - (D[u][head] + D[tail][v] - D[u][v])
                            if delta > 0:
                                self._move(seg, u, head != seg[0])
                                self.cost -= delta
                                return [p, nx, seg[0], seg[-1], u, v]
        return None

    def _move(self, seg: list[int], u: int, reverse: bool) -> None:
        """Cut the stretch ``seg`` out and put it back right after node u."""
        inside = set(seg)
        rest = [v for v in self.t if v not in inside]
        k = rest.index(u) + 1
        self.t = rest[:k] + (seg[::-1] if reverse else seg) + rest[k:]
        for i, v in enumerate(self.t):
            self.pos[v] = i

    def local_search(self, todo: list[int]) -> None:
        """Improve until no node in the queue (``todo``, then touched ones) has a move."""
        queued = [False] * self.n
        queue: deque[int] = deque()
        for v in todo:
            if not queued[v]:
                queued[v] = True
                queue.append(v)
        while queue:
            a = queue.popleft()
            queued[a] = False
            touched = self._two_opt(a) or self._or_opt(a)
            for v in touched or ():
                if not queued[v]:
                    queued[v] = True
                    queue.append(v)


def _shortest_tour(D: np.ndarray, kicks: int, seed: int) -> np.ndarray:
    """int ``[n]``: a short closed tour through the nodes of the metric ``D`` [n, n].

    Nearest neighbour from node 0, the local search of :class:`_TourSearch`, then
    ``kicks`` rounds of iterated local search: swap two neighbouring stretches of the
    best tour (a double bridge, from :func:`qpatrol.maps.tours._double_bridge`; every fourth
    anywhere, else within ``_KICK_WINDOW`` positions), re-optimise around the changed
    edges, and keep the result if it is no longer. The kicks draw from
    ``numpy.random.default_rng(seed)``, so the tour is deterministic. Starts at node 0.
    """
    n = D.shape[0]
    search = _TourSearch(D, _nearest_neighbour(D))
    search.local_search(list(range(n)))
    best, best_cost = np.array(search.t), search.cost
    rng = np.random.default_rng(seed)
    if n >= 8:
        for k in range(kicks):
            window = None if k % 4 == 0 else min(_KICK_WINDOW, n - 1)
            kicked = _double_bridge(best, rng, window)
            search.set_tour(kicked)
            before, after = _successors(best), _successors(kicked)
            changed = np.flatnonzero(before != after)
            search.local_search(np.unique(np.concatenate([changed, after[changed]])).tolist())
            if search.cost <= best_cost:
                best, best_cost = np.array(search.t), search.cost
    return np.roll(best, -int(np.flatnonzero(best == 0)[0]))


def _successors(order: np.ndarray) -> np.ndarray:
    """int ``[n]``: the node after each node in the closed tour ``order``."""
    succ = np.empty_like(order)
    succ[order] = np.roll(order, -1)
    return succ


def _depth_first_order(nb: np.ndarray, root: int = 0) -> np.ndarray:
    """int ``[n]``: the nodes in depth-first preorder from ``root`` (neighbours in port
    order: N, E, S, W on a grid).

    On a tree, joining consecutive nodes of this order (and the last to the first) by
    shortest paths walks every edge exactly twice: ``2 (n - 1)`` moves, the optimum. Kept
    to a subset of nodes (the targets), the same joins walk twice every edge of the
    smallest subtree holding them, again the optimum (any closed walk through them crosses
    each such edge, which separates two of them, at least twice).
    """
    order, seen, stack = [], np.zeros(nb.shape[0], dtype=bool), [root]
    while stack:
        v = stack.pop()
        if seen[v]:
            continue
        seen[v] = True
        order.append(v)
        stack.extend(int(w) for w in nb[v][::-1] if w >= 0 and not seen[w])
    return np.array(order, dtype=np.int64)


def _expand(nb: np.ndarray, D: np.ndarray, order: np.ndarray) -> np.ndarray:
    """int ``[L]``: the closed walk through the nodes of ``order`` by shortest paths.

    Each leg steps to the first neighbour in port order (N, E, S, W on a grid) one move
    closer to the goal;
    the leg back to ``order[0]`` ends just before it, closing the walk.
    """
    walk = [int(order[0])]
    for goal in [*order[1:].tolist(), int(order[0])]:
        cur = walk[-1]
        while D[cur, goal] > 0:
            cur = next(int(x) for x in nb[cur] if x >= 0 and D[x, goal] == D[cur, goal] - 1)
            walk.append(cur)
    return np.array(walk[:-1], dtype=np.int64)


@lru_cache(maxsize=256)
def _walk_cached(key: _MapKey, cells: tuple[int, ...], seed: int, effort: str) -> np.ndarray:
    m, arr = key.m, np.array(cells, dtype=np.int64)
    tgt = _region_targets(m, arr)  # nodes of the targets; all nodes on a grid
    nb = _local_neighbors(m, arr)
    _require_connected(m, arr, nb)
    if tgt.size == 1:
        return _out_and_back(m, int(arr[tgt[0]]))
    if tgt.size == arr.size and arr.size <= 2:
        return arr
    if tgt.size > SEARCH_TARGETS:
        local_back = np.where(nb >= 0, m.back[arr], -1)
        corridors = _corridors_cached(key, cells) if tgt.size == arr.size else None
        return arr[_large_walk(nb, local_back, m.target[arr], corridors)]
    D = all_pairs_distances(nb)
    if (nb >= 0).sum() // 2 == arr.size - 1:  # a tree: depth-first order is optimal
        order = _depth_first_order(nb, int(tgt[0]))
        order = order[m.target[arr[order]]]
    elif tgt.size <= 3:  # every order of three is the same tour
        order = tgt
    else:
        per_cell, cap = EFFORTS[effort]
        order = tgt[_shortest_tour(D[np.ix_(tgt, tgt)], min(cap, per_cell * tgt.size), seed)]
    return arr[_expand(nb, D, order)]


def _join(adj: list, dist: list, cur: int, goal: int, out: list) -> None:
    """Append to ``out`` the cells after ``cur`` of the shortest path from ``cur`` to
    ``goal`` that steps to the first neighbour (port order) one move nearer: what
    :func:`_expand` takes over the table, from a search out of ``goal`` that stops once
    it reaches ``cur`` (every cell nearer to ``goal`` is then labelled). ``dist`` is a
    list of -1 of the graph's size, left so."""
    if cur == goal:
        return
    dist[goal] = 0
    seen = [goal]
    head = 0
    while dist[cur] < 0:
        v = seen[head]
        head += 1
        dv = dist[v] + 1
        for w in adj[v]:
            if w >= 0 and dist[w] < 0:
                dist[w] = dv
                seen.append(w)
    while cur != goal:
        here = dist[cur] - 1
        cur = next(x for x in adj[cur] if x >= 0 and dist[x] == here)
        out.append(cur)
    for v in seen:
        dist[v] = -1


def _nearest_walk(adj: list, is_target: list, first: int) -> list:
    """The nearest-neighbour closed walk: from ``first``, again and again the shortest
    path (breadth-first, port order) to the nearest target not yet visited, then back."""
    n = len(adj)
    left = sum(is_target) - 1
    seen = [False] * n
    seen[first] = True
    cur, walk = first, [first]
    dist, parent = [-1] * n, [-1] * n
    while left:
        dist[cur] = 0
        queue, head, found = [cur], 0, -1
        while found < 0:
            v = queue[head]
            head += 1
            for w in adj[v]:
                if w >= 0 and dist[w] < 0:
                    dist[w], parent[w] = dist[v] + 1, v
                    queue.append(w)
                    if is_target[w] and not seen[w]:
                        found = w
                        break
        path, x = [], found
        while x != cur:
            path.append(x)
            x = parent[x]
        for x in reversed(path):
            walk.append(x)
            if is_target[x] and not seen[x]:
                seen[x] = True
                left -= 1
        for v in queue:
            dist[v] = -1
        cur = found
    _join(adj, dist, cur, first, walk)
    return walk[:-1]


def _euler_circuit(adj: list, back: list, mult: list, first: int) -> list:
    """An Euler circuit from ``first`` of the multigraph that uses the move by port p out
    of cell v ``mult[v][p]`` times (even at every cell, the moves used connected):
    Hierholzer, ports in order; ``mult`` is used up. The cells, the last step back to
    ``first`` left out."""
    n, ports = len(adj), len(adj[0])
    circuit, stack, nxt = [], [first], [0] * n
    while stack:
        v = stack[-1]
        p = nxt[v]
        while p < ports and mult[v][p] == 0:
            p += 1
        nxt[v] = p
        if p == ports:
            circuit.append(stack.pop())
        else:
            w = adj[v][p]
            mult[v][p] -= 1
            mult[w][back[v][p]] -= 1
            stack.append(w)
    circuit.reverse()
    return circuit[:-1]


# --- corridors: the walk and bound of a large region whose cells are all targets ----


class _Corridors:
    """A region whose cells are all targets (nodes ``0..n-1``), cut where a closed walk
    through all of them has little choice.

    ``label[v]`` is the 2-edge-connected piece of node v (the region without its
    bridges), ``degree[v]`` its moves inside that piece. ``bridges`` holds one step
    ``(v, port)`` along each bridge; ``rings`` the steps once round each piece of at least
    two nodes that has no *junction* (a node of degree 3 or more in its piece): such a
    piece is a cycle. The moves of every other piece split into *chains*: chain i runs
    from junction ``a[i]`` through ``k[i]`` nodes of degree 2 (a corridor) to junction
    ``b[i]`` (``a[i] == b[i]`` for a loop); ``steps[i]`` are its ``k[i] + 1`` moves
    ``(v, port)`` from ``a[i]``'s end.
    """

    __slots__ = ("label", "degree", "bridges", "rings", "a", "b", "k", "steps")

    def __init__(self, nb: np.ndarray, back: np.ndarray):
        n, ports = nb.shape
        adj, bk = nb.tolist(), back.tolist()
        bridges = _bridges(nb)
        self.bridges = [(u, adj[u].index(v)) for u, v in bridges]
        lab = components(nb, {(u, v) for u, v in bridges} | {(v, u) for u, v in bridges})
        label = lab.tolist()
        inside = (nb >= 0) & (lab[np.maximum(nb, 0)] == lab[:, None])
        degree = inside.sum(axis=1).tolist()
        self.label, self.degree = label, degree
        self.a, self.b, self.k, self.steps = [], [], [], []
        done: set[tuple[int, int]] = set()  # the last steps of chains traced, reversed
        junction_pieces = set()
        for a in range(n):
            if degree[a] < 3:
                continue
            piece = label[a]
            junction_pieces.add(piece)
            for p in range(ports):
                x = adj[a][p]
                if x < 0 or label[x] != piece or (a, p) in done:
                    continue
                steps, cur, q = [(a, p)], x, bk[a][p]
                while degree[cur] == 2:
                    r = next(
                        r
                        for r in range(ports)
                        if r != q and adj[cur][r] >= 0 and label[adj[cur][r]] == piece
                    )
                    steps.append((cur, r))
                    cur, q = adj[cur][r], bk[cur][r]
                done.add((cur, q))
                self.a.append(a)
                self.b.append(cur)
                self.k.append(len(steps) - 1)
                self.steps.append(steps)
        self.rings = []
        seen = set(junction_pieces)
        for s in range(n):
            if degree[s] != 2 or label[s] in seen:
                continue
            seen.add(label[s])
            steps, cur, q = [], s, -1
            while True:
                r = next(
                    r
                    for r in range(ports)
                    if r != q and adj[cur][r] >= 0 and label[adj[cur][r]] == label[s]
                )
                steps.append((cur, r))
                cur, q = adj[cur][r], bk[cur][r]
                if cur == s:
                    break
            self.rings.append(steps)

    def junction_graph(self) -> tuple[list[int], list[int], list[int], list[bool]]:
        """``(junctions, ea, eb, odd)``: the junction nodes in order, the ends of each
        chain as indices into them, and which junctions have odd degree."""
        junctions = sorted(set(self.a) | set(self.b))
        index = {v: i for i, v in enumerate(junctions)}
        ea = [index[v] for v in self.a]
        eb = [index[v] for v in self.b]
        return junctions, ea, eb, [self.degree[v] % 2 == 1 for v in junctions]

    def base_parities(self, ea: list[int], eb: list[int], odd: list[bool]):
        """``(weights, odd)``: the T-join problem of the cheapest chain parities (see
        :func:`_corridor_parities`): each chain starts at its cheaper parity, 0 for a move
        between two junctions (``k = 0``), else 1; changing it costs ``|k - 1|``; the odd
        nodes are those whose chains at their starting parities leave them odd."""
        odd = list(odd)
        for i, k in enumerate(self.k):
            if k == 0 and ea[i] != eb[i]:
                odd[ea[i]] = not odd[ea[i]]
                odd[eb[i]] = not odd[eb[i]]
        return [abs(k - 1) for k in self.k], odd

    def cost(self, parity: list[int]) -> int:
        """Moves of the chains at ``parity`` (0: each end walked in and back, ``2 k``; 1:
        once through, ``k + 1``; 2: twice through, ``2 k + 2``)."""
        return sum((2 * k, k + 1, 2 * k + 2)[p] for k, p in zip(self.k, parity, strict=True))


@lru_cache(maxsize=2)
def _corridors_cached(key: _MapKey, cells: tuple[int, ...]) -> _Corridors:
    m, arr = key.m, np.array(cells, dtype=np.int64)
    nb = _local_neighbors(m, arr)
    return _Corridors(nb, np.where(nb >= 0, m.back[arr], -1))


def _root(parent: list[int], x: int) -> int:
    """The root of x in the union-find forest ``parent`` (paths halved on the way)."""
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


def _contract_free(n: int, ea: list[int], eb: list[int], w: list[int]):
    """``(group, forest)``: ``group[v]`` is one node standing for all the nodes that
    edges of weight 0 join to v, and ``forest`` lists weight-0 edges spanning each group."""
    parent = list(range(n))
    forest = []
    for i in range(len(ea)):
        if w[i] == 0 and ea[i] != eb[i]:
            ra, rb = _root(parent, ea[i]), _root(parent, eb[i])
            if ra != rb:
                parent[ra] = rb
                forest.append(i)
    return [_root(parent, v) for v in range(n)], forest


def _voronoi(n, ea, eb, w, group, inc, start: dict[int, int]):
    """Multi-source Dijkstra over the groups: ``(label, owner, pred)`` where
    ``label[g] = min_s start[s] + d(s, g)`` over the sources s (keys of ``start``),
    ``owner[g]`` the source that attains it and ``pred[g]`` the edge into g on the way
    (-1 at a source and where unreached)."""
    inf = math.inf
    label, owner, pred = [inf] * n, [-1] * n, [-1] * n
    heap = []
    for s, d in start.items():
        label[s], owner[s] = d, s
        heap.append((d, s))
    heapq.heapify(heap)
    while heap:
        d, v = heapq.heappop(heap)
        if d > label[v]:
            continue
        for i in inc[v]:
            u = group[eb[i]] if group[ea[i]] == v else group[ea[i]]
            nd = d + w[i]
            if nd < label[u]:
                label[u], owner[u], pred[u] = nd, owner[v], i
                heapq.heappush(heap, (nd, u))
    return label, owner, pred


def _group_incidence(n, ea, eb, group) -> list[list[int]]:
    """For each group, the edges between it and another group."""
    inc: list[list[int]] = [[] for _ in range(n)]
    for i in range(len(ea)):
        a, b = group[ea[i]], group[eb[i]]
        if a != b:
            inc[a].append(i)
            inc[b].append(i)
    return inc


def _t_join(n: int, ea: list[int], eb: list[int], w: list[int], odd: list[bool]) -> list[bool]:
    """A short T-join: edges (``ea[i]``, ``eb[i]``, weight ``w[i] >= 0``) such that every
    node of ``odd`` meets an odd number of them and every other node an even number
    (each connected piece must hold an even number of odd nodes).

    Nodes joined by weight-0 edges are merged into groups; a group is odd if it holds an
    odd number of odd nodes. In rounds, a Dijkstra from all odd groups not yet paired
    (its Voronoi regions) proposes, for each edge between two regions, their two sources
    at the length of the path through it; the proposals are taken cheapest first,
    each group once, and the edges of the path are flipped in the join. Then a T-join
    on a spanning forest of the weight-0 edges (from the leaves up) evens out the nodes
    inside each group at no cost. Greedy, not minimum; time about ``m log m`` a round.
    """
    m = len(ea)
    group, forest = _contract_free(n, ea, eb, w)
    inc = _group_incidence(n, ea, eb, group)
    group_odd = [False] * n
    for v in range(n):
        if odd[v]:
            group_odd[group[v]] = not group_odd[group[v]]
    join = [False] * m
    left = [g for g in range(n) if group_odd[g]]
    while left:
        label, owner, pred = _voronoi(n, ea, eb, w, group, inc, dict.fromkeys(left, 0))
        offers: dict[tuple[int, int], tuple[int, int]] = {}
        for i in range(m):
            a, b = group[ea[i]], group[eb[i]]
            oa, ob = owner[a], owner[b]
            if oa < 0 or ob < 0 or oa == ob:
                continue
            pair = (oa, ob) if oa < ob else (ob, oa)
            offer = (label[a] + w[i] + label[b], i)
            if pair not in offers or offer < offers[pair]:
                offers[pair] = offer
        paired: set[int] = set()
        for (_, i), pair in sorted((o, p) for p, o in offers.items()):
            if pair[0] in paired or pair[1] in paired:
                continue
            paired.update(pair)
            join[i] = not join[i]
            for x in (group[ea[i]], group[eb[i]]):
                while pred[x] >= 0:
                    j = pred[x]
                    join[j] = not join[j]
                    x = group[eb[j]] if group[ea[j]] == x else group[ea[j]]
        left = [g for g in left if g not in paired]
    rest = list(odd)
    for i in range(m):
        if join[i]:
            rest[ea[i]] = not rest[ea[i]]
            rest[eb[i]] = not rest[eb[i]]
    near: list[list[int]] = [[] for _ in range(n)]
    for i in forest:
        near[ea[i]].append(i)
        near[eb[i]].append(i)
    seen = [False] * n
    for root in range(n):
        if seen[root] or not near[root]:
            continue
        seen[root] = True
        order, up = [root], {}
        for v in order:
            for i in near[v]:
                u = eb[i] if ea[i] == v else ea[i]
                if not seen[u]:
                    seen[u], up[u] = True, i
                    order.append(u)
        for v in reversed(order[1:]):
            if rest[v]:
                i = up[v]
                u = eb[i] if ea[i] == v else ea[i]
                join[i] = not join[i]
                rest[v], rest[u] = False, not rest[u]
    return join


def _ball_packing(
    n: int, ea: list[int], eb: list[int], w: list[int], odd: list[bool], piece: list[int]
) -> dict[int, int]:
    """A lower bound on the weight of every T-join (``odd`` as in :func:`_t_join`), for
    each connected piece (``piece[v]`` of node v): ``{piece: bound * 2**rounds}``, with
    ``rounds = _PACKING_ROUNDS``.

    Merge the nodes joined by weight-0 edges into groups (a T-join's weight-0 edges cost
    nothing, so it is a T-join of the odd groups at the same weight). Read the graph as
    a metric space, each edge a segment of its length, and give each odd group t a
    radius ``r_t >= 0`` such that ``r_t + r_u <= d(t, u)`` for any two: the open balls
    ``B(t, r_t)`` are disjoint and none holds another odd group. A T-join splits into
    paths that pair the odd groups (and cycles); the path from t leaves ``B(t, r_t)``,
    so the join has length ``>= r_t`` inside that ball, and the balls being disjoint,
    its weight is ``>= sum r_t``.

    The radii grow from 0 in rounds. A Dijkstra from every odd group t, started at
    ``-r_t``, labels each node x with ``min_t (d(t, x) - r_t)`` and the group that
    attains it, its owner. Each odd group owns itself: a source keeps its start label
    unless strictly beaten, and ``d(u, t) - r_u >= -r_t`` as ``r_u - r_t <= d(t, u)``.
    For an edge (x, y) from t's region to u's, ``label(x) + w + label(y) >= d(t, u) -
    r_t - r_u``; and on a shortest path from t to the odd group u that minimises
    ``d(t, u) - r_u``, the first edge (x, y) leaving t's region (u is outside it) gives
    at most that value, as ``label(x) = d(t, x) - r_t`` and ``label(y) <= d(u, y) -
    r_u``. So the least value over the edges leaving t's region is exactly t's slack
    ``s_t = min_u (d(t, u) - r_t - r_u)``. Every radius then grows by ``s_t / 2``
    (rounded down): ``s_t / 2 + s_u / 2 <= d(t, u) - r_t - r_u`` for any two, so the
    balls stay disjoint. Radii are counted in ``2**-rounds`` moves: integers.
    """
    group, _ = _contract_free(n, ea, eb, w)
    group_odd = [False] * n
    for v in range(n):
        if odd[v]:
            group_odd[group[v]] = not group_odd[group[v]]
    odds = [g for g in range(n) if group_odd[g]]
    out: dict[int, int] = {}
    if len(odds) < 2:
        return out
    scale = 1 << _PACKING_ROUNDS
    ws = [x * scale for x in w]
    inc = _group_incidence(n, ea, eb, group)
    radius = dict.fromkeys(odds, 0)
    for _ in range(_PACKING_ROUNDS):
        label, owner, _ = _voronoi(n, ea, eb, ws, group, inc, {t: -r for t, r in radius.items()})
        slack = dict.fromkeys(odds, math.inf)
        for i in range(len(ea)):
            a, b = group[ea[i]], group[eb[i]]
            oa, ob = owner[a], owner[b]
            if oa < 0 or ob < 0 or oa == ob:
                continue
            length = label[a] + ws[i] + label[b]
            slack[oa] = min(slack[oa], length)
            slack[ob] = min(slack[ob], length)
        for t in odds:
            if slack[t] != math.inf:
                radius[t] += slack[t] // 2
    for t, r in radius.items():
        out[piece[t]] = out.get(piece[t], 0) + r
    return out


def _corridor_parities(c: _Corridors) -> list[int]:
    """How often the corridor walk (:func:`_corridor_walk`) runs through each chain of
    ``c``: 0 (each end walked in and back, ``2 k`` moves: no move for ``k = 0``), 1
    (``k + 1``) or 2 (``2 k + 2``).

    At every junction the chains run through an odd number of times must be even in
    number, and the chains run through must join all junctions of a piece. First the
    cheapest parities ignoring the joining: chain i starts at its cheaper parity (0 if
    ``k = 0``, else 1), and a T-join (:func:`_t_join`) of weights ``|k - 1|`` changes
    some, to even out the junctions. Then a spanning tree of each piece's junctions
    that takes as few of the chains left at 0 as it can (Prim with weights 0 and 1, the
    latest edge first, so long paths: few odd junctions). Two ways to a walk: the tree's
    chains at 0 go to 2 (same parity); or the parities again from the start with the
    tree's chains kept at 1 or 2 (changing costs ``k + 1``) and the other chains free.
    The cheaper of the two, after dropping from 2 to 0 the chains that the others join
    anyway.
    """
    junctions, ea, eb, odd = c.junction_graph()
    n, m = len(junctions), len(c.k)
    loop = [ea[i] == eb[i] for i in range(m)]
    weight, base_odd = c.base_parities(ea, eb, odd)
    flip = _t_join(n, ea, eb, weight, base_odd)
    free = [(1 if c.k[i] else 0) if loop[i] else int(flip[i] == (c.k[i] == 0)) for i in range(m)]
    inc: list[list[int]] = [[] for _ in range(n)]
    for i in range(m):
        if not loop[i]:
            inc[ea[i]].append(i)
            inc[eb[i]].append(i)
    tree, seen = [False] * m, [False] * n
    for root in range(n):
        if seen[root]:
            continue
        seen[root] = True
        cheap = [(i, root) for i in inc[root] if free[i]]
        dear = [(i, root) for i in inc[root] if not free[i]]
        while cheap or dear:
            i, v = cheap.pop() if cheap else dear.pop()
            u = eb[i] if ea[i] == v else ea[i]
            if seen[u]:
                continue
            seen[u] = tree[i] = True
            for j in inc[u]:
                if not seen[eb[j] if ea[j] == u else ea[j]]:
                    (cheap if free[j] else dear).append((j, u))
    repaired = [2 if tree[i] and not free[i] else free[i] for i in range(m)]
    tree_odd = list(odd)
    tree_weight = [0] * m
    for i in range(m):
        if tree[i]:
            tree_weight[i] = c.k[i] + 1
        else:
            tree_weight[i] = abs(c.k[i] - 1)
            if c.k[i] == 0 and not loop[i]:
                tree_odd[ea[i]] = not tree_odd[ea[i]]
                tree_odd[eb[i]] = not tree_odd[eb[i]]
    flip = _t_join(n, ea, eb, tree_weight, tree_odd)
    rebuilt = [
        (1 if c.k[i] else 0)
        if loop[i]
        else (1 + flip[i] if tree[i] else int(flip[i] == (c.k[i] == 0)))
        for i in range(m)
    ]
    best = None
    for parity in (repaired, rebuilt):
        parent = list(range(n))
        for i in range(m):
            if parity[i] == 1 and not loop[i]:
                parent[_root(parent, ea[i])] = _root(parent, eb[i])
        for i in range(m):
            if parity[i] == 2:
                ra, rb = _root(parent, ea[i]), _root(parent, eb[i])
                if ra == rb:
                    parity[i] = 0
                else:
                    parent[ra] = rb
        if best is None or c.cost(parity) < c.cost(best):
            best = parity
    return best


def _corridor_walk(adj: list, back: list, c: _Corridors, first: int) -> list:
    """The closed walk of a region whose cells are all targets (moves ``adj``, ports
    back ``back``, corridors ``c``), from node ``first``: each bridge twice, each ring
    once, each chain as :func:`_corridor_parities` says (at 0, its first ``ceil(k / 2)``
    corridor cells from ``a``'s end and the rest from ``b``'s), joined into one Euler
    circuit (:func:`_euler_circuit`). Time about linear in the cells."""
    ports = len(adj[0])
    mult = [[0] * ports for _ in range(len(adj))]

    def add(v: int, p: int, times: int) -> None:
        mult[v][p] += times
        mult[adj[v][p]][back[v][p]] += times

    for v, p in c.bridges:
        add(v, p, 2)
    for steps in c.rings:
        for v, p in steps:
            add(v, p, 1)
    for steps, k, parity in zip(c.steps, c.k, _corridor_parities(c), strict=True):
        if parity:
            for v, p in steps:
                add(v, p, parity)
        else:
            half = (k + 1) // 2  # the move between the two halves is left out
            for j, (v, p) in enumerate(steps):
                if j != half:
                    add(v, p, 2)
    return _euler_circuit(adj, back, mult, first)


def _corridor_bounds(c: _Corridors) -> dict[int, int]:
    """``{piece: bound}`` for every piece of ``c`` with a junction: the corridor bound
    of :func:`closed_walk_lower_bound` on a closed walk inside the piece through all its
    nodes."""
    junctions, ea, eb, odd = c.junction_graph()
    weight, base_odd = c.base_parities(ea, eb, odd)
    piece = [c.label[v] for v in junctions]
    packed = _ball_packing(len(junctions), ea, eb, weight, base_odd, piece)
    out: dict[int, int] = {}
    for i, k in enumerate(c.k):
        p = c.label[c.a[i]]
        out[p] = out.get(p, 0) + min(k + 1, 2 * k)
    scale = 1 << _PACKING_ROUNDS
    for p, r in packed.items():
        out[p] += -(-r // scale)
    return out


def _large_walk(
    nb: np.ndarray, back: np.ndarray, is_target: np.ndarray, c: _Corridors | None = None
) -> np.ndarray:
    """int ``[L]``: the closed walk of a region of more than :data:`SEARCH_TARGETS`
    targets (nodes ``0..n-1``, moves ``nb``, ports back ``back``, bool ``is_target``),
    from its first target: the shorter of the corridor walk (:func:`_corridor_walk`,
    given the region's corridors ``c`` when every cell is a target; the first on a tie)
    and the nearest-neighbour walk (:func:`_nearest_walk`). Time about linear in the
    cells."""
    adj = nb.tolist()
    first = int(np.flatnonzero(is_target)[0])
    best = _nearest_walk(adj, is_target.tolist(), first)
    if c is not None:
        other = _corridor_walk(adj, back.tolist(), c, first)
        if len(other) <= len(best):
            best = other
    return np.array(best, dtype=np.int64)


def _out_and_back(m: Map, c: int) -> np.ndarray:
    """The walk of a region whose one target is ``c``: out to the nearest target by c's
    shortest edge (the first such port) and back, ``[c, ..., v, ..., ]``, so that its
    robot enters c again and again (standing on c would never visit it again). On a
    grid, or a graph without waypoints, ``[c, n]``; on a graph the walk goes along the
    whole edge, as robots turn only at vertices; ``[c]`` on a map of one cell."""
    best: list[int] | None = None
    for first in m.neighbors[c].tolist():
        if first < 0:
            continue
        way, prev, cur = [first], c, first
        while not m.target[cur]:  # a waypoint has two ports: go on
            nxt = next(x for x in m.neighbors[cur].tolist() if x >= 0 and x != prev)
            prev, cur = cur, nxt
            way.append(cur)
        if best is None or len(way) < len(best):
            best = way
    if best is None:
        return np.array([c], dtype=np.int64)
    return np.array([c, *best, *best[-2::-1]], dtype=np.int64)


def closed_walk(
    m: Map, cells: np.ndarray | None = None, seed: int = 0, effort: str = "normal"
) -> np.ndarray:
    """A short closed walk through every target of a region: int ``[L]`` cells.

    ``w[i + 1]`` is one move from ``w[i]``, ``w[0]`` one move from ``w[L - 1]``; the
    walk visits each target of the region (every cell on a grid, the vertices on a
    graph) at least once and steps only on the region's cells, but for a region of one
    target; it starts on the region's lowest target. ``L`` is the length in moves. A
    region with one target ``c`` gives ``[c, n]`` on a grid (``L = 2``: out to c's first
    neighbour n, of another region, and back) and on a graph the way out along c's
    shortest edge to the target at its end and back (:func:`_out_and_back`); a region
    of two cells ``a < b``, both targets, ``[a, b]``.

    A travelling salesman tour over the targets in the region's own shortest-path
    metric (the metric closure of the targets; :func:`_shortest_tour`: nearest
    neighbour, 2-opt and or-opt, iterated with double-bridge kicks), each leg expanded
    into a shortest path inside the region (on a graph, along the edges' waypoints). A
    region whose cells form a tree takes the depth-first order instead (optimal). A
    region of more than :data:`SEARCH_TARGETS` targets has no table and no tour search:
    :func:`_large_walk` (the corridor walk, or the nearest-neighbour walk if shorter; the
    seed and effort do not matter there). Deterministic for a given ``seed``. ``effort``
    ("fast", "normal", "thorough") sets the kicks per target (:data:`EFFORTS`); "normal"
    takes about 2 s on a 700-cell map.

    Args:
        m: the map.
        cells: int ``[n]``, the region's cells (any order; default: all cells). Their
            induced subgraph must be connected and hold a target, else ValueError.
        seed: seed of the kicks.
        effort: search effort.
    """
    if effort not in EFFORTS:
        raise ValueError(f"effort must be one of {', '.join(EFFORTS)}, got {effort!r}")
    return _walk_cached(_MapKey(m), _cell_set(m, cells), int(seed), effort).copy()


def walk_is_closed_cover(m: Map, walk: np.ndarray, cells: np.ndarray | None = None) -> bool:
    """True if ``walk`` (int ``[L]``) is a closed walk of the region ``cells`` through all
    its targets.

    Every step, including ``walk[L - 1] -> walk[0]``, must be one move; every cell of the
    walk must be in ``cells`` (default: all cells) and every target of ``cells`` (on a
    grid: every cell) in the walk. A region with one target ``c`` has one walk, out and
    back (:func:`_out_and_back`: ``[c]`` only on a map of one cell).
    """
    w = np.asarray(walk)
    if w.ndim != 1 or w.size == 0 or not np.issubdtype(w.dtype, np.integer):
        return False
    if ((w < 0) | (w >= m.n_cells)).any():
        return False
    region = _cell_set(m, cells)
    lone = [c for c in region if m.target[c]]
    if len(lone) == 1:
        return w.tolist() == _out_and_back(m, lone[0]).tolist()
    visited = set(w.tolist())
    if not visited <= set(region):
        return False
    if any(m.target[c] and c not in visited for c in region):
        return False
    if w.size == 1:
        return True
    nxt = np.roll(w, -1)
    return bool((m.neighbors[w] == nxt[:, None]).any(axis=1).all())


# --- lower bound -------------------------------------------------------------------


def _held_karp_closed(D: np.ndarray, upper: int, iterations: int = _HK_ITERATIONS) -> float:
    """``max_pi L(pi)`` found by subgradient ascent: the Held-Karp bound of a closed tour.

    ``L(pi) = T_pi + e1 + e2 - 2 sum(pi)``, where ``T_pi`` is a minimum spanning tree
    of nodes ``1..n-1`` and ``e1 <= e2`` the two cheapest edges from node 0, all under
    the weights ``D[i, j] + pi[i] + pi[j]``. A tour is such a "1-tree" with every
    degree 2, of modified weight ``len + 2 sum(pi)``, so ``len >= L(pi)`` for every
    ``pi``. Polyak steps ``mu (upper - best) / |g|^2`` along the subgradient ``g``
    (degree - 2) towards ``upper`` (a known tour length); ``mu`` halves after 5 steps
    without progress. Every value evaluated is a valid bound; the best is returned.
    """
    Df = D.astype(np.float64)
    pi = np.zeros(D.shape[0])
    best, mu, stale = -math.inf, 2.0, 0
    for _ in range(iterations):
        w = Df + pi[:, None] + pi[None, :]
        tree, degree = _mst(w[1:, 1:])
        two = np.argsort(w[0, 1:], kind="stable")[:2] + 1
        value = tree + w[0, two].sum() - 2.0 * pi.sum()
        g = np.concatenate([[0], degree]).astype(np.float64) - 2.0
        g[two] += 1.0
        if value > best + 1e-9:
            best, stale = value, 0
        else:
            stale += 1
            if stale >= 5:
                mu, stale = mu / 2.0, 0
        norm = float(g @ g)
        if norm == 0.0 or math.ceil(best - 1e-6) >= upper or mu < 1e-3:
            break  # the 1-tree is a tour, or the bound is met, or the steps vanished
        pi += mu * max(upper - best, 1.0) / norm * g
    return best


@lru_cache(maxsize=256)
def _bound_cached(key: _MapKey, cells: tuple[int, ...]) -> int:
    m, arr = key.m, np.array(cells, dtype=np.int64)
    tgt = _region_targets(m, arr)
    nb = _local_neighbors(m, arr)
    _require_connected(m, arr, nb)
    if tgt.size == 1:  # out and back, exact (the robot turns at the nearest target)
        return len(_out_and_back(m, int(arr[tgt[0]])))
    if tgt.size == arr.size and arr.size <= 2:
        return arr.size
    if tgt.size < arr.size:
        return _steiner_bound(m, arr)
    if arr.size > SEARCH_TARGETS:
        return _large_bound(nb, _corridors_cached(key, cells))
    n_bridges, label = _two_edge_components(nb)
    total = 2 * n_bridges
    order = np.argsort(label, kind="stable")
    for part in np.split(arr[order], np.flatnonzero(np.diff(label[order])) + 1):
        if part.size < 2:
            continue
        sub = _local_neighbors(m, part)
        cheap = _parity_bound(m, part, sub)
        if part.size > SEARCH_TARGETS:  # no Held-Karp on a large piece (its [n, n] table)
            total += cheap
            continue
        D = all_pairs_distances(sub)
        tour = _nearest_neighbour(D)
        upper = int(D[tour, np.roll(tour, -1)].sum())
        held_karp = math.ceil(_held_karp_closed(D, upper) - 1e-6) if upper > cheap else cheap
        best = max(cheap, held_karp)
        total += best + best % 2 if _colours(sub)[1].all() else best
    return total


def _large_bound(nb: np.ndarray, c: _Corridors) -> int:
    """The bound of :func:`closed_walk_lower_bound` for a connected region of more than
    :data:`SEARCH_TARGETS` cells, all targets (moves ``nb``, corridors ``c``): the
    bound of the smaller regions (bridges, counts, colours, Held-Karp on the pieces of at
    most :data:`SEARCH_TARGETS` cells that are not rings, on a ring never above the
    counts), raised on each piece with a junction to its corridor bound
    (:func:`_corridor_bounds`), without a table of the region."""
    label = np.array(c.label, dtype=np.int64)
    colour, bipartite = _colours(nb, label)
    size = np.bincount(label)
    black = np.bincount(label, weights=colour, minlength=size.size).astype(np.int64)
    counts = np.where(bipartite, np.maximum(size, 2 * np.maximum(black, size - black)), size)
    corridor = _corridor_bounds(c)
    order = np.argsort(label, kind="stable")
    index = np.full(nb.shape[0], -1, dtype=np.int64)
    total = 2 * len(c.bridges)
    for part in np.split(order, np.flatnonzero(np.diff(label[order])) + 1):
        piece = int(label[part[0]])
        if part.size < 2:
            continue
        cheap = int(counts[piece])
        best = max(cheap, corridor.get(piece, 0))
        if piece in corridor and part.size <= SEARCH_TARGETS:
            index[part] = np.arange(part.size)
            sub = np.where(nb[part] >= 0, index[np.maximum(nb[part], 0)], -1)
            index[part] = -1
            D = all_pairs_distances(sub)
            tour = _nearest_neighbour(D)
            upper = int(D[tour, np.roll(tour, -1)].sum())
            if upper > cheap:
                best = max(best, math.ceil(_held_karp_closed(D, upper) - 1e-6))
        total += best + best % 2 if bipartite[piece] else best
    return total


def _required_bound(nb: np.ndarray, tgt: np.ndarray) -> int:
    """A lower bound on a closed walk in the connected graph ``nb`` through the nodes
    ``tgt`` (step 2 of the waypoint case of :func:`closed_walk_lower_bound`)."""
    if tgt.size == 1:
        return 1
    if tgt.size == 2:
        return 2 * int(bfs(nb, int(tgt[0]))[tgt[1]])
    colour, bipartite = _colours(nb)
    cheap = tgt.size
    if bipartite.all():
        b = int(colour[tgt].sum())
        cheap = max(cheap, 2 * b, 2 * (tgt.size - b))
    if nb.shape[0] > SEARCH_TARGETS:  # no Held-Karp on a large piece (its [n, n] table)
        return cheap + cheap % 2 if bipartite.all() else cheap
    D = all_pairs_distances(nb)
    DT = D[np.ix_(tgt, tgt)]
    tour = _nearest_neighbour(DT)
    upper = int(DT[tour, np.roll(tour, -1)].sum())
    held_karp = math.ceil(_held_karp_closed(DT, upper) - 1e-6) if upper > cheap else cheap
    best = max(cheap, held_karp)
    return best + best % 2 if bipartite.all() else best


def _steiner_bound(m: Map, cells: np.ndarray) -> int:
    """The bound of :func:`closed_walk_lower_bound` for a connected region ``cells`` with
    cells that are not targets (waypoints)."""
    cells = _prune_dead_ends(m, cells)
    nb = _local_neighbors(m, cells)
    is_target = m.target[cells]
    whole = _required_bound(nb, np.flatnonzero(is_target))
    if is_target.sum() <= 1:
        return whole
    bridges = _bridges(nb)
    if not bridges:
        return whole
    n_bridges, label = _two_edge_components(nb)
    # the bridges join the components into a tree: each must have targets on both sides
    n_comp = int(label.max()) + 1
    held = np.bincount(label, weights=is_target, minlength=n_comp).astype(np.int64)
    tree: list[list[int]] = [[] for _ in range(n_comp)]
    for u, v in bridges:
        tree[label[u]].append(int(label[v]))
        tree[label[v]].append(int(label[u]))
    parent, order, stack = [-1] * n_comp, [], [0]
    seen = {0}
    while stack:
        c = stack.pop()
        order.append(c)
        for d in tree[c]:
            if d not in seen:
                seen.add(d)
                parent[d] = c
                stack.append(d)
    below = held.copy()
    for c in reversed(order[1:]):
        below[parent[c]] += below[c]
    if any(below[c] == 0 or below[c] == below[0] for c in order[1:]):
        return whole  # a side of a bridge without target: no decomposition
    required = is_target.copy()
    for u, v in bridges:
        required[u] = required[v] = True
    total = 2 * n_bridges
    order = np.argsort(label, kind="stable")
    for part in np.split(order, np.flatnonzero(np.diff(label[order])) + 1):
        need = np.flatnonzero(required[part])
        if need.size >= 2:
            total += _required_bound(_local_neighbors(m, cells[part]), need)
    return max(whole, total)


def closed_walk_lower_bound(m: Map, cells: np.ndarray | None = None) -> int:
    """A proven lower bound on the length of any closed walk through every target of a region.

    *Every cell a target* (a grid, or a graph whose edges are all one move). Let W be a
    closed walk of ``L >= 2`` moves that visits all ``n >= 2`` cells of the region (its
    induced graph G connected; ``cells`` as in :func:`closed_walk`).

    1. *Bridges.* An edge whose removal disconnects G (a bridge) separates two sets of
       cells W must both visit; a closed walk crosses between them an even number of
       times, so at least twice. The 2-edge-connected components ``C_1..C_r`` (G without
       its bridges) form a tree joined by the bridges, so once W leaves ``C_i`` by a
       bridge at cell x it can only come back into ``C_i`` over that bridge, at x.
       Deleting those excursions from W leaves a closed walk ``W_i`` inside ``C_i`` (moves
       between cells of ``C_i`` only) that visits all of ``C_i``. Every move of W is a
       bridge crossing or a move of exactly one ``W_i``, so
       ``L >= 2 * bridges + sum_i L_i`` with ``L_i = 0`` for a one-cell component.
    2. *Each component* (``n_i >= 2`` cells, so at least 4 in a grid): ``L_i >= n_i``
       (each move enters one cell); if ``C_i`` is bipartite (a grid always is, by
       ``(row + col) % 2``; colours here come from a breadth-first 2-colouring), a closed
       walk alternates colours, has even length and visits each colour in ``L_i / 2``
       positions: ``L_i >= 2 * max(black_i, white_i)``; and ``L_i`` is at least the
       Held-Karp bound :func:`_held_karp_closed` of the travelling salesman tour over
       ``C_i`` in the shortest-path metric of ``C_i`` (``W_i``, listed by first visits,
       is such a tour of length <= ``L_i``). ``L_i`` being even (bipartite ``C_i``), the
       largest of the three is rounded up to even.
    3. *Corridors* (regions of more than :data:`SEARCH_TARGETS` cells, which take the
       Held-Karp bound only on pieces of at most that many cells: :func:`_large_bound`).
       Let ``C_i`` have a junction, a cell with at least 3 moves inside ``C_i``; its
       moves split into chains, paths from a junction through ``k >= 0`` cells of
       degree 2 to a junction (:class:`_Corridors`). ``W_i`` makes the ``k + 1`` moves
       of a chain ``m_0..m_k`` times; at a cell of degree 2 the two add up to an even
       number (a closed walk leaves a cell as often as it enters it), so all have one
       parity, the chain's. Odd: every move is made, ``>= k + 1`` moves on the chain.
       Even, ``k >= 1``: ``W_i`` is connected and visits the chain's cells and a
       junction, so at most one of the chain's moves is not made (two would cut off
       the cells between them) and the others are made twice or more, ``>= 2 k``. At
       a junction the odd chains meet an even number of times (a loop twice). So with
       each chain at its cheaper parity (even for ``k = 0``, else odd), costing
       ``min(k + 1, 2 k)``, and ``|k - 1|`` more at the other, the loops aside, the
       chains of ``W_i`` at their dearer parity form a T-join of the junctions that the
       cheaper parities leave odd: ``L_i >= sum min(k + 1, 2 k)`` plus the least weight
       of such a T-join, bounded below by disjoint balls round those junctions
       (:func:`_ball_packing`); rounded up, and to even if ``C_i`` is bipartite.

    For a tree (every edge a bridge) this is the exact ``2 (n - 1)``; for a ring,
    exactly n. The Held-Karp linear relaxation also splits over bridges (a bridge
    carries 2 in it), so this is at least the Held-Karp bound of the whole region, up
    to the subgradient's accuracy. Conventions: 2 for two cells; for one target c, the
    length of its out-and-back walk (:func:`_out_and_back`), exact: a walk that enters c
    again must leave it and turn back, at the nearest target on a graph (robots turn
    only at vertices), at the next cell on a grid.

    *Some cells not targets* (a graph's waypoints). First drop, again and again, the
    non-target cells with at most one neighbour left: a walk that enters such a dead
    end comes back the same way, and cutting the excursion out leaves a shorter walk
    through all targets, so the shortest walk lives in what remains, G'. For a set R
    of cells a closed walk in a connected graph H must visit (``r = |R|``), let
    ``B(H, R)`` be: 1 for one cell, ``2 d(a, b)`` for two; else the largest of ``r``
    (each takes a position of the walk), ``2 * max(black, white)`` counted over R if H
    is bipartite (same argument as above), and the Held-Karp bound of the tour over R
    in H's shortest-path metric (the walk listed by first visits of R is such a tour),
    rounded up to even if H is bipartite. The bound is ``B(G', targets)``, or if
    larger, the step-1 decomposition of G' when every bridge of G' has targets on both
    sides: each bridge is crossed at least twice, and the walk ``W_i`` left in
    component ``C_i`` visits its targets and the ends of its bridges (the walk crosses
    every bridge), so ``L >= 2 * bridges + sum_i B(C_i, R_i)`` over the components with
    ``|R_i| >= 2``. For a tree this is again exact: twice the edges of the smallest
    subtree holding every target.
    """
    return _bound_cached(_MapKey(m), _cell_set(m, cells))


def closed_walk_methods(m: Map, cells: np.ndarray | None = None) -> dict[str, str]:
    """How :func:`closed_walk` and :func:`closed_walk_lower_bound` compute a region's walk
    and bound (``walk_method``, ``walk_lower_bound_method``), for ``summary.json``."""
    region = _cell_set(m, cells)
    arr = np.array(region, dtype=np.int64)
    t = int(m.target[arr].sum())
    nb = _local_neighbors(m, arr)
    if t <= 2 or (t == arr.size and arr.size <= 2):
        return {"walk_method": "exact (at most two targets)", "walk_lower_bound_method": "exact"}
    if t > SEARCH_TARGETS and t < arr.size:
        walk = f"above {SEARCH_TARGETS} targets: the nearest-neighbour walk"
    elif t > SEARCH_TARGETS:
        walk = (
            f"above {SEARCH_TARGETS} targets: the shorter of the corridor walk (each corridor "
            "once, twice or in and back from both ends, parities by a greedy T-join, joined "
            "by a spanning tree; an Euler circuit) and the nearest-neighbour walk"
        )
    elif (nb >= 0).sum() // 2 == arr.size - 1:
        walk = "tree: depth-first order (optimal)"
    else:
        walk = "tour search over the targets' distances: nearest neighbour, 2-opt, or-opt, kicks"
    # the Held-Karp part runs on every piece of at most SEARCH_TARGETS cells
    large = arr.size > SEARCH_TARGETS
    if large and t == arr.size:  # the pieces: 2-edge-connected components
        label = _corridors_cached(_MapKey(m), region).label
        large = bool((np.bincount(label) > SEARCH_TARGETS).any())
    bound = "bridges, counts, colours and Held-Karp per 2-edge-connected piece"
    if t == arr.size > SEARCH_TARGETS:
        bound = (
            "bridges, counts, colours, corridor parities (disjoint balls round the odd "
            "junctions) and Held-Karp per 2-edge-connected piece"
        )
    if large:
        bound += f" (Held-Karp skipped on pieces of more than {SEARCH_TARGETS} cells)"
    return {"walk_method": walk, "walk_lower_bound_method": bound}


# --- partition ---------------------------------------------------------------------


def _farthest_seeds(dist: np.ndarray, k: int, rng: np.random.Generator) -> list[int]:
    """k nodes of the metric ``dist`` [n, n] spread out: a random first, then each the
    farthest from those chosen."""
    seeds = [int(rng.integers(dist.shape[0]))]
    near = dist[seeds[0]].copy()
    for _ in range(k - 1):
        seeds.append(int(np.argmax(near)))
        near = np.minimum(near, dist[seeds[-1]])
    return seeds


#: A graph's edges as chains of cells: ``(a, b, waypoints from a's end to b's)``.
Chains = list[tuple[int, int, list[int]]]


def _edge_chains(m: Map) -> Chains:
    """The edges between targets, each once (from its lower end), with their waypoints.

    Empty when every cell is a target (a grid, a graph of one-move edges) or when some
    non-target cell does not have exactly two neighbours (no chains to speak of): the
    partition then works cell by cell."""
    if m.target.all():
        return []
    deg = (m.neighbors >= 0).sum(axis=1)
    if (deg[~m.target] != 2).any():
        return []
    chains: Chains = []
    for a in np.flatnonzero(m.target).tolist():
        for first in m.neighbors[a].tolist():
            if first < 0:
                continue
            prev, cur, ways = a, first, []
            while not m.target[cur]:
                ways.append(cur)
                prev, cur = cur, next(int(x) for x in m.neighbors[cur] if x >= 0 and x != prev)
            if a < cur or (a == cur and ways and ways[0] < ways[-1]):
                chains.append((a, int(cur), ways))
    return chains


def _attach_waypoints(labels: np.ndarray, chains: Chains, which: list[int] | None = None) -> None:
    """Give the waypoints of each chain (``which``: their indices; default all) the region
    of the nearer end vertex (of ``a`` at the middle; all of it if both ends share a
    region). ``labels`` int ``[C]`` is changed in place."""
    for i in range(len(chains)) if which is None else which:
        a, b, ways = chains[i]
        la, lb = labels[a], labels[b]
        moves = len(ways) + 1
        for j, c in enumerate(ways, start=1):
            labels[c] = la if la == lb or 2 * j <= moves else lb


def _grow(
    m: Map, seeds: list[int], delays: list[float] | None = None, chains: Chains = ()
) -> np.ndarray:
    """int ``[C]``: region of each cell, by breadth-first search from all seeds at once.

    Region r holds ``seeds[r]`` from the start and spreads from it one move per step,
    starting after ``delays[r]`` steps (default 0). A cell joins the first region to
    reach it (ties to the lower region), from a cell of that region, so every region is
    connected and non-empty. With ``chains`` (a graph's edges), the waypoints then
    follow their edge's vertices (:func:`_attach_waypoints`).
    """
    labels = np.full(m.n_cells, -1, dtype=np.int64)
    labels[seeds] = np.arange(len(seeds))
    heap = [
        (d, r, s) for r, (s, d) in enumerate(zip(seeds, delays or [0.0] * len(seeds), strict=True))
    ]
    heapq.heapify(heap)
    while heap:
        t, r, c = heapq.heappop(heap)
        if labels[c] >= 0 and c != seeds[r]:
            continue
        labels[c] = r
        for nb in m.neighbors[c]:
            if nb >= 0 and labels[nb] < 0:
                heapq.heappush(heap, (t + 1, r, int(nb)))
    if chains:
        _attach_waypoints(labels, chains)
    return labels


def _medoids(dist: np.ndarray, labels: np.ndarray, k: int, target: np.ndarray) -> list[int]:
    """The target of each region with the least total distance to the region's targets
    (``target`` bool ``[C]``; on a grid every cell)."""
    out = []
    for r in range(k):
        members = np.flatnonzero((labels == r) & target)
        out.append(int(members[np.argmin(dist[np.ix_(members, members)].sum(axis=1))]))
    return out


def _region_cost(m: Map, cells: np.ndarray) -> int | None:
    """Estimated walk length of a region; None if disconnected or without a target.

    :func:`_parity_bound` of the region's cells, after dropping the dead-end chains of
    waypoints that no walk needs (:func:`_prune_dead_ends`; a grid keeps all its cells)."""
    nb = _local_neighbors(m, cells)
    if cells.size > 1 and components(nb).max() > 0:
        return None
    if not m.target[cells].any():
        return None
    kept = _prune_dead_ends(m, cells)
    if kept.size < cells.size:
        cells, nb = kept, _local_neighbors(m, kept)
    if m.target[cells].sum() == 1:  # a lone target's walk goes out and back (closed_walk)
        c = int(cells[m.target[cells]][0])
        return len(_out_and_back(m, c))
    return _parity_bound(m, cells, nb)


def _spread(costs: list[int]) -> tuple[int, int]:
    """Sort key of a partition by its region costs: the largest, then the sum of squares."""
    return max(costs), sum(c * c for c in costs)


def _delay_balance(
    m: Map, seeds: list[int], k: int, rounds: int = _DELAY_ROUNDS, chains: Chains = ()
) -> np.ndarray:
    """Regions grown from ``seeds`` with start delays tuned to even out their costs.

    Each round grows the regions (:func:`_grow`) and delays every region in proportion
    to how far its estimated walk length exceeds the mean; the best partition seen
    (:func:`_spread`) is returned.
    """
    delays = [0.0] * k
    best, best_key = None, None
    for _ in range(rounds):
        labels = _grow(m, seeds, delays, chains)
        costs = [_region_cost(m, np.flatnonzero(labels == r)) for r in range(k)]
        key = _spread(costs)
        if best_key is None or key < best_key:
            best, best_key = labels, key
        mean = sum(costs) / k
        delays = [d + _DELAY_STEP * (c - mean) / mean for d, c in zip(delays, costs, strict=True)]
        delays = [d - min(delays) for d in delays]
    return best


def _balance(m: Map, labels: np.ndarray, k: int, chains: Chains = ()) -> np.ndarray:
    """Move boundary cells between regions while that lowers the sorted costs.

    Repeatedly take the costliest region that has an improving move: a cell of it next
    to a cheaper region goes there if both regions stay connected and both new costs
    are below the old cost of the first. The costs sorted in decreasing order drop
    lexicographically at every move, so this ends. With ``chains`` (a graph with
    waypoints) the moves are of vertices instead (:func:`_best_vertex_move`).
    """
    labels = labels.copy()
    cost = [_region_cost(m, np.flatnonzero(labels == r)) for r in range(k)]
    chains_of: dict[int, list[int]] = {}
    for i, (a, b, _) in enumerate(chains):
        chains_of.setdefault(a, []).append(i)
        chains_of.setdefault(b, []).append(i)
    moved = True
    while moved:
        moved = False
        for r in sorted(range(k), key=lambda g: (-cost[g], g)):
            if chains:
                move = _best_vertex_move(m, labels, cost, r, chains, chains_of)
            else:
                move = _best_move(m, labels, cost, r)
            if move is not None:
                cell, target, cost_r, cost_t = move
                labels[cell] = target
                if chains:
                    _attach_waypoints(labels, chains, chains_of.get(cell, []))
                cost[r], cost[target] = cost_r, cost_t
                moved = True
                break
    return labels


def _best_vertex_move(
    m: Map,
    labels: np.ndarray,
    cost: list[int],
    r: int,
    chains: Chains,
    chains_of: dict[int, list[int]],
) -> tuple[int, int, int, int] | None:
    """:func:`_best_move` on a graph with waypoints: a vertex of region r that shares an
    edge with a cheaper region moves there, the waypoints of its edges following
    (:func:`_attach_waypoints`); (vertex, region, new cost of r, new cost there)."""
    members = np.flatnonzero(labels == r)
    vertices = members[m.target[members]]
    if vertices.size < 2:
        return None
    best = None
    for v in vertices.tolist():
        ends = {b if a == v else a for a, b, _ in (chains[i] for i in chains_of.get(v, []))}
        targets = sorted({int(labels[e]) for e in ends if cost[labels[e]] < cost[r]})
        if not targets:
            continue
        trial = labels.copy()
        cost_r = None
        for t in targets:
            trial[v] = t
            _attach_waypoints(trial, chains, chains_of[v])
            if cost_r is None:  # region r loses v and the same waypoints whatever t is
                cost_r = _region_cost(m, np.flatnonzero(trial == r))
                if cost_r is None or cost_r >= cost[r]:
                    break
            cost_t = _region_cost(m, np.flatnonzero(trial == t))
            if cost_t is not None and cost_t < cost[r]:
                if best is None or max(cost_r, cost_t) < max(best[2:]):
                    best = (v, t, cost_r, cost_t)
    return best


def _best_move(
    m: Map, labels: np.ndarray, cost: list[int], r: int
) -> tuple[int, int, int, int] | None:
    """The move of a boundary cell of region r that lowers ``max`` of the two costs most."""
    members = np.flatnonzero(labels == r)
    if members.size < 2:
        return None
    nb = m.neighbors[members]
    nb_label = np.where(nb >= 0, labels[np.maximum(nb, 0)], -1)
    best = None
    for i in np.flatnonzero(((nb_label >= 0) & (nb_label != r)).any(axis=1)):
        cell = int(members[i])
        targets = sorted({int(t) for t in nb_label[i] if t >= 0 and t != r and cost[t] < cost[r]})
        if not targets:
            continue
        cost_r = _region_cost(m, members[members != cell])
        if cost_r is None or cost_r >= cost[r]:
            continue
        for t in targets:
            cost_t = _region_cost(m, np.sort(np.append(np.flatnonzero(labels == t), cell)))
            if cost_t < cost[r] and (best is None or max(cost_r, cost_t) < max(best[2:])):
                best = (cell, t, cost_r, cost_t)
    return best


@lru_cache(maxsize=64)
def _partition_cached(key: _MapKey, k: int, seed: int) -> np.ndarray:
    m = key.m
    if k == 1:
        return np.zeros(m.n_cells, dtype=np.int64)
    dist = m.distances()
    targets = np.flatnonzero(m.target)
    spread = dist if targets.size == m.n_cells else dist[np.ix_(targets, targets)]
    seeds = targets[_farthest_seeds(spread, k, np.random.default_rng(seed))].tolist()
    chains = _edge_chains(m)
    labels = _grow(m, seeds, chains=chains)
    for _ in range(10):  # Lloyd steps: regrow from the regions' medoids
        seeds = _medoids(dist, labels, k, m.target)
        grown = _grow(m, seeds, chains=chains)
        if (grown == labels).all():
            break
        labels = grown
    labels = _delay_balance(m, seeds, k, chains=chains)
    return _balance(m, labels, k, chains)


def partition_regions(m: Map, k: int, seed: int = 0) -> np.ndarray:
    """int ``[C]``: region 0..k-1 of every cell; regions connected, each with a target.

    Seeds (targets) spread by farthest-point sampling on BFS distance (the first drawn
    with ``seed``); regions grown by simultaneous BFS from them over all cells and
    re-centred on their medoid targets a few times (k-means on the maze metric); the
    regions' start delays tuned to even out their estimated walk lengths
    (:func:`_delay_balance`); then boundary cells moved while that lowers the largest
    estimate (:func:`_balance`). The estimate of a region's walk is the
    bridge-and-colour part of :func:`closed_walk_lower_bound` (exact on trees and
    rings, 0-15% low on corridor loops), on a graph over the region's cells less its
    dead-end waypoint chains (:func:`_region_cost`). On a graph a region is thus its
    targets (vertices) plus waypoints: those of the edges its walk travels, and maybe
    some of an edge to another region, which its walk never enters. Deterministic given
    ``seed``. ``1 <= k <=`` the number of targets, else ValueError.
    """
    n = m.n_targets
    if not 1 <= k <= n:
        what = "targets (vertices)" if m.is_graph else "free cells"
        raise ValueError(f"k must be between 1 and the {n} {what} of map {m.name}, got {k}")
    return _partition_cached(_MapKey(m), int(k), int(seed)).copy()


def region_walks(m: Map, labels: np.ndarray, seed: int = 0) -> list[np.ndarray]:
    """The closed walk (:func:`closed_walk`) of each region 0..max(labels): int ``[L_r]`` each."""
    labels = np.asarray(labels)
    if labels.shape != (m.n_cells,):
        raise ValueError(f"labels must have shape ({m.n_cells},), got {labels.shape}")
    return [closed_walk(m, np.flatnonzero(labels == r), seed) for r in range(int(labels.max()) + 1)]
