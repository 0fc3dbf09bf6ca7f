"""Pictures of one run: an RGB array (``rgb_array``) and text (``ansi``).

A cell shows a dot when any robot's dot map still holds it (with communication on
there is one map); robots are drawn over everything, robot ``k`` in colour ``k`` (or
its digit in text, letters from 10 on).
"""

from __future__ import annotations

import numpy as np

from qpatrol import world
from qpatrol.maps import BIG, Map

#: The render modes of both environments.
RENDER_MODES = ("rgb_array", "ansi")
#: Pixels per grid cell in ``rgb_array`` images.
CELL_PX = 8
WALL_RGB = (33, 33, 180)
FLOOR_RGB = (0, 0, 0)
DOT_RGB = (255, 184, 151)
STATION_RGB = (0, 160, 0)
ROBOT_RGB = np.array(
    [
        (255, 255, 0),
        (255, 0, 0),
        (0, 255, 255),
        (255, 128, 255),
        (255, 160, 0),
        (160, 255, 100),
        (180, 120, 255),
        (255, 255, 255),
    ],
    dtype=np.uint8,
)
ROBOT_CHARS = "0123456789abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"


def dots_shown(s: world.State) -> np.ndarray:
    """bool ``[C]``: cells whose dot is still on some robot's map (run 0)."""
    return s.dots[0].any(axis=0)


def rgb(m: Map, p: world.Params, s: world.State) -> np.ndarray:
    """uint8 ``[rows x 8, cols x 8, 3]``: walls, floor, stations, dots and robots."""
    rows, cols = m.free.shape
    img = np.empty((rows, cols, 3), dtype=np.uint8)
    img[:] = WALL_RGB
    img[m.free] = FLOOR_RGB
    img = np.repeat(np.repeat(img, CELL_PX, axis=0), CELL_PX, axis=1)
    dots = dots_shown(s)
    for h in p.homes:
        r, c = m.coords[h]
        img[r * CELL_PX : (r + 1) * CELL_PX, c * CELL_PX : (c + 1) * CELL_PX] = STATION_RGB
    for cell in np.flatnonzero(dots):
        r, c = m.coords[cell]
        half = 2 if m.dot_kind[cell] == BIG else 1
        mid = CELL_PX // 2
        img[
            r * CELL_PX + mid - half : r * CELL_PX + mid + half,
            c * CELL_PX + mid - half : c * CELL_PX + mid + half,
        ] = DOT_RGB
    for k, cell in enumerate(s.pos[0]):
        r, c = m.coords[cell]
        img[r * CELL_PX + 1 : (r + 1) * CELL_PX - 1, c * CELL_PX + 1 : (c + 1) * CELL_PX - 1] = (
            ROBOT_RGB[k % len(ROBOT_RGB)]
        )
    return img


def ansi(m: Map, p: world.Params, s: world.State) -> str:
    """The maze as text (``#`` wall, ``.``/``o`` dot, ``H`` station, digits robots),
    then one line per robot: cell, charge, mode."""
    rows, cols = m.free.shape
    grid = [["#" if not m.free[r, c] else " " for c in range(cols)] for r in range(rows)]
    dots = dots_shown(s)
    for cell in range(p.n_cells):
        r, c = m.coords[cell]
        if dots[cell]:
            grid[r][c] = "o" if m.dot_kind[cell] == BIG else "."
    for h in p.homes:
        r, c = m.coords[h]
        grid[r][c] = "H"
    for k, cell in enumerate(s.pos[0]):
        r, c = m.coords[cell]
        grid[r][c] = ROBOT_CHARS[k % len(ROBOT_CHARS)]
    lines = ["".join(row) for row in grid]
    lines.append(f"t={s.t}")
    modes = ("patrol", "homing", "queued", "charging")
    for k in range(p.n_agents):
        lines.append(
            f"robot {k}: cell {int(s.pos[0, k])} charge {int(s.charge[0, k])} "
            f"{modes[int(s.mode[0, k])]}"
        )
    return "\n".join(lines) + "\n"


def check_mode(mode: str | None) -> str | None:
    """``mode`` if it is None or one of :data:`RENDER_MODES`; else a one-line ValueError."""
    if mode is not None and mode not in RENDER_MODES:
        raise ValueError(f"render_mode: got {mode!r}; allowed: None, {', '.join(RENDER_MODES)}")
    return mode


def picture(m: Map, p: world.Params, s: world.State, mode: str) -> np.ndarray | str:
    """The run drawn in render mode ``mode``: :func:`rgb` or :func:`ansi`."""
    return rgb(m, p, s) if mode == "rgb_array" else ansi(m, p, s)
