"""Shared fixtures: tiny maps written to temporary files."""

from __future__ import annotations

from pathlib import Path

import pytest

RING = """\
; name: ring
; description: a 3x3 ring of eight cells around one wall
0..
.#.
...
"""

ROOMS = """\
; name: rooms
#########
#0..#..1#
#.#...#.#
#...H...#
#.#.#.#.#
#2.o#o.3#
#########
"""


@pytest.fixture
def ring_map(tmp_path: Path) -> Path:
    p = tmp_path / "ring.txt"
    p.write_text(RING)
    return p


@pytest.fixture
def rooms_map(tmp_path: Path) -> Path:
    p = tmp_path / "rooms.txt"
    p.write_text(ROOMS)
    return p
