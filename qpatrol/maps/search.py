"""Breadth-first searches on a map's moves that grow with the map, not its square.

Every function takes ``neighbors`` (int ``[C, D]``, the cell one move away by each port,
-1 for none: :attr:`qpatrol.maps.Map.neighbors`) and computes exact shortest-path
lengths in moves, so that nothing on the way of ``train``, ``sweep`` or ``maps import``
needs the ``[C, C]`` table of :func:`qpatrol.maps.core.all_pairs_distances`:

* :func:`bfs` and :func:`bfs_rows`: moves from one cell, or a few, to every cell;
* :func:`relax`: the moves to the nearest of a growing set of cells (the spread of
  robots over a map, :func:`qpatrol.world.place_agents`);
* :func:`diameter`: the longest shortest path, exactly, by iFUB (Crescenzi et al.
  2013, "On computing the diameter of real-world undirected graphs"), a few searches
  on most maps instead of one per cell.

With numba installed the searches on maps of at least
:data:`COMPILED_CELLS` cells run compiled; the numbers are the same either way.
"""

from __future__ import annotations

from collections import deque

import numpy as np

#: Maps of at least this many cells search with the compiled kernels, when numba is
#: installed (smaller ones in Python: no compile, already fast).
COMPILED_CELLS = 4_096

try:  # the compiled kernels (optional extra ``fast``)
    from numba import njit
except ImportError:  # pragma: no cover - numba is installed in the test environment
    njit = None


def _bfs_kernel(nb, source, dist, queue):  # pragma: no cover - compiled
    dist[source] = 0
    queue[0] = source
    head, tail = 0, 1
    while head < tail:
        c = queue[head]
        head += 1
        dc = dist[c] + 1
        for p in range(nb.shape[1]):
            x = nb[c, p]
            if x >= 0 and dist[x] < 0:
                dist[x] = dc
                queue[tail] = x
                tail += 1


def _relax_kernel(nb, source, near, queue):  # pragma: no cover - compiled
    near[source] = 0
    queue[0] = source
    head, tail = 0, 1
    while head < tail:
        c = queue[head]
        head += 1
        dc = near[c] + 1
        for p in range(nb.shape[1]):
            x = nb[c, p]
            if x >= 0 and near[x] > dc:
                near[x] = dc
                queue[tail] = x
                tail += 1


_compiled: list = []


def _kernels():
    """The compiled (bfs, relax) kernels, or None without numba."""
    if njit is None:
        return None
    if not _compiled:
        _compiled.append(
            (
                njit(cache=True, nogil=True)(_bfs_kernel),
                njit(cache=True, nogil=True)(_relax_kernel),
            )
        )
    return _compiled[0]


def _fast(neighbors: np.ndarray):
    if neighbors.shape[0] < COMPILED_CELLS:
        return None
    return _kernels()


def bfs(neighbors: np.ndarray, source: int) -> np.ndarray:
    """int ``[cells]``: moves from ``source`` to every cell (-1 if unreachable)."""
    n = neighbors.shape[0]
    dist = np.full(n, -1, dtype=np.int64)
    k = _fast(neighbors)
    if k is not None:
        k[0](np.ascontiguousarray(neighbors, dtype=np.int64), int(source), dist,
             np.empty(n, dtype=np.int64))  # fmt: skip
        return dist
    nb = neighbors.tolist()
    d = [-1] * n
    d[source] = 0
    queue = deque([source])
    pop, push = queue.popleft, queue.append
    while queue:
        c = pop()
        dc = d[c] + 1
        for x in nb[c]:
            if x >= 0 and d[x] < 0:
                d[x] = dc
                push(x)
    dist[:] = d
    return dist


def bfs_rows(neighbors: np.ndarray, sources, dtype=np.int64) -> np.ndarray:
    """``[S, cells]`` of ``dtype``: row i the moves from ``sources[i]`` (-1 unreachable)."""
    src = [int(s) for s in np.asarray(sources).ravel()]
    out = np.empty((len(src), neighbors.shape[0]), dtype=dtype)
    for i, s in enumerate(src):
        out[i] = bfs(neighbors, s)
    return out


def relax(neighbors: np.ndarray, source: int, near: np.ndarray) -> None:
    """Lower ``near`` (int64 ``[cells]``, moves to the nearest cell of a set, a large
    number where the set is empty) in place to the moves to the set with ``source``
    added: a search from ``source`` that goes on only where it comes nearer, so a set of
    K cells costs about ``cells x (1 + 1/2 + ... + 1/K)`` steps on an even spread."""
    k = _fast(neighbors)
    if k is not None:
        k[1](np.ascontiguousarray(neighbors, dtype=np.int64), int(source), near,
             np.empty(neighbors.shape[0], dtype=np.int64))  # fmt: skip
        return
    nb = neighbors.tolist()
    d = near.tolist()
    d[source] = 0
    queue = deque([source])
    pop, push = queue.popleft, queue.append
    while queue:
        c = pop()
        dc = d[c] + 1
        for x in nb[c]:
            if x >= 0 and d[x] > dc:
                d[x] = dc
                push(x)
    near[:] = d


def components(
    neighbors: np.ndarray, cut: set[tuple[int, int]] | frozenset = frozenset()
) -> np.ndarray:
    """int ``[cells]``: the connected component of each cell, numbered from 0 in order of
    their lowest cell; the moves ``(c, x)`` in ``cut`` left out (list both ways to cut
    an edge)."""
    n = neighbors.shape[0]
    label = np.full(n, -1, dtype=np.int64)
    nb = neighbors.tolist()
    lab = label.tolist()
    count = 0
    for s in range(n):
        if lab[s] >= 0:
            continue
        lab[s] = count
        stack = [s]
        while stack:
            c = stack.pop()
            for x in nb[c]:
                if x >= 0 and lab[x] < 0 and (not cut or (c, x) not in cut):
                    lab[x] = count
                    stack.append(x)
        count += 1
    label[:] = lab
    return label


def _component_diameter(neighbors: np.ndarray, cells: np.ndarray) -> int:
    """The diameter of the component of ``cells`` (int, its cells) by Takes and Kosters'
    BoundingDiameters ("Determining the diameter of small world networks", 2011): each
    search from a cell v of eccentricity e bounds every cell w's eccentricity by
    ``max(d(v, w), e - d(v, w)) <= ecc(w) <= e + d(v, w)``; the diameter lies between
    the largest lower and the largest upper bound, and a cell whose bounds can no longer
    move either drops out. Searches alternate from the cell of the largest upper bound
    and of the smallest lower bound, until the two bounds of the diameter meet."""
    if cells.size == 1:
        return 0
    lo = np.zeros(cells.size, dtype=np.int64)
    hi = np.full(cells.size, np.iinfo(np.int64).max // 4, dtype=np.int64)
    live = np.ones(cells.size, dtype=bool)
    low_bound, high_bound, turn = 0, int(hi[0]), 0
    while low_bound < high_bound and live.any():
        idx = np.flatnonzero(live)
        pick = idx[np.argmax(hi[idx])] if turn % 2 == 0 else idx[np.argmin(lo[idx])]
        turn += 1
        d = bfs(neighbors, int(cells[pick]))[cells]
        e = int(d.max())
        lo = np.maximum(lo, np.maximum(d, e - d))
        hi = np.minimum(hi, e + d)
        low_bound, high_bound = int(lo.max()), int(hi.max())
        live &= lo != hi
        live &= ~((hi <= low_bound) & (2 * lo >= high_bound))
        live[pick] = False
    return low_bound


def diameter(neighbors: np.ndarray) -> int:
    """The longest shortest path between two cells of one component, in moves (0 for
    one cell): what ``all_pairs_distances(neighbors).max()`` gives, without the table."""
    label = components(neighbors)
    order = np.argsort(label, kind="stable")
    cuts = np.flatnonzero(np.diff(label[order])) + 1
    return max(_component_diameter(neighbors, part) for part in np.split(order, cuts))
