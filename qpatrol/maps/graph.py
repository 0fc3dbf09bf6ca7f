"""Patrol graphs as qpatrol maps: vertices joined by edges of whole moves.

A graph map is a text file (format in ``docs/model.md``, "Maps")::

    ; name: triangle
    ; description: three rooms
    ; kind: graph
    v 0 0.0 0.0 start=0
    v 1 4.0 0.0 station
    v 2 2.0 3.0
    e 0 1 2
    e 1 2 1
    e 2 0 3

``v ID X Y [FLAGS]`` is a vertex: ``ID`` counts 0..V-1 (each once, any order), ``X Y``
its position (any unit, y up). Flags: ``station`` (a charging station, no dot),
``start=K`` (agent K starts there), ``big`` (a big dot), ``nodot`` (no dot),
``label=TEXT`` (the id the source file used). Every other vertex holds a dot.
``e A B MOVES`` is an undirected edge of ``MOVES >= 1`` unit moves between vertices A
and B. Lines starting with ``;`` are comments.

**Cells.** Vertex ``i`` is cell ``i``. An edge of ``m`` moves adds ``m - 1`` waypoint
cells, numbered after the vertices in the order of the edges in the file, from A's end
to B's. Waypoints are not targets: they hold no dot and no measure counts them.

**Ports.** A vertex's ports are its edges in file order (port 0 is the first edge that
names it); a waypoint's port 0 leads towards A, port 1 towards B. ``D`` is the largest
degree. A robot's heading is the port of its cell through which it arrived
(:attr:`qpatrol.maps.Map.entry`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from qpatrol.maps.core import (
    BIG,
    MAX_CELL_PORTS,
    MAX_CELLS,
    MAX_MAGNITUDE,
    NO_DOT,
    SMALL_DOT,
    Map,
    MapError,
    bfs,
)
from qpatrol.util.inputs import short_repr

__all__ = [
    "GraphSpec",
    "build_graph_map",
    "graph_summary",
    "parse_graph_map",
    "render_graph_map",
]


class GraphSpec:
    """A patrol graph before it becomes cells: what a graph map file says.

    Attributes:
        name, description: as in the file's comments.
        xy: float ``[V, 2]``, vertex positions.
        edges: int ``[E, 3]``, (a, b, moves) per edge, in file order.
        dot: int ``[V]``, dot kind per vertex (0 none, 1 dot, 2 big dot).
        station: bool ``[V]``.
        starts: int ``[n]``, the start vertex of agent k.
        labels: the source file's vertex ids ("" where none was given).
    """

    def __init__(
        self,
        name: str,
        description: str,
        xy: np.ndarray,
        edges: np.ndarray,
        dot: np.ndarray,
        station: np.ndarray,
        starts: np.ndarray,
        labels: tuple[str, ...],
    ) -> None:
        self.name, self.description = name, description
        self.xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        self.edges = np.asarray(edges, dtype=np.int64).reshape(-1, 3)
        self.dot = np.asarray(dot, dtype=np.int64)
        self.station = np.asarray(station, dtype=bool)
        self.starts = np.asarray(starts, dtype=np.int64)
        self.labels = tuple(labels)


def _number(tok: str, where: str, what: str) -> float:
    try:
        x = float(tok)
    except ValueError:
        raise MapError(f"{where}: {what} {short_repr(tok, 40)} is not a number") from None
    if not math.isfinite(x):
        raise MapError(f"{where}: {what} {short_repr(tok, 40)} is not a finite number")
    if abs(x) > MAX_MAGNITUDE:
        raise MapError(
            f"{where}: {what} {short_repr(tok, 40)} is out of range; allowed: at most "
            f"{MAX_MAGNITUDE:g} in absolute value"
        )
    return x


def _integer(tok: str, where: str, what: str, low: int, high: int | None = None) -> int:
    digits = tok.lstrip("+-").lstrip("0")
    if len(digits) > 30 and digits.isdigit():
        # int() of a token of thousands of digits is slow, or an error of its own
        raise MapError(f"{where}: {what} of {len(digits):,} digits is out of range")
    try:
        x = int(tok)
    except ValueError:
        raise MapError(f"{where}: {what} {short_repr(tok, 40)} is not a whole number") from None
    if x < low:
        raise MapError(f"{where}: {what} {x} must be at least {low}")
    if high is not None and x > high:
        raise MapError(f"{where}: {what} {x:,}; allowed: at most {high:,}")
    return x


def parse_graph_spec(text: str, source: str = "<string>") -> GraphSpec:
    """Read a graph map's text into a :class:`GraphSpec`; :class:`MapError` names file:line."""
    name = Path(source).stem if source != "<string>" else "graph"
    description = ""
    vertices: dict[int, tuple[int, float, float, list[str]]] = {}
    edge_rows: list[tuple[int, int, int, int]] = []
    waypoints = 0  # cells inside the edges so far: refused past MAX_CELLS as they come
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        where = f"{source}:{lineno}"
        if not line:
            continue
        if line.startswith(";"):
            body = line[1:].strip()
            low = body.lower()
            if low.startswith("name:"):
                name = body[5:].strip() or name
            elif low.startswith("description:"):
                description = body[12:].strip()
            continue
        tok = line.split()
        if tok[0] == "v":
            if len(tok) < 4:
                raise MapError(
                    f"{where}: a vertex line is 'v ID X Y [FLAGS]', got {short_repr(line)}"
                )
            vid = _integer(tok[1], where, "vertex id", 0, MAX_CELLS - 1)
            if vid in vertices:
                raise MapError(f"{where}: vertex {vid} repeated (first on line {vertices[vid][0]})")
            x = _number(tok[2], where, "x")
            y = _number(tok[3], where, "y")
            vertices[vid] = (lineno, x, y, tok[4:])
        elif tok[0] == "e":
            if len(tok) != 4:
                raise MapError(f"{where}: an edge line is 'e A B MOVES', got {short_repr(line)}")
            a = _integer(tok[1], where, "vertex", 0, MAX_CELLS - 1)
            b = _integer(tok[2], where, "vertex", 0, MAX_CELLS - 1)
            moves = _integer(tok[3], where, "moves", 1)
            waypoints += moves - 1
            if len(vertices) + waypoints > MAX_CELLS:
                raise MapError(
                    f"{where}: edge {a}-{b} of {moves:,} moves takes the map to "
                    f"{len(vertices) + waypoints:,} cells (vertices and waypoints so far); "
                    f"allowed: at most {MAX_CELLS:,} cells (refused before building them)"
                )
            edge_rows.append((lineno, a, b, moves))
        else:
            raise MapError(
                f"{where}: unknown line kind {short_repr(tok[0], 40)} (allowed: v, e, ; comment)"
            )
    if len(vertices) + waypoints > MAX_CELLS:  # vertex lines after the edges
        raise MapError(
            f"{source}: {len(vertices):,} vertices and {waypoints:,} waypoints inside the "
            f"edges make more than {MAX_CELLS:,} cells, the most a map may have (refused "
            "before building it)"
        )
    n = len(vertices)
    if n == 0:
        raise MapError(f"{source}: the graph has no vertex")
    for vid in vertices:
        if vid >= n:
            missing = min(set(range(n)) - set(vertices))
            raise MapError(
                f"{source}:{vertices[vid][0]}: vertex ids must be 0..{n - 1} without gaps; "
                f"{missing} is missing"
            )
    xy = np.zeros((n, 2))
    dot = np.full(n, SMALL_DOT, dtype=np.int64)
    station = np.zeros(n, dtype=bool)
    labels = [""] * n
    start_at: dict[int, tuple[int, int]] = {}
    for vid, (lineno, x, y, flags) in vertices.items():
        where = f"{source}:{lineno}"
        xy[vid] = (x, y)
        for flag in flags:
            key, _, value = flag.partition("=")
            if key == "station" and not value:
                station[vid] = True
                dot[vid] = NO_DOT
            elif key == "big" and not value:
                dot[vid] = BIG
            elif key == "nodot" and not value:
                dot[vid] = NO_DOT
            elif key == "label" and value:
                labels[vid] = value
            elif key == "start" and value:
                k = _integer(value, where, "start", 0)
                if k in start_at:
                    raise MapError(f"{where}: start={k} repeated (first on line {start_at[k][1]})")
                start_at[k] = (vid, lineno)
            else:
                raise MapError(
                    f"{where}: unknown vertex flag {short_repr(flag, 40)} "
                    "(allowed: station, start=K, big, nodot, label=TEXT)"
                )
        if station[vid] and dot[vid] == BIG:
            raise MapError(f"{where}: a station holds no dot, so it cannot be 'big'")
    for k in range(len(start_at)):
        if k not in start_at:
            raise MapError(
                f"{source}:{start_at[max(start_at)][1]}: starts must be 0..{len(start_at) - 1} "
                f"without gaps; start={k} is missing"
            )
    seen: dict[tuple[int, int], int] = {}
    for lineno, a, b, _ in edge_rows:
        where = f"{source}:{lineno}"
        for v in (a, b):
            if v >= n:
                raise MapError(f"{where}: vertex {v} is not defined (vertices are 0..{n - 1})")
        if a == b:
            raise MapError(f"{where}: edge from vertex {a} to itself")
        key = (min(a, b), max(a, b))
        if key in seen:
            raise MapError(f"{where}: a second edge {a}-{b} (first on line {seen[key]})")
        seen[key] = lineno
    degree = np.bincount(
        np.array([v for _, a, b, _ in edge_rows for v in (a, b)], dtype=np.int64), minlength=n
    )
    top = int(degree.argmax()) if n else 0
    d = max(1, int(degree[top]) if n else 0, 2 if waypoints else 1)
    if (n + waypoints) * d > MAX_CELL_PORTS:
        raise MapError(
            f"{source}:{vertices[top][0]}: vertex {top} has {int(degree[top]):,} edges, so each "
            f"of the {n + waypoints:,} cells gets {d:,} ports ({(n + waypoints) * d:,} in all); "
            f"allowed: at most {MAX_CELL_PORTS:,} cells x ports (refused before building them)"
        )
    edges = np.array([(a, b, m) for _, a, b, m in edge_rows], dtype=np.int64).reshape(-1, 3)
    starts = np.array([start_at[k][0] for k in range(len(start_at))], dtype=np.int64)
    return GraphSpec(name, description, xy, edges, dot, station, starts, tuple(labels))


def build_graph_map(spec: GraphSpec, source: str = "<string>", text: str = "") -> Map:
    """The :class:`Map` of a graph: vertices, then each edge's waypoints (module doc)."""
    n = spec.xy.shape[0]
    n_cells = n + int(np.maximum(spec.edges[:, 2] - 1, 0).sum()) if spec.edges.size else n
    # each cell's ports in order: (neighbour, the port of the neighbour leading back)
    ports: list[list[tuple[int, int]]] = [[] for _ in range(n_cells)]
    xy = np.zeros((n_cells, 2))
    xy[:n] = spec.xy
    nxt = n
    for a, b, m in spec.edges.tolist():
        chain = [a, *range(nxt, nxt + m - 1), b]
        if m > 1:
            i = np.arange(1, m)[:, None] / m
            xy[nxt : nxt + m - 1] = spec.xy[a] + (spec.xy[b] - spec.xy[a]) * i
        nxt += m - 1
        for u, v in zip(chain[:-1], chain[1:], strict=True):
            pu, pv = ports[u], ports[v]
            pu.append((v, len(pv)))
            pv.append((u, len(pu) - 1))
    d = max(1, max(len(p) for p in ports))
    neighbors = np.full((n_cells, d), -1, dtype=np.int64)
    back = np.full((n_cells, d), -1, dtype=np.int64)
    for c, p in enumerate(ports):
        if p:
            neighbors[c, : len(p)], back[c, : len(p)] = zip(*p, strict=True)
    reach = bfs(neighbors, 0)
    if (reach < 0).any():
        bad = int(np.flatnonzero(reach[:n] < 0)[0]) if (reach[:n] < 0).any() else 0
        raise MapError(
            f"{source}: vertex {bad} cannot be reached from vertex 0 (the graph must be connected)"
        )
    target = np.zeros(n_cells, dtype=bool)
    target[:n] = True
    dot_kind = np.zeros(n_cells, dtype=np.int64)
    dot_kind[:n] = spec.dot
    return Map(
        name=spec.name,
        description=spec.description,
        grid=(),
        free=np.zeros((0, 0), dtype=bool),
        cell_id=np.zeros((0, 0), dtype=np.int64),
        coords=np.full((n_cells, 2), -1, dtype=np.int64),
        neighbors=neighbors,
        dot_kind=dot_kind,
        homes=np.flatnonzero(spec.station).astype(np.int64),
        starts=spec.starts,
        back=back,
        entry=back.copy(),
        target=target,
        xy=xy,
        kind="graph",
        edges=spec.edges.copy(),
        labels=spec.labels,
        source=source,
        text=text,
    )


def parse_graph_map(text: str, source: str = "<string>") -> Map:
    """Parse a graph map's text into a :class:`Map` (module doc)."""
    return build_graph_map(parse_graph_spec(text, source), source, text)


def render_graph_map(spec: GraphSpec) -> str:
    """The graph map text of ``spec`` (what :func:`parse_graph_spec` reads back)."""
    start_of = {int(v): k for k, v in enumerate(spec.starts.tolist())}
    lines = [f"; name: {spec.name}"]
    if spec.description:
        lines.append(f"; description: {spec.description}")
    lines += ["; kind: graph", "; v ID X Y [station] [start=K] [big] [nodot] [label=ID]"]
    for v in range(spec.xy.shape[0]):
        flags = []
        if spec.station[v]:
            flags.append("station")
        elif spec.dot[v] == BIG:
            flags.append("big")
        elif spec.dot[v] == NO_DOT:
            flags.append("nodot")
        if v in start_of:
            flags.append(f"start={start_of[v]}")
        if spec.labels and spec.labels[v]:
            flags.append(f"label={spec.labels[v]}")
        x, y = spec.xy[v]
        lines.append(" ".join([f"v {v} {x:.6g} {y:.6g}", *flags]))
    lines.append("; e A B MOVES")
    lines += [f"e {a} {b} {m}" for a, b, m in spec.edges.tolist()]
    return "\n".join(lines) + "\n"


def graph_summary(m: Map) -> str:
    """A few lines about a graph map: vertices, edges, moves, D, stations, starts."""
    n = m.n_targets
    moves = m.edges[:, 2] if len(m.edges) else np.zeros(0, dtype=np.int64)
    deg = m.degree[:n]
    values, counts = np.unique(deg, return_counts=True)
    degrees = ", ".join(f"{c} of degree {d}" for d, c in zip(values, counts, strict=True))
    span = f"{moves.min()}-{moves.max()} moves each" if moves.size else "no edge"
    lines = [
        f"graph: {n} vertices, {len(moves)} edges ({span}, {int(moves.sum())} in all), "
        f"{m.n_cells} cells with the waypoints, D = {m.n_ports} ({degrees})",
    ]
    if m.n_cells <= 4000:
        d = m.distances()[np.ix_(m.target, m.target)]
        lines.append(f"diameter {int(d.max())} moves between vertices")

    def named(v: int) -> str:
        lab = m.labels[v] if m.labels and m.labels[v] else ""
        return f"{v} ({lab})" if lab else str(v)

    homes = ", ".join(named(int(v)) for v in m.homes) or "none"
    lines.append(f"charging stations (vertex): {homes}")
    starts = ", ".join(f"{k}: {named(int(v))}" for k, v in enumerate(m.starts))
    lines.append(f"starts (agent: vertex): {starts or 'none'}")
    return "\n".join(lines)
