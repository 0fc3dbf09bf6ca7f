from pathlib import Path

import numpy as np
import pytest

from qpatrol.maps import (
    BIG,
    EAST,
    NORTH,
    SMALL_DOT,
    SOUTH,
    WEST,
    MapError,
    available_maps,
    bfs,
    get_map,
    load_map,
    parse_map,
)


def test_ring_numbering_and_neighbours(ring_map):
    m = load_map(ring_map)
    assert m.name == "ring"
    assert m.n_cells == 8
    # row-major: row 0 -> 0,1,2 ; row 1 -> 3 (col 0), 4 (col 2) ; row 2 -> 5,6,7
    assert m.state_at(1, 2) == 4 and m.state_at(2, 0) == 5
    assert m.neighbors[0].tolist() == [-1, 1, 3, -1]  # N wall (off grid), E 1, S 3, W off grid
    assert m.neighbors[4].tolist() == [2, -1, 7, -1]  # E off grid, W is the centre wall
    assert m.starts.tolist() == [0]
    assert (m.dot_kind == SMALL_DOT).all()
    assert m.homes.size == 0


def test_cell_kinds():
    m = parse_map("0-oH.\n")
    assert m.dot_kind.tolist() == [SMALL_DOT, 0, BIG, 0, SMALL_DOT]
    assert m.homes.tolist() == [3]


def test_distances_match_bfs(rooms_map):
    m = load_map(rooms_map)
    d = m.distances()
    for s in range(m.n_cells):
        assert (d[s] == bfs(m.neighbors, s)).all()
    assert (d == d.T).all()
    # each step of a move changes the distance to any target by exactly one
    for s in range(m.n_cells):
        for a in (NORTH, EAST, SOUTH, WEST):
            nb = m.neighbors[s, a]
            if nb >= 0:
                assert (np.abs(d[s] - d[nb]) == 1).all()


@pytest.mark.parametrize(
    "text, where, words",
    [
        ("#...#\n#..#\n", ":2:5:", "ragged row"),
        ("#.x.#\n", ":1:3:", "unknown character 'x'"),
        ("; c\n###\n###\n", ":2:1:", "no free cell"),
        ("..#..\n", ":1:4:", "unreachable"),
        ("0.0\n", ":1:3:", "start digit 0 repeated"),
        ("0.2\n", ":1:3:", "1 is missing"),
        ("; only a comment\n", "", "no grid rows"),
    ],
)
def test_broken_maps_name_file_line_column(tmp_path: Path, text, where, words):
    p = tmp_path / "bad.txt"
    p.write_text(text)
    with pytest.raises(MapError) as e:
        load_map(p)
    msg = str(e.value)
    assert msg.startswith(str(p))
    assert where in msg
    assert words in msg
    assert "\n" not in msg


def test_missing_map_file(tmp_path):
    with pytest.raises(MapError, match="no such map file"):
        load_map(tmp_path / "nope.txt")
    with pytest.raises(MapError, match="unknown map name"):
        get_map("no_such_map_name")


def test_shipped_maps_load():
    names = available_maps()
    for n in ("map_a", "map_b", "pacman", "facility"):
        assert n in names
        assert get_map(n).name == n
