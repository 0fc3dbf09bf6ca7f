"""Maze maps made by the tests: random mazes, dead-end stations, one-wide corridors.

Each function returns map text in qpatrol's format (see ``docs/model.md``), made from a
seed, so the liveness tests can run every strategy on maps the project never shipped.
"""

from __future__ import annotations

import numpy as np


def _text(grid: np.ndarray, name: str) -> str:
    rows = ["".join(r) for r in grid]
    return f"; name: {name}\n" + "\n".join(rows) + "\n"


def _neighbours(grid: np.ndarray, r: int, c: int) -> int:
    return sum(grid[r + dr, c + dc] != "#" for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)))


def random_maze(
    rows: int,
    cols: int,
    seed: int,
    loops: float = 0.0,
    stations: int = 2,
    dead_end_stations: bool = True,
) -> str:
    """A maze carved by a randomized depth-first search on a ``rows x cols`` room grid.

    With ``loops = 0`` it is a tree (every corridor ends in a dead end); each remaining
    wall between two rooms is then knocked down with probability ``loops``. Stations go
    to dead ends when ``dead_end_stations`` (if there are any), else to junctions.
    """
    rng = np.random.default_rng(seed)
    h, w = 2 * rows + 1, 2 * cols + 1
    grid = np.full((h, w), "#", dtype="<U1")
    seen = np.zeros((rows, cols), dtype=bool)
    stack = [(0, 0)]
    seen[0, 0] = True
    grid[1, 1] = "."
    while stack:
        r, c = stack[-1]
        options = [
            (r + dr, c + dc)
            for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1))
            if 0 <= r + dr < rows and 0 <= c + dc < cols and not seen[r + dr, c + dc]
        ]
        if not options:
            stack.pop()
            continue
        nr, nc = options[rng.integers(len(options))]
        seen[nr, nc] = True
        grid[2 * nr + 1, 2 * nc + 1] = "."
        grid[r + nr + 1, c + nc + 1] = "."
        stack.append((nr, nc))
    if loops > 0:
        for r in range(1, h - 1):
            for c in range(1, w - 1):
                between = (r % 2 == 1) != (c % 2 == 1)
                if grid[r, c] == "#" and between and rng.random() < loops:
                    grid[r, c] = "."
    free = [(r, c) for r in range(h) for c in range(w) if grid[r, c] != "#"]
    dead = [x for x in free if _neighbours(grid, *x) == 1]
    junction = [x for x in free if _neighbours(grid, *x) >= 3]
    pool = dead if (dead_end_stations and dead) else (junction or free)
    order = rng.permutation(len(pool))
    for i in order[:stations]:
        r, c = pool[i]
        grid[r, c] = "H"
    rest = [x for x in free if grid[x] == "."]
    for digit, i in enumerate(rng.permutation(len(rest))[:2]):
        grid[rest[i]] = str(digit)
    return _text(grid, f"maze-{rows}x{cols}-{seed}")


def corridor_ring(length: int, width: int = 1, spur: int = 0) -> str:
    """A one-wide rectangular ring of about ``length`` cells, a station on a spur.

    ``spur`` > 0 adds a one-wide dead end of that many cells off the ring, with the
    station at its end (the hardest place for a station); else the station is on the
    ring.
    """
    side = max(2, length // 4)
    h, w = side + 2, side + 2 + spur
    grid = np.full((h, w), "#", dtype="<U1")
    grid[1, 1 : side + 1] = "."
    grid[side, 1 : side + 1] = "."
    grid[1 : side + 1, 1] = "."
    grid[1 : side + 1, side] = "."
    if spur:
        r = (side + 1) // 2
        grid[r, side + 1 : side + 1 + spur] = "."
        grid[r, side + spur] = "H"
    else:
        grid[1, side // 2] = "H"
    grid[side, 2] = "0"
    return _text(grid, f"ring-{length}-spur{spur}")


def comb(teeth: int, depth: int) -> str:
    """A corridor with ``teeth`` one-wide dead ends of ``depth`` cells; stations at the
    ends of the first and last tooth (more robots than junctions fit easily)."""
    w = 2 * teeth + 1
    grid = np.full((depth + 3, w), "#", dtype="<U1")
    grid[1, 1 : w - 1] = "."
    for i in range(teeth):
        c = 2 * i + 1
        grid[2 : 2 + depth, c] = "."
    grid[1 + depth, 1] = "H"
    grid[1 + depth, 2 * (teeth - 1) + 1] = "H"
    grid[1, 2] = "0"
    return _text(grid, f"comb-{teeth}x{depth}")


def rooms(rows: int, cols: int, size: int, seed: int, stub: int = 2, loops: float = 0.3) -> str:
    """Square rooms of ``size x size`` cells on a ``rows x cols`` grid, joined by one-wide
    corridors of two cells (a random spanning tree of the rooms, plus each other link
    with probability ``loops``); one station ends a one-wide dead end of ``stub`` cells
    off a top room (a charging room at the end of a corridor), the other stands in a
    room."""
    rng = np.random.default_rng(seed)
    gap = 2
    h = 2 + stub + rows * size + (rows - 1) * gap
    w = 2 + cols * size + (cols - 1) * gap
    grid = np.full((h, w), "#", dtype="<U1")

    def corner(i: int, j: int) -> tuple[int, int]:
        return 1 + stub + i * (size + gap), 1 + j * (size + gap)

    for i in range(rows):
        for j in range(cols):
            r0, c0 = corner(i, j)
            grid[r0 : r0 + size, c0 : c0 + size] = "."
    links = [((i, j), (i, j + 1)) for i in range(rows) for j in range(cols - 1)]
    links += [((i, j), (i + 1, j)) for i in range(rows - 1) for j in range(cols)]
    order = rng.permutation(len(links))
    group = {(i, j): (i, j) for i in range(rows) for j in range(cols)}

    def root(x: tuple[int, int]) -> tuple[int, int]:
        while group[x] != x:
            x = group[x]
        return x

    for n in order.tolist():
        a, b = links[n]
        joined = root(a) != root(b)
        if not joined and rng.random() >= loops:
            continue
        group[root(a)] = root(b)
        r0, c0 = corner(*a)
        if a[0] == b[0]:  # east: a corridor along the room's middle row
            grid[r0 + size // 2, c0 + size : c0 + size + gap] = "."
        else:  # south: along the middle column
            grid[r0 + size : r0 + size + gap, c0 + size // 2] = "."
    r0, c0 = corner(0, int(rng.integers(cols)))
    col = c0 + int(rng.integers(size))
    grid[r0 - stub : r0, col] = "."
    grid[r0 - stub, col] = "H"
    r1, c1 = corner(int(rng.integers(rows)), int(rng.integers(cols)))
    grid[r1 + int(rng.integers(size)), c1 + int(rng.integers(size))] = "H"
    return _text(grid, f"rooms-{rows}x{cols}x{size}-{seed}")


def reachable(grid: np.ndarray) -> np.ndarray:
    """bool, grid-shaped: the free squares reachable from the corner (0, 0)."""
    seen = np.zeros(grid.shape, dtype=bool)
    seen[0, 0] = True
    stack = [(0, 0)]
    while stack:
        r, c = stack.pop()
        for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            inside = 0 <= rr < grid.shape[0] and 0 <= cc < grid.shape[1]
            if inside and grid[rr, cc] != "#" and not seen[rr, cc]:
                seen[rr, cc] = True
                stack.append((rr, cc))
    return seen
