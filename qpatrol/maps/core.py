"""The map's data: :class:`Map`, its constants and distances (shared by both map kinds).

Grid maps are parsed in :mod:`qpatrol.maps`, patrol graphs in :mod:`qpatrol.maps.graph`;
both give a :class:`Map`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from qpatrol.maps.search import bfs  # noqa: F401 (moves from one cell: maps.bfs)

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

#: Most cells a map may have: free cells of a grid, vertices + waypoints of a graph. Every
#: map (a file, or one ``maps import`` makes) is refused beyond it before its arrays are
#: built. Nothing on the way of training builds a cells x cells table
#: (:mod:`qpatrol.maps.search`); a strategy keeps one only up to :data:`TABLE_CELLS`.
MAX_CELLS = 200_000
#: Largest map whose ``[C, C]`` distance table (:meth:`Map.distances`, int64: 128 MiB
#: here) a strategy may keep; on larger maps the strategies that follow walks search
#: from their goals instead (:mod:`qpatrol.strategies.follow`) and the others are refused.
TABLE_CELLS = 4096
#: Most (cell, port) slots of a graph map, cells x D: its neighbour arrays are that large
#: (a hub of 100,000 edges would give every cell 100,000 ports). 8 ports per cell at
#: MAX_CELLS.
MAX_CELL_PORTS = 8 * MAX_CELLS
#: Most rows x columns of a grid map, walls included (a 2,000 x 2,000 grid).
MAX_GRID_AREA = 4_000_000
#: Largest map file read (text grid or graph map).
MAX_MAP_BYTES = 16 << 20
#: Largest magnitude of a graph position or edge length: far beyond any floor plan in
#: any unit, and far enough from float64's limit (1.8e308) that differences, squares and
#: sums stay finite (a drawing of positions 1e308 apart has an infinite size).
MAX_MAGNITUDE = 1e100


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
    _memo: dict = field(default_factory=dict, repr=False, compare=False)

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

        Computed once by breadth-first search from every cell, then cached: for small
        maps only (a strategy's table, :data:`TABLE_CELLS`; tests); the setup of a run
        searches from the cells it needs (:mod:`qpatrol.maps.search`).
        """
        if not self._dist:
            self._dist.append(all_pairs_distances(self.neighbors))
        return self._dist[0]

    def diameter(self) -> int:
        """The longest shortest path between two cells (of one component), in moves;
        exact, without the all-pairs table (:func:`qpatrol.maps.search.diameter`)."""
        if "diameter" not in self._memo:
            from qpatrol.maps.search import diameter

            self._memo["diameter"] = diameter(self.neighbors)
        return self._memo["diameter"]

    def state_at(self, row: int, col: int) -> int:
        """State number of the free cell at (row, col); raises if it is a wall."""
        s = int(self.cell_id[row, col])
        if s < 0:
            raise ValueError(f"({row}, {col}) is a wall")
        return s


def far_targets(
    neighbors: np.ndarray, back: np.ndarray, target: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(far, length)``, int ``[C, D]`` each: for a target c and port d, the target at the
    far end of the way out of c by d (through cells that are not targets: a graph's
    waypoints) and its length in moves; -1 (both) where c is not a target, d has no move,
    or the way ends in a dead end before a target. On a grid (every cell a target)
    ``far`` is ``neighbors`` and ``length`` 1 wherever there is a move.

    ``neighbors``, ``back``: :attr:`Map.neighbors`, :attr:`Map.back`; ``target`` bool
    ``[C]``: :attr:`Map.target`."""
    n_cells, n_ports = neighbors.shape
    # a move straight into a target (every move of a grid's), then the ways through
    # waypoints, followed one by one
    step = target[:, None] & (neighbors >= 0) & target[np.maximum(neighbors, 0)]
    far = np.where(step, neighbors, -1).astype(np.int64)
    length = np.where(step, 1, -1).astype(np.int64)
    inside = target[:, None] & (neighbors >= 0) & ~target[np.maximum(neighbors, 0)]
    for c, d in zip(*(x.tolist() for x in np.nonzero(inside)), strict=True):
        cur, came, n = int(neighbors[c, d]), int(back[c, d]), 1
        while cur >= 0 and not target[cur] and n <= n_cells:
            out = [e for e in range(n_ports) if e != came and neighbors[cur, e] >= 0]
            if not out:
                cur = -1
                break
            came, cur = int(back[cur, out[0]]), int(neighbors[cur, out[0]])
            n += 1
        if cur >= 0 and target[cur]:
            far[c, d], length[c, d] = cur, n
    return far, length


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


def balls(neighbors: np.ndarray, radius: int) -> np.ndarray:
    """int ``[C, B]``: for each cell, the cells within ``radius`` moves of it (shortest
    path; the cell itself included), ascending, padded with -1 to the largest ball ``B``.
    Grown one move at a time: a ball of radius r + 1 is the ball of radius r and its
    cells' neighbours, deduplicated row by row (no ``[C, C]`` table)."""
    c = neighbors.shape[0]
    ball = np.arange(c, dtype=np.int64)[:, None]
    for _ in range(radius):
        step = neighbors[np.maximum(ball, 0)]  # [C, B, D]
        step[ball < 0] = -1  # a padding slot has no neighbours
        grown = np.concatenate([ball, step.reshape(c, -1)], axis=1)
        grown.sort(axis=1)
        dup = np.zeros(grown.shape, dtype=bool)
        dup[:, 1:] = grown[:, 1:] == grown[:, :-1]
        keep = ~dup & (grown >= 0)
        width = int(keep.sum(axis=1).max())
        # the kept cells of each row first (a stable sort of "not kept"), then padding
        order = np.argsort(~keep, axis=1, kind="stable")[:, :width]
        ball = np.where(
            np.take_along_axis(keep, order, axis=1), np.take_along_axis(grown, order, axis=1), -1
        )
    return ball
