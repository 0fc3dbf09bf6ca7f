"""The station rules (``docs/model.md``, "Batteries and stations"), by hand, each engine alone.

Every test here runs a tiny hand-built map from a hand-set state on the numpy engine
and, separately, on the compiled one (skipped without numba), and checks each against
values derived by hand in the test: neither engine is compared with the other, so a
rule broken in :mod:`qpatrol.world.battery` fails the numpy case and one broken in
:mod:`qpatrol.engines.compiled.stations` the compiled case, even without the other
engine at hand.

The robots' asks are fixed: every robot runs the ``random`` strategy with a fixed
uniform per robot, which picks among its *open* moves (not into a wall, a robot's
cell or a held station's pocket; every legal move if none is open) the ``floor(u x
n)``-th in N, E, S, W order. So ``FIRST`` (u = 0) asks for the first open move,
``LAST`` the last one, and ``MID`` (u = 0.5) the second of two or of three. On the
numpy engine one team step is :func:`qpatrol.engines.numpy_loop.advance`
(``world.begin_step``, the strategy, ``world.step``); on the compiled engine one call
of :class:`qpatrol.engines.numba_core.Loop` for one step. Robots needing a station
(homing, queued, charging) do not choose: their uniform is not read.

Cells are numbered row by row over the free cells of the map.
"""

from __future__ import annotations

import numpy as np
import pytest

from qpatrol import measures, strategies, world
from qpatrol.config import from_flat
from qpatrol.engines import numpy_loop
from qpatrol.maps import parse_map
from qpatrol.measures.records import Recorder, Tail
from qpatrol.world.battery import CHARGING, HOMING, PATROL, QUEUED

FIRST, MID, LAST = 0.0, 0.5, 0.999  # a robot's fixed uniform: its first, second, last open move
P, Hm, Q, C = PATROL, HOMING, QUEUED, CHARGING  # short names for the tables of modes


class Team:
    """One run on map ``text``, robots on cells ``starts``, stepped by one engine.

    The battery is on with full batteries and no margin unless ``flat`` says
    otherwise; set the state by hand (:meth:`holds`, ``s.charge``, ...) before the
    first :meth:`step`.
    """

    def __init__(self, engine: str, text: str, starts: list[int], **flat):
        base = {
            "agents": len(starts),
            "policy": "random",
            "battery.enabled": True,
            "battery.capacity": 20,
            "battery.margin": 0,
            "battery.initial_charge": "full",
        }
        cfg = from_flat({**base, **flat})
        m = parse_map(text)
        self.p = p = world.make_params(cfg, m)
        cells = np.array([starts], dtype=np.int64)
        self.s = world.init_state(p, cells)
        self.strategy = strategies.make("random", cfg, m, p, cells)
        self.engine = engine
        self.loop = None

    def holds(self, k: int, h: int, mode: int = PATROL, rest: int = 0, depart_left: int = 0):
        """Robot k holds station h (it stands on it unless homing), in ``mode``."""
        s = self.s
        s.goal[0, k], s.reserved[0, h] = h, k
        s.mode[0, k], s.rest[0, k], s.depart_left[0, k] = mode, rest, depart_left

    def step(self, picks: list[float]) -> None:
        """One team step; ``picks``: each robot's uniform (FIRST, MID, LAST)."""
        s, p, K = self.s, self.p, self.p.n_agents
        u = np.zeros((1, K, 2))
        u[0, :, 1] = picks
        if self.engine == "numpy":
            numpy_loop.advance(s, p, self.strategy, u)
            return
        if self.loop is None:  # built on the hand-set state (the loop shares its arrays)
            from qpatrol.engines import numba_core

            watch = measures.Measures(1, K, p.n_cells, 0)
            rec = Recorder(np.arange(1))
            self.loop = numba_core.Loop(s, p, self.strategy, watch, Tail(0, s), rec, 1)
        self.loop.run([(0, 1, [(0, 1, np.ascontiguousarray(u[:, None]))])])

    def row(self, *ks: int) -> tuple:
        """``(holders of the stations, (cell, mode, charge) of robots ks)`` now."""
        s = self.s
        robots = tuple((int(s.pos[0, k]), int(s.mode[0, k]), int(s.charge[0, k])) for k in ks)
        return (tuple(s.reserved[0].tolist()), *robots)


@pytest.fixture(params=["numpy", "numba"])
def engine(request) -> str:
    if request.param == "numba":
        pytest.importorskip("numba")
    return request.param


# --- 1. first come, first served ---------------------------------------------------------

# A T: the top row 0..6 with the station H on the junction 3, a stem 7, 8, 9 under it.
# H is on a junction: no pocket, depart_len 1 (a holder keeps it 2 steps after charging).
T_MAP = "...H...\n###.###\n###.###\n###.###\n"


def test_two_robots_queued_at_once_are_served_first_come_first_served(engine):
    """Robots 1 and 2 both wait for the one station, held by robot 0; robot 2 began to
    need it a step before robot 1, so robot 2 gets it first although its index is
    higher (and it is no nearer: both are 3 moves away). Robot 1 waits where it is, at
    no cost, until robot 2 has charged and left."""
    team = Team(engine, T_MAP, [3, 1, 6], **{"battery.charge_steps": 2})
    s, p = team.s, team.p
    assert p.homes.tolist() == [3] and p.depart_len.tolist() == [1]
    team.holds(0, 0, depart_left=2 * 1)  # robot 0 has just charged on H: leaving
    s.charge[0] = [20, 4, 4]
    # Threshold: charge <= distance + margin + 1 = distance + 1.
    # step 1: robot 2 (cell 6, 3 from H, charge 4 <= 4) needs a station from step 1 on:
    #   H is held, it waits (QUEUED). Robot 1 (cell 1, 2 from H, 4 > 3) patrols: open W,
    #   E, LAST = West, to cell 0 (charge 3). Robot 0 (MID of E, S, W = South) to 7.
    # step 2: robot 1 (cell 0, 3 from H, 3 <= 4) needs one from step 2 on: waits.
    #   Robot 0 (MID of N, S = South) to 8; it has made 2 x depart_len moves: H released.
    # step 3: the queue: robot 2 (since step 1) before robot 1 (since step 2); robot 2
    #   takes H and goes 5, 4, 3 (steps 3-5, charge 3, 2, 1), charges in steps 6 and 7,
    #   then leaves (FIRST of E, S, W = East) to 4 and 5 (steps 8, 9, full charge 20
    #   less a move each): H released after step 9.
    # step 10: robot 1 (charge 3, 3 moves from H) takes H, goes 1, 2, 3 (steps 10-12),
    #   arriving with charge 0. Robot 2 meanwhile: 6 (step 10, East), 5 (only West), 6.
    # Robot 0 shuttles in the stem: 9, 8, 9, ... (MID at 8 is South, 9 has only North).
    expect = [
        # holder of H, (cell, mode, charge) of robot 1, of robot 2
        ((0,), (0, P, 3), (6, Q, 4)),  # step 1
        ((-1,), (0, Q, 3), (6, Q, 4)),  # step 2
        ((2,), (0, Q, 3), (5, Hm, 3)),  # step 3
        ((2,), (0, Q, 3), (4, Hm, 2)),  # step 4
        ((2,), (0, Q, 3), (3, C, 1)),  # step 5
        ((2,), (0, Q, 3), (3, C, 1)),  # step 6
        ((2,), (0, Q, 3), (3, C, 1)),  # step 7
        ((2,), (0, Q, 3), (4, P, 19)),  # step 8
        ((-1,), (0, Q, 3), (5, P, 18)),  # step 9
        ((1,), (1, Hm, 2), (6, P, 17)),  # step 10
        ((1,), (2, Hm, 1), (5, P, 16)),  # step 11
        ((1,), (3, C, 0), (6, P, 15)),  # step 12
    ]
    got, cells0, waits1 = [], [], []
    for _ in expect:
        team.step([MID, LAST, FIRST])
        got.append(team.row(1, 2))
        cells0.append(int(s.pos[0, 0]))
        waits1.append(int(s.wait[0, 1]))
    assert got == expect
    assert cells0 == [7, 8, 9, 8, 9, 8, 9, 8, 9, 8, 9, 8]
    # robot 1 waits for a station from step 2 to step 9, a wait that grows each step
    assert waits1 == [0, 1, 2, 3, 4, 5, 6, 7, 8, 0, 0, 0]


# --- 2. the nearest free station -----------------------------------------------------------

# A line of 11 cells, stations on cells 0 (station 0) and 8 (station 1); cell c is c
# moves from station 0 and |8 - c| from station 1.
LINE_2H = "H.......H..\n"


@pytest.mark.parametrize(
    "charge, margin, other, expect",
    [
        # Robot 0 on cell 5 (5 from station 0, 3 from station 1), charge 7, margin 3:
        # 7 <= 3 + 3 + 1, it needs a station at step 1. Both are free and within reach
        # (5 <= 7, 3 <= 7): it takes the nearer, station 1 (the higher index), and goes
        # 6, 7, 8, one unit a move, arriving (charging) at step 3 with 4.
        (7, 3, None, [((-1, 0), (6, Hm, 6)), ((-1, 0), (7, Hm, 5)), ((-1, 0), (8, C, 4))]),
        # The same, but robot 1 charges on station 1: robot 0 takes the nearest *free*
        # station, station 0, 5 moves away: 4, 3, 2, 1, 0, arriving with 2.
        (
            7,
            3,
            "charging",
            [
                ((0, 1), (4, Hm, 6)),
                ((0, 1), (3, Hm, 5)),
                ((0, 1), (2, Hm, 4)),
                ((0, 1), (1, Hm, 3)),
                ((0, 1), (0, C, 2)),
            ],
        ),
        # Station 1 held again, and robot 0 has charge 4, margin 0 (4 <= 3 + 0 + 1): the
        # free station 0 is 5 moves away, out of its reach: it waits on cell 5 (QUEUED,
        # no move, no charge spent).
        (4, 0, "charging", [((-1, 1), (5, Q, 4))] * 5),
    ],
)
def test_the_nearest_free_station_within_reach_is_taken(engine, charge, margin, other, expect):
    starts = [5] if other is None else [5, 10]
    team = Team(engine, LINE_2H, starts, **{"battery.margin": margin, "battery.charge_steps": 9})
    s, p = team.s, team.p
    assert p.homes.tolist() == [0, 8]
    if other is not None:
        s.occ[0, 10], s.pos[0, 1], s.occ[0, 8] = -1, 8, 1
        team.holds(1, 1, mode=CHARGING, rest=9)  # on station 1 for the whole test
    s.charge[0, 0] = charge
    got = []
    for _ in expect:
        team.step([FIRST] * len(starts))
        got.append(team.row(0))
    assert got == expect


# --- 3. the bound on a wait ------------------------------------------------------------------

# A T with two dead ends holding stations: the top row 0..4 (station 0 on cell 0), the
# junction 2, the stem 5, 6, 7 under it (station 1 on cell 7).
TWO_DEAD_ENDS = "H.-..\n##.##\n##.##\n##H##\n"


def test_wait_bound_exact_value():
    """``measures.wait_bound``, the fair-queue bound of docs/model.md, on a map whose
    quantities are counted by hand: ``K x (charge_steps + 2 x max depart_len +
    diameter) + diameter`` with the battery on, ``diameter`` without."""
    K, charge_steps = 3, 4
    cfg = from_flat({"agents": K, "battery.capacity": 20, "battery.charge_steps": charge_steps})
    p = world.make_params(cfg, parse_map(TWO_DEAD_ENDS))
    # by hand: station 0 (cell 0) is 2 moves from the junction (0 -> 1 -> 2), station 1
    # (cell 7) 3 moves (7 -> 6 -> 5 -> 2); the longest shortest path joins the two
    # stations, 0 -> 1 -> 2 -> 5 -> 6 -> 7 (5 moves; 4 -> 7 is 5 moves too).
    depart_len, diameter = [2, 3], 5
    assert p.homes.tolist() == [0, 7]
    assert p.depart_len.tolist() == depart_len and p.diameter == diameter
    turnaround = charge_steps + 2 * max(depart_len) + diameter  # 4 + 6 + 5 = 15
    assert measures.wait_bound(p) == K * turnaround + diameter == 50
    off = world.make_params(cfg.replace(**{"battery.enabled": False}), parse_map(TWO_DEAD_ENDS))
    assert measures.wait_bound(off) == diameter == 5
