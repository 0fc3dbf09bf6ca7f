"""Text maps: parse, validate and turn into arrays once.

A map is a text file (format in ``docs/model.md``)::

    ; name: map_a
    ; description: a small facility
    #########
    #0....o.#
    #.##-##H#
    #########

``#`` wall; ``.`` free cell holding a dot; ``-`` free cell with no dot; ``o`` free
cell holding a big dot; ``H`` charging station (free, no dot); ``0``-``9`` start cell
of agent *k* (free, with a dot). Lines starting with ``;`` are comments. Every grid
row has the same length; off the grid counts as wall.

Free cells are numbered row-major from 0: that number is the *state* (cell) used
everywhere else. Directions are ordered North, East, South, West (0..3).

A map file whose comments say ``; kind: graph`` is a patrol graph instead
(:mod:`qpatrol.maps.graph`): vertices and edges, each edge a chain of unit moves.
Both kinds give a :class:`Map`: cells with up to ``D`` ports (a grid has the four ports
N, E, S, W), the port back through which each move arrives, and the cells that count
as patrol targets.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from qpatrol.util.data import shipped_dir  # noqa: F401 (maps.shipped_dir)

NORTH, EAST, SOUTH, WEST = 0, 1, 2, 3
DIRECTIONS = ("north", "east", "south", "west")
DIR_LETTERS = "NESW"
#: (row, col) offset of a move in each direction.
OFFSETS = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]], dtype=np.int64)
#: Direction opposite to each direction.
OPPOSITE = np.array([SOUTH, WEST, NORTH, EAST], dtype=np.int64)

WALL, DOT, EMPTY, BIG_DOT, HOME = "#", ".", "-", "o", "H"
ALLOWED = set("#.-oH0123456789")

#: Dot kinds stored per cell.
NO_DOT, SMALL_DOT, BIG = 0, 1, 2


class MapError(ValueError):
    """A map file that cannot be used; the message names file, line and column."""


@dataclass(frozen=True)
class Map:
    """A parsed maze. Cell arrays are indexed by state number (free cells, row-major).

    Attributes:
        name: the map's name (``; name:`` comment or file stem).
        description: the ``; description:`` comment, or "".
        grid: the grid rows as text, walls included.
        free: bool ``[rows, cols]``, True on free cells.
        cell_id: int ``[rows, cols]``, the state number of a free cell, -1 on walls.
        coords: int ``[cells, 2]``, (row, col) of each state.
        neighbors: int ``[cells, 4]``, the state one move N/E/S/W away, -1 if wall.
        dot_kind: int ``[cells]``, 0 no dot, 1 dot, 2 big dot.
        homes: int ``[n_homes]``, states of the charging stations ``H``.
        starts: int ``[n_starts]``, the start state of agent k for k = 0..n_starts-1.
        back: int ``[cells, D]``, for the move out of cell c by port p, the port of
            ``neighbors[c, p]`` that leads back to c (-1 where there is no move); a grid's
            is the opposite direction.
        entry: int ``[cells, D]``, the heading a robot has after the move out of cell c by
            port p: on a grid the direction moved (p), on a graph the port it arrived
            through (``back``). Either names the arrival side of the new cell uniquely.
        target: bool ``[cells]``, the cells every measure counts: all cells of a grid, the
            vertices of a graph (not the waypoints inside its edges).
        xy: float ``[cells, 2]``, where to draw each cell: (col, row) on a grid, the
            vertex position (waypoints evenly spaced along their edge) on a graph.
        kind: ``"grid"`` or ``"graph"``.
        edges: int ``[E, 3]``, a graph's edges as (vertex a, vertex b, moves); empty for
            a grid.
        labels: a graph's vertex ids as the source file named them; () for a grid.
        source: the file it came from, if any.
        text: the text it was parsed from (copied into run folders as ``map.txt``).
    """

    name: str
    description: str
    grid: tuple[str, ...]
    free: np.ndarray
    cell_id: np.ndarray
    coords: np.ndarray
    neighbors: np.ndarray
    dot_kind: np.ndarray
    homes: np.ndarray
    starts: np.ndarray
    back: np.ndarray
    entry: np.ndarray
    target: np.ndarray
    xy: np.ndarray
    kind: str = "grid"
    edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=np.int64))
    labels: tuple[str, ...] = ()
    source: str = ""
    text: str = field(default="", repr=False, compare=False)
    _dist: list = field(default_factory=list, repr=False, compare=False)

    @property
    def n_cells(self) -> int:
        """Number of free cells (states)."""
        return int(self.coords.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the grid."""
        return self.free.shape  # type: ignore[return-value]

    @property
    def n_ports(self) -> int:
        """D, the most moves out of one cell (4 on a grid)."""
        return int(self.neighbors.shape[1])

    @property
    def is_graph(self) -> bool:
        """True for a patrol graph, False for a grid maze."""
        return self.kind == "graph"

    @property
    def n_targets(self) -> int:
        """Number of target cells (every cell of a grid, a graph's vertices)."""
        return int(self.target.sum())

    @property
    def degree(self) -> np.ndarray:
        """int ``[cells]``: number of free neighbours of each state."""
        return (self.neighbors >= 0).sum(axis=1)

    def distances(self) -> np.ndarray:
        """int ``[cells, cells]``: shortest-path length in moves between two states.

        Computed once by breadth-first search from every cell, then cached.
        """
        if not self._dist:
            self._dist.append(all_pairs_distances(self.neighbors))
        return self._dist[0]

    def state_at(self, row: int, col: int) -> int:
        """State number of the free cell at (row, col); raises if it is a wall."""
        s = int(self.cell_id[row, col])
        if s < 0:
            raise ValueError(f"({row}, {col}) is a wall")
        return s


def bfs(neighbors: np.ndarray, source: int) -> np.ndarray:
    """int ``[cells]``: moves from ``source`` to every state (-1 if unreachable)."""
    dist = np.full(neighbors.shape[0], -1, dtype=np.int64)
    dist[source] = 0
    queue = deque([source])
    while queue:
        c = queue.popleft()
        for nb in neighbors[c]:
            if nb >= 0 and dist[nb] < 0:
                dist[nb] = dist[c] + 1
                queue.append(nb)
    return dist


def all_pairs_distances(neighbors: np.ndarray) -> np.ndarray:
    """int ``[cells, cells]``: BFS distances between all states (-1 if unreachable).

    Frontier expansion over all sources at once, one numpy pass per distance.
    """
    n = neighbors.shape[0]
    dist = np.full((n, n), -1, dtype=np.int64)
    src = np.arange(n)
    dist[src, src] = 0
    frontier_src, frontier_cell = src, src
    d = 0
    while frontier_src.size:
        d += 1
        nb = neighbors[frontier_cell]  # [F, D]
        s = np.repeat(frontier_src, neighbors.shape[1])
        c = nb.ravel()
        ok = c >= 0
        s, c = s[ok], c[ok]
        new = dist[s, c] < 0
        s, c = s[new], c[new]
        # drop duplicates discovered twice in this wave
        key = np.unique(s * n + c)
        s, c = key // n, key % n
        dist[s, c] = d
        frontier_src, frontier_cell = s, c
    return dist


def parse_map(text: str, source: str = "<string>") -> Map:
    """Parse map text into a :class:`Map`; raise :class:`MapError` naming file:line:col.

    A text whose comments say ``; kind: graph`` is a patrol graph
    (:func:`qpatrol.maps.graph.parse_graph_map`)."""
    for raw in text.splitlines():
        line = raw.strip()
        if line.startswith(";") and line[1:].strip().lower().replace(" ", "") == "kind:graph":
            from qpatrol.maps.graph import parse_graph_map

            return parse_graph_map(text, source)
    name = Path(source).stem if source != "<string>" else "map"
    description = ""
    rows: list[str] = []
    line_numbers: list[int] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.rstrip("\r\n")
        if line.startswith(";"):
            body = line[1:].strip()
            low = body.lower()
            if low.startswith("name:"):
                name = body[5:].strip() or name
            elif low.startswith("description:"):
                description = body[12:].strip()
            continue
        if not line.strip() and not rows:
            continue  # leading blank lines
        rows.append(line)
        line_numbers.append(lineno)
    while rows and not rows[-1].strip():  # trailing blank lines
        rows.pop()
        line_numbers.pop()
    if not rows:
        raise MapError(f"{source}: no grid rows (only comments or empty)")
    width = len(rows[0])
    for row, lineno in zip(rows, line_numbers, strict=True):
        if len(row) != width:
            col = min(len(row), width) + 1
            raise MapError(
                f"{source}:{lineno}:{col}: ragged row: {len(row)} characters where the "
                f"first grid row (line {line_numbers[0]}) has {width}"
            )
        for j, ch in enumerate(row):
            if ch not in ALLOWED:
                raise MapError(
                    f"{source}:{lineno}:{j + 1}: unknown character {ch!r} (allowed: # . - o H 0-9)"
                )
    n_rows = len(rows)
    grid = np.array([list(r) for r in rows])
    free = grid != WALL
    if not free.any():
        raise MapError(f"{source}:{line_numbers[0]}:1: the map has no free cell")
    cell_id = np.full(free.shape, -1, dtype=np.int64)
    coords = np.argwhere(free)
    cell_id[free] = np.arange(coords.shape[0])
    neighbors = np.full((coords.shape[0], 4), -1, dtype=np.int64)
    for d in range(4):
        rr = coords[:, 0] + OFFSETS[d, 0]
        cc = coords[:, 1] + OFFSETS[d, 1]
        inside = (rr >= 0) & (rr < n_rows) & (cc >= 0) & (cc < width)
        nb = np.full(coords.shape[0], -1, dtype=np.int64)
        nb[inside] = cell_id[rr[inside], cc[inside]]
        neighbors[:, d] = nb
    chars = grid[free]
    dot_kind = np.zeros(coords.shape[0], dtype=np.int64)
    dot_kind[(chars == DOT) | np.char.isdigit(chars)] = SMALL_DOT
    dot_kind[chars == BIG_DOT] = BIG
    homes = np.flatnonzero(chars == HOME)

    start_at: dict[int, tuple[int, int]] = {}
    for r, c in np.argwhere(np.char.isdigit(grid)):
        k = int(grid[r, c])
        if k in start_at:
            r0, c0 = start_at[k]
            raise MapError(
                f"{source}:{line_numbers[r]}:{c + 1}: start digit {k} repeated "
                f"(first at line {line_numbers[r0]}, column {c0 + 1})"
            )
        start_at[k] = (int(r), int(c))
    for k in range(len(start_at)):
        if k not in start_at:
            r, c = start_at[max(start_at)]
            raise MapError(
                f"{source}:{line_numbers[r]}:{c + 1}: start digits must be 0..{len(start_at) - 1} "
                f"without gaps; {k} is missing"
            )
    starts = np.array([cell_id[start_at[k]] for k in range(len(start_at))], dtype=np.int64)

    reach = bfs(neighbors, 0)
    if (reach < 0).any():
        bad = int(np.flatnonzero(reach < 0)[0])
        r, c = coords[bad]
        raise MapError(
            f"{source}:{line_numbers[r]}:{c + 1}: free cell unreachable from the first free "
            f"cell (line {line_numbers[coords[0][0]]}, column {coords[0][1] + 1})"
        )
    return Map(
        name=name,
        description=description,
        grid=tuple(rows),
        free=free,
        cell_id=cell_id,
        coords=coords.astype(np.int64),
        neighbors=neighbors,
        dot_kind=dot_kind,
        homes=homes.astype(np.int64),
        starts=starts,
        back=np.where(neighbors >= 0, OPPOSITE[None, :], -1),
        entry=np.where(neighbors >= 0, np.arange(4)[None, :], -1),
        target=np.ones(coords.shape[0], dtype=bool),
        xy=coords[:, ::-1].astype(np.float64),
        source=source,
        text=text,
    )


def load_map(path: str | Path) -> Map:
    """Read and parse a map file; a missing or unreadable file is a :class:`MapError`."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise MapError(f"{p}: no such map file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise MapError(f"{p}: cannot read map file ({e})") from None
    return parse_map(text, source=str(p))


def maps_dirs() -> list[Path]:
    """Folders searched for map names: ./maps, then the maps shipped with qpatrol."""
    dirs = [Path.cwd() / "maps", shipped_dir("maps")]
    seen: list[Path] = []
    for d in dirs:
        if d.is_dir() and d.resolve() not in [s.resolve() for s in seen]:
            seen.append(d)
    return seen


def available_maps() -> dict[str, Path]:
    """Map name (file stem) -> path, for every ``*.txt`` in :func:`maps_dirs`."""
    found: dict[str, Path] = {}
    for d in maps_dirs():
        for p in sorted(d.glob("*.txt")):
            found.setdefault(p.stem, p)
    return found


def resolve_map(name_or_path: str) -> Path:
    """The file behind a map name (``map_a``) or path; a :class:`MapError` if none."""
    p = Path(name_or_path)
    if p.suffix == ".txt" or "/" in name_or_path or p.is_file():
        if p.is_file():
            return p
        raise MapError(f"{name_or_path}: no such map file")
    known = available_maps()
    if name_or_path in known:
        return known[name_or_path]
    names = ", ".join(sorted(known)) or "none found"
    raise MapError(f"{name_or_path}: unknown map name (known: {names})")


def get_map(name_or_path: str) -> Map:
    """Load a map by name or path."""
    return load_map(resolve_map(name_or_path))


def corridor_length(m: Map, state: int, direction: int) -> int:
    """States passed walking from ``state`` in ``direction`` to the next junction or dead end.

    The walk leaves ``state`` by ``direction`` (a port) and then follows the corridor
    (cells with exactly two neighbours, turning at L-turns, never reversing); the count
    includes the cell where it stops, a junction (3 or more neighbours) or a dead end (1).
    Returns 0 if ``direction`` leads into a wall.
    """
    deg = m.degree
    nxt = int(m.neighbors[state, direction])
    if nxt < 0:
        return 0
    came = int(m.back[state, direction])
    count = 1
    cur = nxt
    while deg[cur] == 2:
        d = next(d for d in range(m.n_ports) if d != came and m.neighbors[cur, d] >= 0)
        came = int(m.back[cur, d])
        cur = int(m.neighbors[cur, d])
        count += 1
        if cur == state:  # a closed loop without junctions
            break
    return count


def render_states(m: Map, width: int = 4) -> str:
    """The grid as text with each free cell's state number (walls as ``#``)."""
    lines = []
    rows, cols = m.shape
    for r in range(rows):
        cells = []
        for c in range(cols):
            s = m.cell_id[r, c]
            cells.append(("#" * (width - 1)) if s < 0 else str(int(s)))
        lines.append(" ".join(x.rjust(width - 1) for x in cells))
    return "\n".join(lines)
