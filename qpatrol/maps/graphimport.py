"""Patrol graphs from other simulators -> qpatrol graph maps: the steps both importers share.

A reader (:mod:`qpatrol.maps.patrolling_sim`, :mod:`qpatrol.maps.simpatrol`) turns its file
into a :class:`SourceGraph`: vertices (with positions, or none), undirected edges with a
length each, and the charging stations the file names, if any. :func:`to_graph_map` then

- **lays the graph out** when the file gives no positions (:func:`layout`: classical MDS
  of the shortest-path length matrix, then stress majorisation; above
  :data:`EXACT_LAYOUT_MAX` vertices the near-linear :func:`pivot_layout`), so that it
  can be drawn;
- **cuts each edge into moves**: an edge of length ``l`` becomes
  ``max(1, floor(l / step + 1/2))`` unit moves (``--edge-step``, default the shortest
  edge, so that it is one move), or one move each (``--unit-edges``);
- **places starts and stations** on vertices as the ROS importer places them on cells
  (:func:`qpatrol.maps.importer.place`): farthest-point sampling on the shortest-path
  distance in moves, the first near the graph's middle; stations never on a start and on
  vertices of degree 2 or more while there are any. Waypoints inside edges get neither.

and writes the map text (:func:`qpatrol.maps.graph.render_graph_map`).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from qpatrol.maps import (
    MAX_CELLS,
    MAX_MAGNITUDE,
    MAX_MAP_BYTES,
    NO_DOT,
    SMALL_DOT,
    Map,
    MapError,
    parse_map,
)
from qpatrol.maps.graph import GraphSpec, build_graph_map, render_graph_map
from qpatrol.maps.importer import _bfs, _farthest, default_stations
from qpatrol.util.inputs import InputError, read_text_capped

__all__ = [
    "EXACT_LAYOUT_MAX",
    "MAX_CELLS",
    "MAX_SOURCE_BYTES",
    "GraphImportError",
    "ImportedGraph",
    "SourceGraph",
    "edge_moves",
    "layout",
    "pivot_layout",
    "shortest_lengths",
    "stress",
    "to_graph_map",
]

#: Largest patrolling_sim or SimPatrol file read (the XML tree takes about 15 times its
#: size in memory).
MAX_SOURCE_BYTES = 32 << 20
#: Largest graph laid out exactly (MDS of the V x V path length matrix, then stress
#: majorisation: V^3 time, V^2 memory); larger ones get the near-linear pivot layout.
EXACT_LAYOUT_MAX = 500
#: Pivots of the large-graph layout (:func:`pivot_layout`).
LAYOUT_PIVOTS = 12


class GraphImportError(MapError):
    """A graph file that cannot be imported; one line naming the file and the place."""


@dataclass
class SourceGraph:
    """A patrol graph as read from another simulator's file.

    Attributes:
        kind: what the file is ("patrolling_sim graph", "SimPatrol graph").
        path: the file.
        labels: the file's vertex ids, one per vertex (vertex i of the map is labels[i]).
        xy: float ``[V, 2]`` vertex positions, or None when the file gives none.
        edges: float ``[E, 3]``: (a, b, length) per undirected edge, a < b, sorted.
        stations: bool ``[V]``, vertices the file marks as charging stations (all False
            when it marks none).
        unit: the unit of the lengths ("px", "" for none).
        facts: what the description should say about the source (one clause).
        notes: what the reader changed (merged parallel edges), for the description.
    """

    kind: str
    path: Path
    labels: tuple[str, ...]
    xy: np.ndarray | None
    edges: np.ndarray
    stations: np.ndarray
    unit: str = ""
    facts: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        """Number of vertices."""
        return len(self.labels)


@dataclass(frozen=True)
class ImportedGraph:
    """The result of a graph import.

    Attributes:
        text: the qpatrol graph map file's content.
        spec: the graph ``text`` renders (:func:`qpatrol.maps.graph.render_graph_map`).
        map: the parsed :class:`Map` of ``text``.
        step: the edge step used (None for ``--unit-edges``).
        source: what was read.
        farthest_station: most moves from any vertex to its nearest station (-1: none).
    """

    text: str
    spec: GraphSpec
    map: Map
    step: float | None
    source: SourceGraph
    farthest_station: int


def check_connected(n: int, edges: np.ndarray, labels: tuple[str, ...], where: str) -> None:
    """Raise :class:`GraphImportError` unless every vertex can be reached from vertex 0."""
    adj: list[list[int]] = [[] for _ in range(n)]
    for a, b in edges[:, :2].astype(np.int64).tolist():
        adj[a].append(b)
        adj[b].append(a)
    seen = np.zeros(n, dtype=bool)
    seen[0] = True
    stack = [0]
    while stack:
        for w in adj[stack.pop()]:
            if not seen[w]:
                seen[w] = True
                stack.append(w)
    if not seen.all():
        bad = int(np.flatnonzero(~seen)[0])
        raise GraphImportError(
            f"{where}: vertex {labels[bad]} cannot be reached from vertex {labels[0]} "
            f"({int((~seen).sum())} of {n} vertices cut off; the graph must be connected)"
        )


def merge_parallel(
    pairs: dict[tuple[int, int], list[float]], labels: tuple[str, ...]
) -> tuple[np.ndarray, list[str]]:
    """One edge per vertex pair, the shortest of those the file gives.

    Args:
        pairs: (a, b) with a < b -> the lengths of every edge the file gives between them.

    Returns float ``[E, 3]`` (a, b, length) sorted by (a, b), and a note per merged pair.
    """
    rows = []
    merged = []
    for (a, b), lengths in sorted(pairs.items()):
        rows.append((a, b, min(lengths)))
        if len(lengths) > 1:
            merged.append(f"{labels[a]}-{labels[b]}")
    notes = []
    if merged:
        notes.append(
            f"{len(merged)} vertex pair(s) joined by parallel edges kept only the shortest "
            f"({', '.join(merged[:5])}{', ...' if len(merged) > 5 else ''})"
        )
    return np.array(rows, dtype=np.float64).reshape(-1, 3), notes


def edge_moves(lengths: np.ndarray, step: float | None) -> np.ndarray:
    """int ``[E]``: the moves of each edge, ``max(1, floor(length / step + 1/2))``.

    ``step`` None: one move per edge (``--unit-edges``).
    """
    lengths = np.asarray(lengths, dtype=np.float64)
    if step is None:
        return np.ones(lengths.shape, dtype=np.int64)
    return np.maximum(1, np.floor(lengths / step + 0.5)).astype(np.int64)


def check_cells(g: SourceGraph, step: float | None) -> None:
    """Raise :class:`GraphImportError` if cutting ``g``'s edges at ``step`` makes more than
    :data:`MAX_CELLS` cells; counted in floating point, before any integer is made."""
    unit = f" {g.unit}" if g.unit else ""
    if g.n > MAX_CELLS:
        raise GraphImportError(
            f"{g.path}: {g.n:,} vertices; allowed: at most {MAX_CELLS:,} cells in a map"
        )
    if step is None or not g.edges.shape[0]:
        return
    moves = np.maximum(1.0, np.floor(g.edges[:, 2] / step + 0.5))
    total = g.n + float((moves - 1.0).sum())
    if total > MAX_CELLS:
        i = int(np.argmax(moves))
        a, b = int(g.edges[i, 0]), int(g.edges[i, 1])
        raise GraphImportError(
            f"{g.path}: edge step {step:g}{unit} makes {_count(total)} cells, more than the "
            f"{MAX_CELLS:,} a map may have (the longest edge, {g.labels[a]}-{g.labels[b]} of "
            f"length {g.edges[i, 2]:g}, alone makes {_count(moves[i])} moves); use a larger "
            "--edge-step, or --unit-edges"
        )


def _count(x: float) -> str:
    """A whole count held in a float: its digits while exact, else 3 significant ones."""
    return f"{x:.0f}" if x < 2**53 else f"{x:.3g}"


def shortest_lengths(n: int, edges: np.ndarray) -> np.ndarray:
    """float ``[V, V]``: shortest-path length between vertices (inf if unreachable).

    Floyd-Warshall, one numpy pass per intermediate vertex (V^3 / numpy speed).
    """
    d = np.full((n, n), np.inf)
    np.fill_diagonal(d, 0.0)
    a = edges[:, 0].astype(np.int64)
    b = edges[:, 1].astype(np.int64)
    d[a, b] = np.minimum(d[a, b], edges[:, 2])
    d[b, a] = np.minimum(d[b, a], edges[:, 2])
    for k in range(n):
        np.minimum(d, d[:, k, None] + d[None, k, :], out=d)
    return d


def layout(n: int, edges: np.ndarray, iterations: int = 300) -> np.ndarray:
    """float ``[V, 2]``: vertex positions whose distances follow the path lengths.

    Up to :data:`EXACT_LAYOUT_MAX` vertices: classical MDS of the shortest-path length
    matrix (numpy ``eigh``), then stress majorisation (SMACOF, weights ``1/d^2``) until
    the stress stops falling (at most ``iterations`` rounds). Larger graphs: the
    near-linear :func:`pivot_layout` (no V x V matrix). Finally centred, turned onto its
    principal axes and each axis flipped so that its third moment is >= 0.
    Deterministic: no random start.

    Args:
        n: number of vertices (connected by ``edges``).
        edges: float ``[E, 3]``: (a, b, length) per edge.
    """
    if n == 1:
        return np.zeros((1, 2))
    if n > EXACT_LAYOUT_MAX:
        x = pivot_layout(n, edges)
    else:
        d = shortest_lengths(n, edges)
        sq = d**2
        j = np.eye(n) - 1.0 / n
        b = -0.5 * j @ sq @ j
        vals, vecs = np.linalg.eigh(b)
        order = np.argsort(vals)[::-1][:2]
        x = vecs[:, order] * np.sqrt(np.maximum(vals[order], 0.0))
        if x.shape[1] < 2:
            x = np.column_stack([x, np.zeros(n)])
        x = _smacof(d, x, iterations)
    x -= x.mean(axis=0)
    cov = x.T @ x
    _, axes = np.linalg.eigh(cov)
    x = x @ axes[:, ::-1]
    third = (x**3).sum(axis=0)
    scale = np.abs(x).max() or 1.0
    x[:, third < -1e-9 * scale**3 * n] *= -1.0
    return x


def pivot_layout(n: int, edges: np.ndarray, pivots: int = LAYOUT_PIVOTS) -> np.ndarray:
    """float ``[V, 2]``: a layout of a large graph in ``O(pivots x E log V)`` time and
    ``O(pivots x V)`` memory (pivot MDS, Brandes and Pich 2006).

    Shortest-path lengths (Dijkstra) from ``pivots`` vertices chosen by farthest-point
    sampling (the first is vertex 0), classical MDS of that ``V x pivots`` block (the top
    two singular vectors of its double-centred squares), then one scale so that the drawn
    edges are as long as their lengths in the least-squares sense. Deterministic.
    """
    adj: list[list[tuple[int, float]]] = [[] for _ in range(n)]
    for a, b, w in edges.tolist():
        adj[int(a)].append((int(b), w))
        adj[int(b)].append((int(a), w))
    k = min(pivots, n)
    cols = np.empty((n, k))
    near = np.full(n, np.inf)
    src = 0
    for i in range(k):
        cols[:, i] = _dijkstra(adj, src)
        np.minimum(near, cols[:, i], out=near)
        src = int(np.argmax(near))
    sq = cols**2
    c = -0.5 * (sq - sq.mean(axis=0) - sq.mean(axis=1, keepdims=True) + sq.mean())
    u, sv, _ = np.linalg.svd(c, full_matrices=False)
    x = u[:, :2] * sv[:2]
    if x.shape[1] < 2:
        x = np.column_stack([x, np.zeros(n)])
    a = edges[:, 0].astype(np.int64)
    b = edges[:, 1].astype(np.int64)
    drawn = np.linalg.norm(x[a] - x[b], axis=1)
    fit = float((drawn * edges[:, 2]).sum())
    norm = float((drawn**2).sum())
    return x * (fit / norm) if norm > 0 and fit > 0 else x


def _dijkstra(adj: list[list[tuple[int, float]]], source: int) -> np.ndarray:
    """float ``[V]``: shortest-path lengths from ``source`` over ``adj`` (inf: unreachable)."""
    dist = [math.inf] * len(adj)
    dist[source] = 0.0
    heap = [(0.0, source)]
    pop, push = heapq.heappop, heapq.heappush
    while heap:
        du, u = pop(heap)
        if du > dist[u]:
            continue
        for v, w in adj[u]:
            dv = du + w
            if dv < dist[v]:
                dist[v] = dv
                push(heap, (dv, v))
    return np.array(dist)


def stress(d: np.ndarray, x: np.ndarray) -> float:
    """Weighted stress ``sum_{i<j} (|x_i - x_j| - d_ij)^2 / d_ij^2`` of a layout."""
    iu = np.triu_indices(d.shape[0], 1)
    dist = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=2)[iu]
    target = d[iu]
    ok = target > 0
    return float((((dist[ok] - target[ok]) / target[ok]) ** 2).sum())


def _smacof(d: np.ndarray, x: np.ndarray, iterations: int) -> np.ndarray:
    n = d.shape[0]
    w = np.zeros_like(d)
    pos = d > 0
    w[pos] = 1.0 / d[pos] ** 2
    v = -w.copy()
    np.fill_diagonal(v, w.sum(axis=1))
    v_pinv = np.linalg.pinv(v)
    last = stress(d, x)
    for _ in range(iterations):
        dist = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=2)
        ratio = np.zeros_like(d)
        ok = dist > 1e-12
        ratio[ok] = w[ok] * d[ok] / dist[ok]
        bm = -ratio
        np.fill_diagonal(bm, ratio.sum(axis=1))
        x = v_pinv @ (bm @ x)
        now = stress(d, x)
        if last - now < 1e-9 * max(last, 1e-12) * n:
            break
        last = now
    return x


def _round6(a: np.ndarray) -> np.ndarray:
    """Positions as the map text writes them (6 significant digits), so that a map built
    here and one parsed back from its text hold the same numbers."""
    return np.array([[float(f"{v:.6g}") for v in row] for row in a], dtype=np.float64).reshape(
        -1, 2
    )


def to_graph_map(
    g: SourceGraph,
    name: str,
    agents: int = 4,
    stations: int | None = None,
    edge_step: float | None = None,
    unit_edges: bool = False,
) -> ImportedGraph:
    """The qpatrol graph map of ``g`` (module doc): moves, layout, starts and stations.

    Args:
        name: the map's name.
        agents: start vertices to place (start=0..agents-1).
        stations: charging stations to place by farthest-point sampling; None: the file's
            own stations if it marks any, else one per 150 vertices rounded up.
        edge_step: the length of one move (None: the shortest edge).
        unit_edges: every edge one move (``edge_step`` must then be None).
    """
    where = str(g.path)
    if unit_edges and edge_step is not None:
        raise GraphImportError("--edge-step and --unit-edges exclude each other; give one")
    if g.edges.shape[0] == 0 and g.n > 1:
        raise GraphImportError(f"{where}: the graph has no edge")
    lengths = g.edges[:, 2]
    if unit_edges:
        step = None
    elif edge_step is None:
        step = float(lengths.min()) if lengths.size else 1.0
    else:
        if not (math.isfinite(edge_step) and edge_step > 0):
            raise GraphImportError(f"edge step: {edge_step} is not a length > 0")
        step = float(edge_step)
    check_cells(g, step)
    moves = edge_moves(lengths, step)
    edges = np.column_stack([g.edges[:, :2].astype(np.int64), moves]).reshape(-1, 3)
    xy = g.xy if g.xy is not None else layout(g.n, g.edges)
    xy = _round6(xy)
    if not np.all(np.abs(xy) <= MAX_MAGNITUDE):
        raise GraphImportError(
            f"{where}: the positions reach {float(np.nanmax(np.abs(xy))):g}; allowed: at most "
            f"{MAX_MAGNITUDE:g} in absolute value (shorter edges, or a --edge-step)"
        )
    n = g.n
    labels = g.labels if any(lab != str(i) for i, lab in enumerate(g.labels)) else ("",) * n
    bare = GraphSpec(
        name,
        "",
        xy,
        edges,
        np.full(n, SMALL_DOT),
        np.zeros(n, bool),
        np.zeros(0, np.int64),
        labels,
    )
    cells = build_graph_map(bare, where)
    starts, homes, how = _place(cells, g, agents, stations)
    station = np.zeros(n, dtype=bool)
    station[homes] = True
    dot = np.where(station, NO_DOT, SMALL_DOT)
    description = _description(g, step, moves, len(starts), len(homes), how)
    spec = GraphSpec(name, description, xy, edges, dot, station, starts, labels)
    text = render_graph_map(spec)
    if len(text) > MAX_MAP_BYTES:  # characters: at least one byte each
        raise GraphImportError(
            f"{where}: the map text would be {len(text):,} characters, more than the "
            f"{MAX_MAP_BYTES:,} bytes a map file may have"
        )
    m = parse_map(text, source=f"<{name}>")
    far = int(_bfs(m.neighbors, list(map(int, homes)))[m.target].max()) if len(homes) else -1
    return ImportedGraph(text=text, spec=spec, map=m, step=step, source=g, farthest_station=far)


def _place(
    cells: Map, g: SourceGraph, agents: int, stations: int | None
) -> tuple[np.ndarray, np.ndarray, str]:
    """Start and station vertices (module doc); and how the stations were chosen."""
    n = g.n
    if agents < 0:
        raise GraphImportError(f"agents: {agents}; allowed: 0 or more")
    if stations is not None and stations < 0:
        raise GraphImportError(f"stations: {stations}; allowed: 0 or more")
    vertex = np.zeros(cells.n_cells, dtype=bool)
    vertex[:n] = True
    given = np.flatnonzero(g.stations)
    if stations is None and given.size:
        n_st, how = int(given.size), "the file's"
    else:
        n_st = default_stations(n) if stations is None else stations
        how = "farthest-point"
    if agents + n_st > n or n_st >= n:
        raise GraphImportError(
            f"{g.path}: {n} vertices cannot hold {agents} starts, {n_st} charging stations "
            "and a dot; lower --agents or --stations"
        )
    if how == "the file's":
        free = vertex.copy()
        free[given] = False
        starts = _farthest(cells.neighbors, free, agents, [])
        homes = given.tolist()
    else:
        starts = _farthest(cells.neighbors, vertex, agents, [])
        not_start = vertex.copy()
        not_start[starts] = False
        homes = _farthest(cells.neighbors, not_start & (cells.degree >= 2), n_st, [])
        homes = _farthest(cells.neighbors, not_start, n_st, homes)
    return np.array(starts, dtype=np.int64), np.array(sorted(homes), dtype=np.int64), how


def _description(
    g: SourceGraph, step: float | None, moves: np.ndarray, agents: int, homes: int, how: str
) -> str:
    unit = f" {g.unit}" if g.unit else ""
    if step is None:
        cut = "every edge one move (--unit-edges)"
    else:
        cut = (
            f"edge step {step:g}{unit} (moves = max(1, round(length / step)): "
            f"{moves.min()}-{moves.max()})"
        )
    pos = (
        "positions as in the file"
        if g.xy is not None
        else "positions laid out by MDS"
        if g.n <= EXACT_LAYOUT_MAX
        else f"positions laid out by pivot MDS ({LAYOUT_PIVOTS} pivots)"
    )
    st = f"{homes} charging station{'' if homes == 1 else 's'}"
    placed = (
        f"{agents} starts by farthest-point sampling and the file's {st}"
        if how == "the file's"
        else f"{agents} starts and {st} placed by farthest-point sampling"
    )
    parts = [f"imported from {g.kind} {g.path.name} ({g.facts})", cut, pos, placed, *g.notes]
    return "; ".join(parts)


def read_text(path: Path, noun: str = "a graph file") -> str:
    """A source file's text; a missing or unreadable file, anything but a regular file and
    a file of more than :data:`MAX_SOURCE_BYTES` are a one-line error."""
    try:
        return read_text_capped(path, MAX_SOURCE_BYTES, noun)
    except FileNotFoundError:
        raise GraphImportError(f"{path}: no such file") from None
    except InputError as e:
        raise GraphImportError(str(e)) from None
    except (OSError, UnicodeDecodeError) as e:
        why = getattr(e, "strerror", None) or str(e)
        raise GraphImportError(f"{path}: cannot read ({why})") from None
