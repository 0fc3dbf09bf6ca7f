"""Turn a ROS occupancy map (a real floor plan) into a qpatrol text map.

Steps, each a function here::

    read_occupancy(yaml)        map_server's occupancy grid (see qpatrol.maps.ros)
    to_cells(occ, res, cell)    square cells of ``cell`` metres: free only if all pixels are
    largest_region(free)        the largest 4-connected free region; the rest is wall
    crop(free)                  bounding box of the region plus a one-cell wall border
    place(free, agents, H)      start digits 0..N-1 and charging stations H spread out
    render(...)                 the map text, with ; name:, ; description: and ; frame:

**Cells.** A cell is ``cell / resolution`` pixels on a side (any real number >= 1).
Cell boundaries lie at exact metric positions measured from the map's origin, the
lower-left corner of the image, so cell (i, j) from the bottom-left covers the square
``x in [ox + j cell, ox + (j+1) cell]``, ``y in [oy + i cell, oy + (i+1) cell]``. A pixel
belongs to every cell its square overlaps (with a non-integer ratio, a pixel on a
boundary belongs to two cells), and a cell is free only if all its pixels are free:
walls are never thinned away. Cells that would stick out of the image (a partial
column at the right edge, a partial row at the top when the size is not a multiple of
the cell) are left out, i.e. wall. Grid row 0 is the top (north) of the image. Yaw is
ignored: the grid is aligned with the image.

**Starts and stations.** Both are spread by farthest-point sampling on shortest-path
(BFS) distance, deterministically (ties go to the lowest state number, i.e. row-major
first). The first start goes to the map's approximate middle: the cell minimising the
larger of its distances to the two ends ``a``, ``b`` of a double sweep (``a`` farthest
from cell 0, ``b`` farthest from ``a``); each further start goes to the cell farthest
from the starts placed so far. Stations are placed the same way (the first one in the
middle, the next ones farthest from the stations so far: the greedy k-centre rule,
which keeps the longest trip to a station short) on cells that are not start cells
and have at least two free neighbours, so that no station sits at the end of a dead
end; only when those run out do dead ends become eligible.
The default is one station per 150 free cells, rounded up (the shipped ``facility`` map
has one per 139). Every other cell holds a dot.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from qpatrol.maps import MAX_CELLS, MAX_GRID_AREA, Map, parse_map
from qpatrol.maps.ros import RosMap, RosMapError, read_occupancy

__all__ = [
    "CELLS_PER_STATION",
    "MAX_STARTS",
    "Imported",
    "RosMapError",
    "crop",
    "default_stations",
    "import_ros_map",
    "import_map",
    "largest_region",
    "place",
    "read_occupancy",
    "render",
    "to_cells",
]

#: One charging station per this many free cells by default (rounded up).
CELLS_PER_STATION = 150
#: Start cells are the digits 0-9.
MAX_STARTS = 10
#: Slack in pixel units when comparing cell boundaries with pixel boundaries.
_EPS = 1e-6


@dataclass(frozen=True)
class Imported:
    """The result of an import.

    Attributes:
        text: the qpatrol map file's content.
        free: bool ``[rows, cols]``, the cropped grid's free cells (border included).
        starts: int ``[agents, 2]``, (row, col) of start digit k in ``free``.
        homes: int ``[stations, 2]``, (row, col) of each charging station.
        cell_pixels: the cell side in pixels (``cell / resolution``).
        free_cells: free cells before the largest region was kept.
        regions: number of 4-connected free regions found.
        farthest_station: most moves from any free cell to its nearest station (-1 if none).
    """

    text: str
    free: np.ndarray
    starts: np.ndarray
    homes: np.ndarray
    cell_pixels: float
    free_cells: int
    regions: int
    farthest_station: int


def to_cells(occ: np.ndarray, resolution: float, cell: float, free_max: int = 0) -> np.ndarray:
    """bool ``[rows, cols]``: True on cells all of whose pixels are free.

    Args:
        occ: int ``[height, width]`` occupancy (row 0 on top); a pixel is free when
            ``0 <= occ <= free_max`` (-1 unknown is never free).
        resolution: metres per pixel.
        cell: cell side in metres, at least one pixel.

    Cells are anchored at the image's lower-left corner (the ROS origin); only whole
    cells are kept, ``rows = floor(height / ratio)``, ``cols = floor(width / ratio)``
    with ``ratio = cell / resolution``. Row 0 is the top row of cells.
    """
    if not (math.isfinite(cell) and cell > 0):
        raise RosMapError(f"cell: {cell} is not a size in metres (a number > 0)")
    ratio = cell / resolution
    if ratio < 1 - _EPS:
        raise RosMapError(
            f"cell: {cell:g} m is smaller than one pixel (resolution {resolution:g} m/px)"
        )
    blocked = ~((occ >= 0) & (occ <= free_max))
    blocked = blocked[::-1]  # count rows from the bottom edge, where the origin is
    lo_r, hi_r = _cell_spans(blocked.shape[0], ratio)
    lo_c, hi_c = _cell_spans(blocked.shape[1], ratio)
    sums = np.zeros((blocked.shape[0] + 1, blocked.shape[1] + 1), dtype=np.int32)
    sums[1:, 1:] = blocked.cumsum(axis=0, dtype=np.int32).cumsum(axis=1, dtype=np.int32)
    count = (
        sums[np.ix_(hi_r, hi_c)]
        - sums[np.ix_(lo_r, hi_c)]
        - sums[np.ix_(hi_r, lo_c)]
        + sums[np.ix_(lo_r, lo_c)]
    )
    return (count == 0)[::-1].copy()


def _cell_spans(n_pixels: int, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel index ranges ``[lo, hi)`` overlapped by each whole cell along one axis."""
    n_cells = int(math.floor(n_pixels / ratio + _EPS))
    j = np.arange(n_cells, dtype=np.float64)
    lo = np.floor(j * ratio + _EPS).astype(np.int64)
    hi = np.minimum(np.ceil((j + 1) * ratio - _EPS).astype(np.int64), n_pixels)
    return lo, hi


def largest_region(free: np.ndarray) -> tuple[np.ndarray, int]:
    """The largest 4-connected region of ``free`` and the number of regions.

    Returns bool ``[rows, cols]`` (all False if nothing is free) and the region count.
    Of equally large regions the one whose first cell comes first row-major is kept.
    """
    rows, cols = free.shape
    label = np.full(rows * cols, -1, dtype=np.int64)
    flat = free.ravel()
    sizes: list[int] = []
    for seed in np.flatnonzero(flat):
        if label[seed] >= 0:
            continue
        region = len(sizes)
        label[seed] = region
        queue = deque([int(seed)])
        size = 0
        while queue:
            i = queue.popleft()
            size += 1
            r, c = divmod(i, cols)
            up, down, left, right = r > 0, r < rows - 1, c > 0, c < cols - 1
            for j, inside in ((i - cols, up), (i + cols, down), (i - 1, left), (i + 1, right)):
                if inside and flat[j] and label[j] < 0:
                    label[j] = region
                    queue.append(j)
        sizes.append(size)
    if not sizes:
        return np.zeros_like(free, dtype=bool), 0
    keep = int(np.argmax(sizes))
    return (label == keep).reshape(rows, cols), len(sizes)


def crop(free: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
    """The bounding box of the free cells with a one-cell wall border around it.

    Returns bool ``[rows, cols]`` and ``(row, col)`` of its top-left cell in ``free``
    (-1 when the border lies outside ``free``).
    """
    rr, cc = np.nonzero(free)
    r0, r1, c0, c1 = rr.min(), rr.max(), cc.min(), cc.max()
    out = np.zeros((r1 - r0 + 3, c1 - c0 + 3), dtype=bool)
    out[1:-1, 1:-1] = free[r0 : r1 + 1, c0 : c1 + 1]
    return out, (int(r0) - 1, int(c0) - 1)


def default_stations(n_cells: int) -> int:
    """One charging station per :data:`CELLS_PER_STATION` free cells, rounded up."""
    return max(1, math.ceil(n_cells / CELLS_PER_STATION))


def place(free: np.ndarray, agents: int, stations: int) -> tuple[np.ndarray, np.ndarray]:
    """Start cells and charging stations spread over a connected grid (see module doc).

    Args:
        free: bool ``[rows, cols]``, one 4-connected free region.
        agents: start digits to place (0..10).
        stations: charging stations to place.

    Returns:
        int ``[agents, 2]`` and int ``[stations, 2]``: (row, col) of each start and station.
    """
    m = _as_map(free)
    n = m.n_cells
    if not 0 <= agents <= MAX_STARTS:
        raise RosMapError(f"agents: {agents} start digits; allowed: 0 to {MAX_STARTS} (0-9)")
    if stations < 0:
        raise RosMapError(f"stations: {stations}; allowed: 0 or more")
    if agents + stations > n or stations >= n:
        raise RosMapError(
            f"{n} free cells cannot hold {agents} starts, {stations} charging stations and a "
            "dot; lower --agents or --stations, or use a smaller --cell"
        )
    everywhere = np.ones(n, dtype=bool)
    starts = _farthest(m.neighbors, everywhere, agents, [])
    not_start = everywhere.copy()
    not_start[starts] = False
    homes = _farthest(m.neighbors, not_start & (m.degree >= 2), stations, [])
    homes = _farthest(m.neighbors, not_start, stations, homes)
    return m.coords[starts].reshape(-1, 2), m.coords[homes].reshape(-1, 2)


def _farthest(neighbors: np.ndarray, allowed: np.ndarray, k: int, chosen: list[int]) -> list[int]:
    """Extend ``chosen`` to ``k`` states by farthest-point sampling among ``allowed``.

    Starts from the approximate middle when ``chosen`` is empty; stops early when no
    allowed state is left.
    """
    chosen = list(chosen)
    allowed = allowed.copy()
    allowed[chosen] = False
    if len(chosen) >= k or not allowed.any():
        return chosen
    adj = _adjacency(neighbors)
    if not chosen:
        first = _middle(adj, allowed)
        chosen.append(first)
        allowed[first] = False
    top = int(np.iinfo(np.int64).max)
    near = np.full(neighbors.shape[0], top, dtype=np.int64)
    near_list = [top] * neighbors.shape[0]
    for s in chosen:
        _closer(adj, near, near_list, s)
    while len(chosen) < k and allowed.any():
        nxt = int(np.argmax(np.where(allowed, near, -1)))
        chosen.append(nxt)
        allowed[nxt] = False
        _closer(adj, near, near_list, nxt)
    return chosen


def _adjacency(neighbors: np.ndarray) -> list[list[int]]:
    """Each state's neighbours as Python lists (walls left out), for the searches below:
    a Python breadth-first search costs the same on a corridor of 100,000 cells as on a
    hall, where one numpy pass per distance would cost 100,000 passes."""
    return [[v for v in row if v >= 0] for row in neighbors.tolist()]


def _closer(adj: list[list[int]], near: np.ndarray, near_list: list[int], source: int) -> None:
    """Lower ``near`` (int ``[cells]``, distance to the nearest chosen state, and its copy
    ``near_list``) in place for a newly chosen ``source``.

    A breadth-first search that expands only cells it brings closer: a cell not improved
    cannot lead to an improved one, so the search stays within the new state's own
    region of the map and farthest-point sampling costs about one BFS in all.
    """
    near_list[source] = 0
    changed = [source]
    frontier = [source]
    d = 0
    while frontier:
        d += 1
        new = []
        for c in frontier:
            for x in adj[c]:
                if near_list[x] > d:
                    near_list[x] = d
                    new.append(x)
        changed += new
        frontier = new
    idx = np.array(changed, dtype=np.int64)
    near[idx] = np.array([near_list[i] for i in changed], dtype=np.int64)


def _middle(adj: list[list[int]], allowed: np.ndarray) -> int:
    """The allowed state minimising the larger distance to both ends of a double sweep."""
    a = int(np.argmax(_bfs_lists(adj, [0])))
    dist_a = _bfs_lists(adj, [a])
    dist_b = _bfs_lists(adj, [int(np.argmax(dist_a))])
    spread = np.maximum(dist_a, dist_b)
    return int(np.argmin(np.where(allowed, spread, np.iinfo(np.int64).max)))


def render(
    free: np.ndarray,
    starts: np.ndarray,
    homes: np.ndarray,
    name: str,
    description: str,
    comments: tuple[str, ...] = (),
) -> str:
    """Map text: ``#`` walls, ``.`` dots, digits at ``starts``, ``H`` at ``homes``."""
    grid = np.where(free, ".", "#").astype("<U1")
    for k, (r, c) in enumerate(starts):
        grid[r, c] = str(k)
    for r, c in homes:
        grid[r, c] = "H"
    head = [f"; name: {name}", f"; description: {description}", *(f"; {c}" for c in comments)]
    return "\n".join(head + ["".join(row) for row in grid]) + "\n"


def import_map(
    yaml_path: str | Path,
    cell: float,
    agents: int = 4,
    stations: int | None = None,
    name: str | None = None,
) -> Imported:
    """Import a ROS map_server map as a qpatrol map; see the module docstring.

    Args:
        yaml_path: the map's YAML file.
        cell: cell side in metres (at least one pixel).
        agents: start digits 0..agents-1 to place (at most 10).
        stations: charging stations ``H`` (default :func:`default_stations`).
        name: the map's name (default: the YAML file's stem).

    Raises :class:`RosMapError` (one line) on bad input or when no free cell is left.
    """
    ros = read_occupancy(yaml_path)
    cells = to_cells(ros.occ, ros.resolution, cell, ros.free_max)
    region, n_regions = largest_region(cells)
    if n_regions == 0:
        free_px = int(ros.free().sum())
        raise RosMapError(
            f"{ros.yaml_path}: no free cell of {cell:g} m ({free_px} of {ros.occ.size} pixels "
            "free); try a smaller --cell"
        )
    grid, (row0, col0) = crop(region)
    n = int(grid.sum())
    if n > MAX_CELLS or grid.size > MAX_GRID_AREA:
        raise RosMapError(
            f"{ros.yaml_path}: {cell:g} m cells make a grid of {grid.shape[1]:,} x "
            f"{grid.shape[0]:,} with {n:,} free cells; allowed: at most {MAX_CELLS:,} free "
            f"cells and {MAX_GRID_AREA:,} in all; use a larger --cell"
        )
    n_stations = default_stations(n) if stations is None else stations
    starts, homes = place(grid, agents, n_stations)
    name = name or ros.yaml_path.stem
    ratio = cell / ros.resolution
    text = render(
        grid,
        starts,
        homes,
        name,
        _description(ros, cell, ratio, n, agents, len(homes)),
        (_frame(ros, cell, cells.shape[0], row0, col0),),
    )
    return Imported(
        text=text,
        free=grid,
        starts=starts,
        homes=homes,
        cell_pixels=ratio,
        free_cells=int(cells.sum()),
        regions=n_regions,
        farthest_station=_farthest_station(grid, homes),
    )


def import_ros_map(
    yaml_path: str | Path, cell: float, agents: int = 4, stations: int | None = None
) -> str:
    """The qpatrol map text of a ROS map; see :func:`import_map`."""
    return import_map(yaml_path, cell, agents, stations).text


def _description(ros: RosMap, cell: float, ratio: float, n: int, agents: int, homes: int) -> str:
    origin = ", ".join(f"{v:g}" for v in ros.origin)
    return (
        f"imported from ROS map {ros.yaml_path.name} (image {ros.image_path.name}, "
        f"{ros.occ.shape[1]} x {ros.occ.shape[0]} px, resolution {ros.resolution:g} m/px, "
        f"origin [{origin}], mode {ros.mode}) with {cell:g} m cells ({ratio:.4g} px); "
        f"largest free region, {n} cells; {agents} start cells and {homes} charging "
        "stations H placed by farthest-point sampling"
    )


def _frame(ros: RosMap, cell: float, full_rows: int, row0: int, col0: int) -> str:
    """Where the grid lies in the map frame (yaw ignored)."""
    x0 = ros.origin[0] + col0 * cell
    y0 = ros.origin[1] + (full_rows - row0) * cell
    return (
        f"frame: grid row r, column c covers x in [X0 + c*{cell:g}, X0 + (c+1)*{cell:g}], "
        f"y in [Y0 - (r+1)*{cell:g}, Y0 - r*{cell:g}] metres, X0 = {x0:.6g}, Y0 = {y0:.6g}"
    )


def _farthest_station(free: np.ndarray, homes: np.ndarray) -> int:
    if not len(homes):
        return -1
    m = _as_map(free)
    return int(_bfs(m.neighbors, [m.state_at(int(r), int(c)) for r, c in homes]).max())


def _as_map(free: np.ndarray) -> Map:
    """A plain qpatrol map of ``free`` (dots only), for its numbering and neighbours."""
    return parse_map("\n".join("".join("." if f else "#" for f in row) for row in free))


def _bfs(neighbors: np.ndarray, sources: int | list[int]) -> np.ndarray:
    """int ``[cells]``: moves from the nearest of ``sources`` to every state (-1: unreachable).

    As :func:`qpatrol.maps.bfs` but from several sources (:func:`_adjacency` says why it
    walks Python lists).
    """
    return _bfs_lists(_adjacency(neighbors), np.atleast_1d(np.asarray(sources)).tolist())


def _bfs_lists(adj: list[list[int]], sources: list[int]) -> np.ndarray:
    """:func:`_bfs` over :func:`_adjacency` lists."""
    dist = [-1] * len(adj)
    queue = deque()
    for s in sources:
        if dist[s] < 0:
            dist[s] = 0
            queue.append(s)
    while queue:
        c = queue.popleft()
        d = dist[c] + 1
        for x in adj[c]:
            if dist[x] < 0:
                dist[x] = d
                queue.append(x)
    return np.array(dist, dtype=np.int64)
