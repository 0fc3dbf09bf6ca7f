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

from pathlib import Path

import numpy as np

from qpatrol.maps.core import (  # noqa: F401 (the package names them)
    ALLOWED,
    BIG,
    BIG_DOT,
    DIR_LETTERS,
    DIRECTIONS,
    DOT,
    EAST,
    EMPTY,
    HOME,
    MAX_CELL_PORTS,
    MAX_CELLS,
    MAX_GRID_AREA,
    MAX_MAGNITUDE,
    MAX_MAP_BYTES,
    NO_DOT,
    NORTH,
    OFFSETS,
    OPPOSITE,
    SMALL_DOT,
    SOUTH,
    WALL,
    WEST,
    Map,
    MapError,
    all_pairs_distances,
    bfs,
)
from qpatrol.maps.graph import parse_graph_map
from qpatrol.util.data import shipped_dir  # noqa: F401 (maps.shipped_dir)
from qpatrol.util.inputs import InputError, not_a_file, read_text_capped


def parse_map(text: str, source: str = "<string>") -> Map:
    """Parse map text into a :class:`Map`; raise :class:`MapError` naming file:line:col.

    A text whose comments say ``; kind: graph`` is a patrol graph
    (:func:`qpatrol.maps.graph.parse_graph_map`)."""
    for raw in text.splitlines():
        line = raw.strip()
        if line.startswith(";") and line[1:].strip().lower().replace(" ", "") == "kind:graph":
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
    n_rows = len(rows)
    if n_rows * width > MAX_GRID_AREA:
        raise MapError(
            f"{source}: a grid of {width:,} x {n_rows:,} characters ({n_rows * width:,}); "
            f"allowed: at most {MAX_GRID_AREA:,}, walls included (refused before building it)"
        )
    n_free = sum(len(r) - r.count(WALL) for r in rows)
    if n_free > MAX_CELLS:
        raise MapError(
            f"{source}: {n_free:,} free cells; allowed: at most {MAX_CELLS:,} cells in a map "
            "(refused before building it)"
        )
    for row, lineno in zip(rows, line_numbers, strict=True):
        for j, ch in enumerate(row):
            if ch not in ALLOWED:
                raise MapError(
                    f"{source}:{lineno}:{j + 1}: unknown character {ch!r} (allowed: # . - o H 0-9)"
                )
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
    """Read and parse a map file; a missing or unreadable file is a :class:`MapError`, and
    so is anything but a regular file of at most :data:`MAX_MAP_BYTES`."""
    p = Path(path)
    try:
        text = read_text_capped(p, MAX_MAP_BYTES, "a map file")
    except FileNotFoundError:
        raise MapError(f"{p}: no such map file") from None
    except InputError as e:
        raise MapError(str(e)) from None
    except (OSError, UnicodeDecodeError) as e:
        why = getattr(e, "strerror", None) or str(e)
        raise MapError(f"{p}: cannot read map file ({why})") from None
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
    kind = not_a_file(p)  # a device or FIFO is named by its path; a folder may share a name
    if p.suffix == ".txt" or "/" in name_or_path or p.is_file() or kind not in (None, "a folder"):
        if p.is_file():
            return p
        if kind is not None:
            raise MapError(f"{name_or_path}: is {kind}, not a map file")
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
