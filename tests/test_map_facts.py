"""Facts the shipped maps must hold (paper set-up), and corridor_length on a hand map."""

from pathlib import Path

import numpy as np
import pytest

from qpatrol.maps import EAST, NORTH, SOUTH, WEST, corridor_length, load_map, parse_map

MAPS_DIR = Path(__file__).parent.parent / "maps"
FILES = ["map_a.txt", "map_b.txt", "pacman.txt", "facility.txt"]
N_STARTS = {"map_a.txt": 4, "map_b.txt": 4, "pacman.txt": 4, "facility.txt": 8}


@pytest.fixture(scope="module", params=FILES)
def any_map(request):
    return request.param, load_map(MAPS_DIR / request.param)


def _t_junction_facts(m, state, west, east):
    nb = m.neighbors[state]
    assert m.degree[state] == 3
    assert nb[WEST] >= 0 and nb[EAST] >= 0
    assert (nb[NORTH] >= 0) != (nb[SOUTH] >= 0)  # exactly one of North/South
    assert corridor_length(m, state, WEST) == west
    assert corridor_length(m, state, EAST) == east


def test_map_a_state_13():
    m = load_map(MAPS_DIR / "map_a.txt")
    assert m.name == "map_a"
    _t_junction_facts(m, 13, west=1, east=22)


def test_map_b_state_34():
    m = load_map(MAPS_DIR / "map_b.txt")
    assert m.name == "map_b"
    _t_junction_facts(m, 34, west=4, east=4)


def test_pacman_shape():
    m = load_map(MAPS_DIR / "pacman.txt")
    assert m.name == "pacman"
    assert m.shape == (31, 28)


def test_facility_size():
    m = load_map(MAPS_DIR / "facility.txt")
    assert m.name == "facility"
    assert m.n_cells >= 400


def test_common_facts(any_map):
    fname, m = any_map
    assert m.name == Path(fname).stem
    assert len(m.starts) == N_STARTS[fname]
    assert len(set(m.starts.tolist())) == len(m.starts)
    assert len(m.homes) >= 2
    assert (m.degree[m.homes] >= 2).all(), "a charging station sits in a dead end"
    assert (m.dot_kind > 0).sum() >= 1
    assert m.description


# Hand map (state numbers):      #######
#                                #01234#   state 2 is a T (W, E, S)
#                                ###5###
#                                ###67##   6 and 7 are L-turns
#                                ####8##
#                                #######
HAND_T = "#######\n#.....#\n###.###\n###..##\n####.##\n#######\n"


def test_corridor_length_hand_map():
    m = parse_map(HAND_T)
    assert m.n_cells == 9
    assert m.degree.tolist() == [1, 2, 3, 2, 1, 2, 2, 2, 1]
    assert corridor_length(m, 2, WEST) == 2  # 1, then dead end 0
    assert corridor_length(m, 2, EAST) == 2  # 3, then dead end 4
    assert corridor_length(m, 2, SOUTH) == 4  # 5, 6 (L), 7 (L), dead end 8
    assert corridor_length(m, 2, NORTH) == 0  # wall
    assert corridor_length(m, 8, NORTH) == 4  # 7, 6, 5, junction 2
    assert corridor_length(m, 0, EAST) == 2  # 1, junction 2
    assert corridor_length(m, 1, WEST) == 1  # straight into dead end 0


def test_corridor_length_closed_loop():
    # an 8-cell ring without junctions: the walk comes back to the start after 8 moves
    m = parse_map("#####\n#...#\n#.#.#\n#...#\n#####\n")
    assert np.all(m.degree == 2)
    assert corridor_length(m, 0, EAST) == 8
    assert corridor_length(m, 0, SOUTH) == 8
