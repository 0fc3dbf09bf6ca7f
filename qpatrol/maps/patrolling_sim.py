"""patrolling_sim ``.graph`` files -> :class:`~qpatrol.maps.graphimport.SourceGraph`.

patrolling_sim (github.com/davidbsp/patrolling_sim, BSD) stores a patrol graph as
whitespace-separated values, in its files one per line::

    N                       vertices
    WIDTH HEIGHT            the map image's size in pixels
    RESOLUTION              metres per pixel
    OFFSET_X OFFSET_Y       metres
    (blank line)
    ID X Y DEGREE           per vertex: id (0..N-1 in order), position in pixels (y up),
    NB DIR COST  x DEGREE   then per neighbour its id, a compass direction
    (blank line)            (N NE E SE S SW W NW) and an integer cost in pixels

Each undirected edge is listed twice, once at each end. The reader checks that: the
ids count 0..N-1 in order, every neighbour is listed back with the same cost, each
direction is one of the eight letters (the letters themselves are not checked against
the positions: the shipped ``1r5.graph`` has an edge E one way and SW the other), every
vertex can be reached, and, in files laid out in blank-line-separated blocks (all nine
shipped ones), that each block holds exactly ``DEGREE`` neighbours. Two vertices listed
as neighbours twice with the same costs both ways (two corridors, as 8-12 in
``example.graph``) become one edge of the shorter cost. Positions become metres:
``x * RESOLUTION + OFFSET_X`` (as patrolling_sim converts them); lengths stay pixels.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from qpatrol.maps.core import MAX_CELLS, MAX_MAGNITUDE
from qpatrol.maps.graphimport import (
    GraphImportError,
    SourceGraph,
    check_connected,
    merge_parallel,
    read_text,
)
from qpatrol.util.inputs import short_repr

__all__ = ["DIRECTIONS", "read_patrolling_sim"]

#: The compass letters patrolling_sim writes.
DIRECTIONS = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")
#: Largest edge cost (the lengths' bound, :data:`qpatrol.maps.core.MAX_MAGNITUDE`).
_MAX_COST = 10**100
assert float(_MAX_COST) <= MAX_MAGNITUDE
_HEADER = ("vertex count", "image width", "image height", "resolution", "offset x", "offset y")


class _Tokens:
    """The file's values with their line numbers, read front to back."""

    def __init__(self, text: str, path: Path) -> None:
        self.path = path
        self.tok: list[str] = []
        self.line: list[int] = []
        self.block_start: set[int] = set()  # token indices that follow a blank line
        self.last_line = 1
        blank = False
        for lineno, raw in enumerate(text.splitlines(), start=1):
            parts = raw.split()
            if not parts:
                blank = True
                continue
            if blank and self.tok:
                self.block_start.add(len(self.tok))
            blank = False
            for p in parts:
                self.tok.append(p)
                self.line.append(lineno)
            self.last_line = lineno
        self.i = 0

    def where(self, i: int | None = None) -> str:
        i = self.i if i is None else i
        line = self.line[i] if i < len(self.tok) else self.last_line
        return f"{self.path}:{line}"

    def take(self, what: str) -> tuple[str, str]:
        if self.i >= len(self.tok):
            raise GraphImportError(f"{self.where()}: file ends where {what} was expected")
        t, w = self.tok[self.i], self.where()
        self.i += 1
        return t, w

    def integer(self, what: str, low: int | None = None, high: int | None = None) -> int:
        t, w = self.take(what)
        digits = t.lstrip("+").lstrip("0")
        if high is not None and digits.isdigit() and len(digits) > len(str(high)):
            # int() of a token of thousands of digits is slow, or an error of its own
            raise GraphImportError(
                f"{w}: {what} of {len(digits):,} digits must be at most {_big(high)}"
            )
        try:
            x = int(t)
        except ValueError:
            raise GraphImportError(
                f"{w}: {what} {short_repr(t, 60)} is not a whole number"
            ) from None
        if low is not None and x < low:
            raise GraphImportError(f"{w}: {what} {x} must be at least {low}")
        if high is not None and x > high:
            raise GraphImportError(f"{w}: {what} {_big(x)} must be at most {_big(high)}")
        return x

    def number(self, what: str) -> float:
        t, w = self.take(what)
        try:
            x = float(t)
        except ValueError:
            raise GraphImportError(f"{w}: {what} {short_repr(t, 60)} is not a number") from None
        if not np.isfinite(x):
            raise GraphImportError(f"{w}: {what} {short_repr(t, 60)} is not a finite number")
        return x


def _big(x: int) -> str:
    """An integer as digits, or in e-notation when it has more than 15 of them."""
    return str(x) if abs(x) < 10**15 else f"{float(x):g}"


def _line(where: str) -> str:
    return where.rsplit(":", 1)[1]


def read_patrolling_sim(path: str | Path) -> SourceGraph:
    """Read a patrolling_sim ``.graph`` file (module doc); :class:`GraphImportError` names
    the file, the line and what is wrong."""
    p = Path(path)
    t = _Tokens(read_text(p, "a patrolling_sim graph file"), p)
    if not t.tok:
        raise GraphImportError(f"{p}: empty file (expected a patrolling_sim graph)")
    n = t.integer(_HEADER[0], low=1, high=10**15)
    if n > MAX_CELLS:
        raise GraphImportError(
            f"{t.where(0)}: vertex count {n:,}; allowed: at most {MAX_CELLS:,}, the most cells "
            "a map may have (refused before reading the vertices)"
        )
    if 4 * n > len(t.tok) - 6:  # each vertex needs its id, x, y and degree
        raise GraphImportError(
            f"{t.where(0)}: vertex count {n:,}, but the file holds only {len(t.tok) - 6:,} "
            "values after the header, fewer than the 4 (id, x, y, degree) each vertex needs"
        )
    t.integer(_HEADER[1], low=0)
    t.integer(_HEADER[2], low=0)
    res_at = t.i
    res = t.number(_HEADER[3])
    if res <= 0:
        raise GraphImportError(f"{t.where(res_at)}: resolution {res:g} must be > 0 (m/px)")
    ox = t.number(_HEADER[4])
    oy = t.number(_HEADER[5])
    blocks = sorted(t.block_start)
    in_blocks = len(blocks) == n and (not blocks or blocks[0] == t.i)
    xy = np.zeros((n, 2))
    # (a, b) -> [(cost, "file:line")] as listed at a
    listed: dict[tuple[int, int], list[tuple[int, str]]] = {}
    for v in range(n):
        start = t.i
        if start >= len(t.tok):
            raise GraphImportError(
                f"{t.where()}: file ends after {v} of the {n} vertices the header announces"
            )
        vid = t.integer("vertex id")
        if vid != v:
            raise GraphImportError(
                f"{t.where(start)}: vertex id {vid} where {v} was expected "
                f"(ids count 0..{n - 1} in file order)"
            )
        xy[v, 0] = t.number(f"vertex {v}'s x")
        xy[v, 1] = t.number(f"vertex {v}'s y")
        deg_at = t.i
        degree = t.integer(f"vertex {v}'s degree", low=0)
        if in_blocks:
            end = blocks[v + 1] if v + 1 < n else len(t.tok)
            found = end - t.i
            if v == n - 1 and found < 3 * degree:
                raise GraphImportError(
                    f"{t.where(len(t.tok) - 1)}: file ends inside vertex {v}'s neighbours "
                    f"({found} of the {3 * degree} values its degree {degree} needs)"
                )
            if found != 3 * degree:
                raise GraphImportError(
                    f"{t.where(deg_at)}: vertex {v} has degree {degree} but its block lists "
                    f"{found} neighbour value(s) where {3 * degree} were expected "
                    "(id, direction, cost per neighbour)"
                )
        for k in range(degree):
            what = f"vertex {v}'s neighbour {k + 1} of {degree}"
            nb_at = t.i
            nb = t.integer(f"{what}: id", low=0, high=n - 1)
            if nb == v:
                raise GraphImportError(f"{t.where(nb_at)}: vertex {v} lists itself as a neighbour")
            d, dw = t.take(f"{what}: direction")
            if d not in DIRECTIONS:
                raise GraphImportError(
                    f"{dw}: {what}: direction {short_repr(d, 60)} is not one of "
                    f"{' '.join(DIRECTIONS)}"
                )
            cost = t.integer(f"{what}: cost", low=1, high=_MAX_COST)
            listed.setdefault((v, nb), []).append((cost, t.where(nb_at)))
    if t.i < len(t.tok):
        raise GraphImportError(
            f"{t.where()}: unexpected {short_repr(t.tok[t.i], 60)} after the last of the {n} "
            "vertices the header announces"
        )
    pairs: dict[tuple[int, int], list[float]] = {}
    for (a, b), here in listed.items():
        back = listed.get((b, a))
        if back is None:
            raise GraphImportError(
                f"{here[0][1]}: vertex {a} lists neighbour {b} (cost {here[0][0]}) but "
                f"vertex {b} does not list {a}"
            )
        if len(back) != len(here):
            raise GraphImportError(
                f"{here[0][1]}: vertex {a} lists neighbour {b} {len(here)} time(s) but "
                f"vertex {b} lists {a} {len(back)} time(s) (line {_line(back[0][1])})"
            )
        mine = sorted(c for c, _ in here)
        theirs = sorted(c for c, _ in back)
        if mine != theirs:
            at = next((w for c, w in here if c not in theirs), here[0][1])
            other = next((w for c, w in back if c not in mine), back[0][1])
            raise GraphImportError(
                f"{at}: edge {a}-{b} costs {', '.join(map(str, mine))} at vertex {a} but "
                f"{', '.join(map(str, theirs))} at vertex {b} (line {_line(other)})"
            )
        if a < b:
            pairs[(a, b)] = [float(c) for c in mine]
    labels = tuple(str(i) for i in range(n))
    edges, notes = merge_parallel(pairs, labels)
    check_connected(n, edges, labels, str(p))
    costs = edges[:, 2]
    facts = (
        f"{n} vertices, {edges.shape[0]} edges of {costs.min():g}-{costs.max():g} px, "
        f"resolution {res:g} m/px, offset [{ox:g}, {oy:g}] m; positions in metres"
        if edges.size
        else f"{n} vertex, resolution {res:g} m/px"
    )
    return SourceGraph(
        kind="patrolling_sim graph",
        path=p,
        labels=labels,
        xy=xy * res + np.array([ox, oy]),
        edges=edges,
        stations=np.zeros(n, dtype=bool),
        unit="px",
        facts=facts,
        notes=notes,
    )
