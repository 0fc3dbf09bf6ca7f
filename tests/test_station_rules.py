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
of :class:`qpatrol.engines.numba_core.Loop` for one step. The compiled loop draws its
uniforms itself from the run's PCG64 state, so each step starts it from a state whose
next draws fall where the fixed uniform's choice is made whatever the number of open
moves (:func:`stream_for`). Robots needing a station
(homing, queued, charging) do not choose: their uniform is not read.

Cells are numbered row by row over the free cells of the map.
"""

from __future__ import annotations

import mazes
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qpatrol import measures, strategies, world
from qpatrol.config import ConfigError, from_flat
from qpatrol.engines import numpy_loop
from qpatrol.maps import parse_map
from qpatrol.measures.records import Recorder, Tail
from qpatrol.world import battery
from qpatrol.world.battery import CHARGING, HOMING, PATROL, QUEUED

FIRST, MID, LAST = 0.0, 0.5, 0.999  # a robot's fixed uniform: its first, second, last open move
#: The uniforms that choose as FIRST, MID and LAST do among 1 to 4 open moves:
#: floor(u n) is 0 for u < 1/4, (n - 1) for u >= 3/4, and floor(0.5 n) for u in [1/2, 2/3).
CHOOSE_ALIKE = {FIRST: (0.0, 0.25), MID: (0.5, 2 / 3), LAST: (0.75, 1.0)}
M64 = (1 << 64) - 1


def stream_for(picks: list[float]) -> np.ndarray:
    """uint64 ``[4]``: a PCG64 state (state low, high, inc low, high) whose next ``2 K``
    uniforms give each robot k a tie-break uniform that chooses as ``picks[k]`` does
    (``CHOOSE_ALIKE``), found by trying seeds in turn."""
    for seed in range(1_000_000):
        g = np.random.Generator(np.random.PCG64(seed))
        st = g.bit_generator.state["state"]
        ties = g.random((len(picks), 2))[:, 1]
        bounds = [CHOOSE_ALIKE[pick] for pick in picks]
        if all(lo <= x < hi for x, (lo, hi) in zip(ties, bounds, strict=True)):
            s, inc = st["state"], st["inc"]
            return np.array([s & M64, s >> 64, inc & M64, inc >> 64], dtype=np.uint64)
    raise AssertionError(f"no stream found for {picks}")


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

    def holds(
        self, k: int, h: int, mode: int = PATROL, rest: int = 0, depart_left: int = 0
    ) -> None:
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
        loop = self._loop()
        loop.words[0] = stream_for(picks)
        loop.run(1, [(0, 1)])

    def _loop(self):
        """The compiled loop, built on the hand-set state (it shares the state's arrays)."""
        if self.loop is None:
            from qpatrol.engines import numba_core

            s, p, K = self.s, self.p, self.p.n_agents
            watch = measures.Measures(1, K, p.n_cells, 0)
            rec = Recorder(np.arange(1))
            words = np.zeros((1, 4), dtype=np.uint64)
            tail = Tail(0, s)
            self.loop = numba_core.Loop(s, p, self.strategy, watch, tail, rec, 1, lambda: words)
        return self.loop

    def end_of_step(self, asked: list[bool]) -> None:
        """The battery's end of a step alone (``battery.end``, the compiled
        ``stations.end``): no robot moved, ``asked`` says which asked for a move."""
        if self.engine == "numpy":
            from qpatrol.world import battery

            moved = np.zeros((1, self.p.n_agents), dtype=bool)
            battery.end(self.s, self.p, moved, np.array([asked]))
            return
        from qpatrol.engines.compiled import stations

        _, bp, _, _, bs, _, _, w = self._loop().args
        w.moved[:] = False
        w.ask[:] = np.where(asked, 0, -1)
        stations.end(0, bp, bs, w)

    def rows(self, n: int, picks: list[float], *ks: int) -> list[tuple]:
        """:meth:`row` of robots ``ks`` after each of ``n`` steps taken with ``picks``."""
        out = []
        for _ in range(n):
            self.step(picks)
            out.append(self.row(*ks))
        return out

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

# A row of 11 cells, stations on cells 0 (station 0) and 8 (station 1), and one-cell
# spurs under cells 1 (cell 11) and 8 (cell 12), so the map is not a line and has room
# for two robots (a battery team on a line with a station at an end is refused): cell c
# of the row is c moves from station 0 and |8 - c| from station 1. Station 0 is alone
# in its pocket, station 1 on a junction.
ROW_2H = "H.......H..\n#.######.##\n"


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
    team = Team(engine, ROW_2H, starts, **{"battery.margin": margin, "battery.charge_steps": 9})
    s, p = team.s, team.p
    assert p.homes.tolist() == [0, 8]
    assert p.home_dist[:, 5].tolist() == [5, 3] and p.pocket_of.tolist() == [0] + [-1] * 12
    if other is not None:
        s.occ[0, 10], s.pos[0, 1], s.occ[0, 8] = -1, 8, 1
        team.holds(1, 1, mode=CHARGING, rest=9)  # on station 1 for the whole test
    s.charge[0, 0] = charge
    assert team.rows(len(expect), [FIRST] * len(starts), 0) == expect


# --- 3. the bound on a wait ------------------------------------------------------------------

# Two dead ends holding stations: the row 3..7 (station 0 on cell 3), the junction 5,
# the stem 8, 9, 10 under it (station 1 on cell 10), and above the junction cells 0, 1,
# 2 (1 over 5, 0 over 1, 2 over 6 and beside 1): room for three robots outside the
# stations' pockets (3, 4 and 8, 9, 10) under the room rule.
TWO_DEAD_ENDS = "##.##\n##..#\nH.-..\n##.##\n##.##\n##H##\n"


def test_pockets_of_one_junction_are_not_taken_at_once(engine):
    """Robots 0 and 1 need a station in the same step and each could reach a free one,
    but the pockets of the two stations of this T share their junction (cell 5): robot
    0 (lower index) takes station 0 and goes home; robot 1 waits (QUEUED, no move) until
    robot 0 stands on its station, and only then takes station 1."""
    team = Team(engine, TWO_DEAD_ENDS, [7, 6], **{"battery.charge_steps": 9})
    s, p = team.s, team.p
    assert p.homes.tolist() == [3, 10] and p.pocket_entry.tolist() == [5, 5]
    # robot 0: 4 moves from station 0, 5 from station 1; robot 1: 3 and 4. Both at the
    # threshold (charge <= distance + 1) in step 1.
    s.charge[0] = [5, 4]
    modes = []
    for _ in range(12):
        team.step([FIRST, FIRST])
        modes.append(tuple(int(x) for x in s.mode[0]))
        assert not (s.mode[0] == HOMING).all()
    assert modes[0] == (Hm, Q)
    first_charge = next(i for i, m in enumerate(modes) if m[0] == C)
    first_home = next(i for i, m in enumerate(modes) if m[1] != Q)
    assert all(m[1] == Q for m in modes[:first_charge])
    assert first_home == first_charge + 1 and modes[first_home][1] == Hm
    assert s.goal[0].tolist() == [0, 1]


def test_stall_bound_exact_value():
    """``measures.stall_bound``, the bound on a stretch without progress of docs/model.md,
    on a map whose quantities are counted by hand: a trip of ``diameter + 2`` steps;
    ``K x (charge_steps + 2 x max depart_len + 2 x trip + 1) + trip`` with the battery
    on, ``K x trip`` without."""
    K, charge_steps = 3, 4
    cfg = from_flat({"agents": K, "battery.capacity": 20, "battery.charge_steps": charge_steps})
    p = world.make_params(cfg, parse_map(TWO_DEAD_ENDS))
    # by hand: station 0 (cell 3) is 2 moves from the nearest junction (3 -> 4 -> 5),
    # station 1 (cell 10) 3 moves (10 -> 9 -> 8 -> 5); the longest shortest path joins
    # the two stations, 3 -> 4 -> 5 -> 8 -> 9 -> 10 (5 moves; 7 -> 10 and 0 -> 10 are 5
    # moves too: every cell above the junction is within 2 of it).
    depart_len, diameter = [2, 3], 5
    assert p.homes.tolist() == [3, 10]
    assert p.depart_len.tolist() == depart_len and p.diameter == diameter
    # the formula's terms, spelled out (a new formula: rewrite these lines from the
    # hand-counted quantities above, not from what stall_bound returns)
    trip = diameter + 2  # 7
    turnaround = charge_steps + 2 * max(depart_len) + 2 * trip + 1  # 4 + 6 + 14 + 1 = 25
    assert measures.stall_bound(p) == K * turnaround + trip == 3 * 25 + 7 == 82
    off = world.make_params(cfg.replace(**{"battery.enabled": False}), parse_map(TWO_DEAD_ENDS))
    assert measures.stall_bound(off) == K * trip == 21


# --- 4. charging, then holding the station while leaving -----------------------------------

LINE_H = "H....\n"  # station on cell 0 of a line: no junction, depart_len 1


@pytest.mark.parametrize("charge_steps", [0, 1, 3])
def test_charging_lasts_charge_steps_steps_and_the_station_is_kept_2_depart_len(
    engine, charge_steps
):
    """A robot on its station charges ``charge_steps`` whole steps without moving, then
    patrols with a full charge, keeping the station for ``2 x depart_len`` moves. With
    ``charge_steps`` 0 it is full on arrival."""
    team = Team(engine, LINE_H, [1], **{"battery.charge_steps": charge_steps})
    s, p = team.s, team.p
    assert p.depart_len.tolist() == [1]
    s.charge[0, 0] = 2
    # step 1: 1 move from H, 2 <= 1 + 0 + 1: it takes H and goes there (charge 1),
    #   charging (with charge_steps 0: full at once, 20, and leaving);
    # steps 2 .. 1 + charge_steps: it charges, not moving (charge still 1);
    # next step: charged, full (20), it leaves East (its only move) to cell 1 (19),
    #   holding H 2 x 1 moves: still held after this step,
    # and the step after it goes on to cell 2 (18) and H is released.
    expect = (
        [((0,), (0, C, 1) if charge_steps else (0, P, 20))]
        + [((0,), (0, C, 1))] * charge_steps
        + [((0,), (1, P, 19)), ((-1,), (2, P, 18))]
    )
    assert team.rows(len(expect), [FIRST], 0) == expect


# The T of a dead end: the top row 0..4, the junction 2, the station H on cell 6 at the
# end of the stem 5, 6: the pocket is cells 5 (depth 1) and 6 (depth 2), its junction 2;
# depart_len 2 (6 -> 5 -> 2).
DEAD_END = "..-..\n##.##\n##H##\n"


def test_a_charged_robot_keeps_its_station_for_2_depart_len_moves(engine):
    """Robot 0 finishes charging on H at step 1 and holds it for 2 x depart_len = 4
    moves while it leaves; robot 1, which needs H from step 1 on, waits until then."""
    team = Team(engine, DEAD_END, [6, 0], **{"battery.charge_steps": 2})
    s, p = team.s, team.p
    assert p.homes.tolist() == [6] and p.depart_len.tolist() == [2]
    assert p.pocket_entry.tolist() == [2]
    team.holds(0, 0, mode=CHARGING, rest=0)  # its last charging step was step 0
    s.charge[0] = [3, 5]
    # step 1: robot 0 is charged (20), holds H for 4 more moves: 5, 2, 3, 4 (FIRST: N
    #   from 5, E from 2 and 3), steps 1-4 (charge 19 .. 16); H released after step 4.
    #   Robot 1 (cell 0, 4 moves from H: 0 -> 1 -> 2 -> 5 -> 6, 5 <= 4 + 0 + 1) needs
    #   H from step 1 on and waits, its charge kept.
    # step 5: robot 1 takes H: 1, 2, 5, 6 (steps 5-8), arriving with 1. Robot 0: 3 (its
    #   only move from 4), 4, 3, 4.
    expect = [
        ((0,), (5, P, 19), (0, Q, 5)),
        ((0,), (2, P, 18), (0, Q, 5)),
        ((0,), (3, P, 17), (0, Q, 5)),
        ((-1,), (4, P, 16), (0, Q, 5)),
        ((1,), (3, P, 15), (1, Hm, 4)),
        ((1,), (4, P, 14), (2, Hm, 3)),
        ((1,), (3, P, 13), (5, Hm, 2)),
        ((1,), (4, P, 12), (6, C, 1)),
    ]
    assert team.rows(len(expect), [FIRST, FIRST], 0, 1) == expect


def test_a_leaving_robot_that_stops_asking_releases_its_station_at_once(engine):
    """The end of a step alone (``battery.end``; the compiled ``stations.end``), the
    asks given: a robot leaving its station (``depart_left`` > 0) keeps it while it
    asks to move, one move less to go each step, and releases it the step it asks for
    none (the random strategy always asks, so the whole step cannot show this)."""
    team = Team(engine, DEAD_END, [2])
    s = team.s
    team.holds(0, 0, depart_left=3)
    team.end_of_step(asked=[True])
    assert (s.reserved[0, 0], s.goal[0, 0], s.depart_left[0, 0]) == (0, 0, 2)
    team.end_of_step(asked=[False])
    assert (s.reserved[0, 0], s.goal[0, 0], s.depart_left[0, 0]) == (-1, -1, 0)


# --- 5. pockets: kept clear while their station is held; yielding is free ----------------

# A T with a longer dead end: the top row 0..4, the junction 2, the stem 5, 6 and the
# station H on cell 7: the pocket is 5, 6, 7 (depths 1, 2, 3), its junction 2.
# Distances to H: 7 - c for c = 5..7, 3 from cell 2, 4 from cells 1 and 3, 5 from 0 and 4.
DEEP_END = "..-..\n##.##\n##.##\n##H##\n"


def deep_end(engine: str, starts: list[int]) -> Team:
    team = Team(engine, DEEP_END, starts, **{"battery.charge_steps": 2})
    p = team.p
    assert p.homes.tolist() == [7] and p.pocket_entry.tolist() == [2]
    assert p.pocket_of.tolist() == [-1] * 5 + [0, 0, 0]
    assert p.pocket_depth.tolist() == [0] * 5 + [1, 2, 3]
    return team


def test_a_queued_robot_leaves_a_held_pocket_free_and_credited_the_holder_waits(engine):
    """Robot 1, waiting for a station (QUEUED) deep in the pocket of H, steps out when
    robot 0 holds H: up to the junction, at no charge, credited the distance it put
    between itself and the station (its charge grows by one a move), and waits there.
    Robot 0, homing, waits before the junction until the pocket is empty, then, with
    the right of way, pushes robot 1 off the junction (free and credited) and goes in."""
    team = deep_end(engine, [0, 6])
    s = team.s
    team.holds(0, 0, mode=HOMING)
    s.mode[0, 1] = QUEUED  # since step 0
    s.charge[0] = [10, 2]
    # step 1: robot 0 moves 0 -> 1 (not yet onto the junction; charge 9); robot 1 (in the
    #   held pocket) steps out 6 -> 5: free, credited 2 - 1 = 1 more move to H: 3.
    # step 2: robot 0 would enter the junction with robot 1 in the pocket: held back (it
    #   waits, charge kept). Robot 1: 5 -> 2 (out of the pocket, 3 from H): 4.
    # step 3: the pocket is empty; robot 0 asks for the junction, where robot 1 (queued,
    #   out of the pocket) waits: blocked, it gets the right of way.
    # step 4: robot 0 pushes robot 1 to the nearest empty cell, N E S W: East, 3 (4 from
    #   H: credited, 5), and takes the junction (charge 8).
    # steps 5-7: robot 0 goes 5, 6, 7 (7, 6, 5), charging from step 7; robot 1 waits on
    #   3 (QUEUED, charge 5).
    expect = [
        ((0,), (1, Hm, 9), (5, Q, 3)),
        ((0,), (1, Hm, 9), (2, Q, 4)),
        ((0,), (1, Hm, 9), (2, Q, 4)),
        ((0,), (2, Hm, 8), (3, Q, 5)),
        ((0,), (5, Hm, 7), (3, Q, 5)),
        ((0,), (6, Hm, 6), (3, Q, 5)),
        ((0,), (7, C, 5), (3, Q, 5)),
    ]
    got, waits0 = [], []
    for _ in expect:
        team.step([FIRST, FIRST])
        got.append(team.row(0, 1))
        waits0.append(int(s.wait[0, 0]))
    assert got == expect
    assert waits0 == [0, 1, 2, 0, 0, 0, 0]  # held back at step 2, blocked at 3: waits


def test_a_homing_robot_on_the_junction_steps_aside_free_for_one_leaving_the_pocket(engine):
    """Robot 0, homing to H, stands on the pocket's junction while robot 1 patrols in the
    pocket: robot 0 yields (off the junction, at no charge, credited the detour), robot
    1, shut in, steps out (also at no charge), then robot 0 goes in."""
    team = deep_end(engine, [2, 5])
    s = team.s
    team.holds(0, 0, mode=HOMING)
    s.charge[0] = [5, 20]
    # step 1: robot 0 on the junction, robot 1 in the pocket: robot 0 steps off to the
    #   first free neighbour outside the pocket (N E S W): 3, 4 moves from H instead of
    #   3: free and credited 1 (charge 6). Robot 1, shut in the held pocket, does not
    #   choose: it steps out, North, and follows onto 2 (yielding: free, 20).
    # step 2: robot 0 heads back onto 2 (the pocket is empty), where robot 1 stands;
    #   robot 1's open moves: West only (East is robot 0's cell, South the held pocket):
    #   it goes to 1 (19), robot 0 follows onto 2 (5).
    # steps 3-5: robot 0 goes 5, 6, 7 (4, 3, 2), charging from step 5. Robot 1: East is
    #   robot 0's cell at the start of step 3: West, to 0 (18); then East to 1 (17), and
    #   from 1 East to 2 (16), free again.
    expect = [
        ((0,), (3, Hm, 6), (2, P, 20)),
        ((0,), (2, Hm, 5), (1, P, 19)),
        ((0,), (5, Hm, 4), (0, P, 18)),
        ((0,), (6, Hm, 3), (1, P, 17)),
        ((0,), (7, C, 2), (2, P, 16)),
    ]
    assert team.rows(len(expect), [FIRST, FIRST], 0, 1) == expect


def test_patrolling_robots_do_not_enter_a_held_pocket(engine):
    """Robot 1 patrols on the junction of H's pocket while robot 0, homing, holds H:
    the move South, into the pocket, is not open to it."""
    team = deep_end(engine, [4, 2])
    team.holds(0, 0, mode=HOMING)
    # step 1: robot 1's open moves are East and West (South is closed): MID takes the
    #   second, West, to 1 (with South open it would take South, into the pocket).
    #   Robot 0: 4 -> 3.
    # step 2: robot 1 at 1: East (2, free) and West (0): MID, West, to 0. Robot 0: 2.
    # step 3: robot 0 into the pocket: 5. Robot 1: its only move, back to 1.
    expect = [
        ((0,), (3, Hm, 19), (1, P, 19)),
        ((0,), (2, Hm, 18), (0, P, 18)),
        ((0,), (5, Hm, 17), (1, P, 17)),
    ]
    assert team.rows(len(expect), [FIRST, MID], 0, 1) == expect


# DEEP_END with one more cell on the left (room for three robots): the top row 0..5,
# the junction 3, the stem 6, 7 and the station H on cell 8 (the pocket 6, 7, 8).
DEEP_END_3 = "...-..\n###.##\n###.##\n###H##\n"


def test_a_push_does_not_shift_robots_into_a_held_pocket(engine):
    """The robot with right of way (robot 0, homing to H) pushes the robots in its way
    along the nearest empty cells, but not into the pocket of a held station: robot 1 on
    the junction goes East (shifting robot 2 on), not South into the empty pocket."""
    team = Team(engine, DEEP_END_3, [2, 3, 4], **{"battery.charge_steps": 2})
    s, p = team.s, team.p
    assert p.homes.tolist() == [8] and p.pocket_entry.tolist() == [3]
    assert p.pocket_of.tolist() == [-1] * 6 + [0, 0, 0]
    team.holds(0, 0, mode=HOMING)
    s.token[0] = 0
    s.charge[0, 0] = 10
    # step 1: robot 0 asks for 3 (East, towards H), taken by robot 1. The push search
    #   from 3 (N E S W, not through robot 0's cell 2, not into the held pocket 6, 7, 8)
    #   finds 4 (robot 2) then the empty cell 5: robot 2 shifts 4 -> 5, robot 1 3 -> 4,
    #   robot 0 takes 3 (charge 9). Robot 2 asked for East (its only open move): as
    #   asked, it pays (19); robot 1 asked for West (LAST of its legal moves, none being
    #   open): pushed, free (20).
    # step 2: robot 0 goes on, 6 (8); robot 1 at 4 and robot 2 at 5 have no open move
    #   (their neighbours are taken at the start of the step): robot 1 asks for its
    #   last legal move, West, robot 2 for its only one, West: each follows the robot
    #   ahead, 1 to 3 (19), 2 to 4 (18).
    expect = [
        ((0,), (3, Hm, 9), (4, P, 20), (5, P, 19)),
        ((0,), (6, Hm, 8), (3, P, 19), (4, P, 18)),
    ]
    assert team.rows(len(expect), [FIRST, LAST, FIRST], 0, 1, 2) == expect


# --- 6. pushes: free, and credited to a robot that needs a station ------------------------

# A row of 9 cells, the station on cell 0 (cell c of the row is c moves from it), and a
# two-cell spur (cells 9, 10) under cell 1, so the map is not a line and a robot on its
# way to H has room for two others past cell 1 (the room rule, three robots).
ROW_9 = "H........\n#.#######\n#.#######\n"


@pytest.mark.parametrize("mode", [HOMING, QUEUED])
def test_a_robot_needing_a_station_pushed_away_is_credited_the_detour(engine, mode):
    """Robot 0, with right of way, moves East into robot 1's cell 3: robot 1 is pushed
    on to 4, one move farther from H. Robot 1 needs H (homing to it, or queued while
    robot 2 charges on it): the push costs it nothing and it is credited that move.
    Robot 0 pays its own move."""
    team = Team(engine, ROW_9, [2, 3, 8] if mode == HOMING else [2, 3, 0])
    s = team.s
    s.token[0] = 0
    s.charge[0] = [20, 4, 20]
    if mode == HOMING:
        team.holds(1, 0, mode=HOMING)  # robot 1 holds H; robot 2 patrols far away
    else:
        team.holds(2, 0, mode=CHARGING, rest=5)  # robot 2 charges on H
        s.mode[0, 1] = QUEUED  # 4 <= 3 + 0 + 1, and H is held: it waits
    # step 1: robot 0 (token: sees every legal move open) FIRST: East, into 3: robot 1
    #   shifts to 4 (the nearest empty cell away from robot 0): 4 - 3 = 1 more move to
    #   H, credited: 4 + 1 = 5. Robot 0 pays 1: 19.
    team.step([FIRST, FIRST, FIRST])
    assert s.pos[0, :2].tolist() == [3, 4]
    assert s.charge[0, :2].tolist() == [19, 5]
    assert s.mode[0, 1] == mode


def test_a_charging_robot_is_not_pushed_off_its_station(engine):
    """Robot 0 holds the right of way beside the station cell where robot 1 charges: a
    charging robot cannot be pushed, so the move into it is not among the holder's open
    moves (traffic.feasible_moves) and robot 0 takes its other one, West, as its own
    move (it pays for it). Were charging robots pushable, East would be open, robot 0
    would take it (its FIRST move) and push robot 1 off the station."""
    team = Team(engine, "..H..\n", [1, 2])
    s = team.s
    team.holds(1, 0, mode=CHARGING, rest=5)
    s.token[0] = 0
    # step 1: robot 0 (token): East into 2 would need a push of the charging robot 1,
    #   so only West is open; FIRST of one: West, to 0, its own move: 20 - 1 = 19.
    #   Robot 1 stays on H, charging (20).
    team.step([FIRST, FIRST])
    assert team.row(0, 1) == ((1,), (0, P, 19), (2, C, 20))


# --- 7. a held pocket is closed: nobody enters, those inside step out first -------------

# A row of 9 cells with the junction 4, under it the pocket 9, 10, 11 (H at its end).
ROW_POCKET = "....-....\n####.####\n####.####\n####H####\n"


def test_a_move_into_a_held_pocket_is_not_made_even_with_no_open_move(engine):
    """Robot 1 patrols on the junction 4 between robot 0 (homing to H, on 3) and robot 2
    (on 5): it has no open move (East and West are taken, South is the held pocket), so
    it chooses among its legal ones, East, South, West: MID, South, into the pocket. The
    move is not made (a held pocket is closed to every robot but its holder); robot 0,
    blocked, gets the right of way and then pushes robot 1 off the junction."""
    team = Team(engine, ROW_POCKET, [3, 4, 5])
    assert team.p.pocket_entry.tolist() == [4] and team.p.homes.tolist() == [11]
    team.holds(0, 0, mode=HOMING)
    # step 1: robot 0 asks for 4 (the pocket is empty: not held back): taken, it waits.
    #   Robot 1: South, into 9, not made: it stays on 4 (were it made: 9, charge 19).
    #   Robot 2 (on 5): open moves East (6) and West (4 is taken: no): FIRST, East (19).
    # step 2: robot 0 holds the right of way and pushes robot 1 along the first path to
    #   an empty cell, East to 5 (19 for robot 0). Robot 1 now has one open move, East
    #   (5), asked and made by the push: its own move (19). Robot 2: FIRST of East (7)
    #   and West (5, empty at the start of the step): East (18).
    expect = [
        ((0,), (3, Hm, 20), (4, P, 20), (6, P, 19)),
        ((0,), (4, Hm, 19), (5, P, 19), (7, P, 18)),
    ]
    assert team.rows(len(expect), [FIRST, MID, FIRST], 0, 1, 2) == expect


# A row of 11 cells with the junction 5, under it the pocket 11, 12, 13 (H at its end).
ROW_DEEP = ".....-.....\n#####.#####\n#####.#####\n#####H#####\n"


def test_a_push_shifts_robots_out_of_a_held_pocket(engine):
    """Robots 1, 2, 3 patrol in the pocket (11, 12, 13) of H, which robot 0 holds; robot
    4 waits for a station on the junction 5. Shut in, the three step out, robot 1 first,
    blocked by robot 4. Robot 3, deepest and with the oldest task, gets the right of way
    and pushes the whole row out: robots 2 and 1 one cell towards the junction (a push
    inside a held pocket may go towards its junction), robot 4 off the junction, East.
    Stepping out is yielding: free; robot 4, pushed away from H, is credited a move."""
    team = Team(engine, ROW_DEEP, [0, 11, 12, 13, 5])
    s = team.s
    assert team.p.pocket_entry.tolist() == [5] and team.p.pocket_depth[11:].tolist() == [1, 2, 3]
    team.holds(0, 0, mode=HOMING)
    s.mode[0, 4] = QUEUED
    s.charge[0, 4] = 4  # 4 <= 3 + 0 + 1 (three moves from H): it still needs a station
    s.since[0, 3] = -5  # robot 3's task is the oldest
    # step 1: robot 0 walks East, 0 -> 1 (19). Robots 1, 2, 3 ask for 5, 11, 12: all
    #   taken, they wait; robot 4 waits for H. Right of way: robot 3, the oldest task.
    team.step([FIRST] * 5)
    assert s.pos[0].tolist() == [1, 11, 12, 13, 5] and s.token[0] == 3
    # step 2: robot 3 asks for 12: the push search from 12 goes to 11 (towards the
    #   junction: allowed inside the held pocket), then 5, then its first neighbour, East,
    #   6, empty: robot 4 -> 6, robot 1 -> 5, robot 2 -> 11, robot 3 -> 12, each free;
    #   robot 4 is 4 moves from H instead of 3: credited, 5. Robot 0: 1 -> 2 (18).
    team.step([FIRST] * 5)
    assert s.pos[0].tolist() == [2, 5, 11, 12, 6]
    assert s.charge[0].tolist() == [18, 20, 20, 20, 5]


@pytest.mark.parametrize("longest", [0, 2])
def test_the_right_of_way_goes_to_the_oldest_task_whatever_it_does(engine, longest):
    """Robot 0, homing to H, is blocked by robot 3 (queued on 2); robot 2, shut in the
    pocket behind robot 1, and robot 1, blocked by robot 4 on the junction, step out.
    One of robot 0 (homing) and robot 2 (stepping out of a pocket) began its task 9
    steps before the others. After a step in which all three are blocked, the right of
    way goes to the one with the oldest task: one order for every robot, whether it
    patrols, homes or steps out of a pocket (robot 2, in the pocket robot 0 holds,
    carries robot 0's age)."""
    team = Team(engine, ROW_DEEP, [1, 11, 12, 2, 5])
    s = team.s
    team.holds(0, 0, mode=HOMING)
    s.mode[0, [3, 4]] = QUEUED
    s.charge[0, [3, 4]] = [4, 4]  # at most 3 + 0 + 1 moves from H: both still queue
    s.since[0, longest] = -9
    # step 1: robot 0 asks for 2, robot 1 for 5, robot 2 for 11: all taken, each waits
    #   a step. Robots 1 and 2 stand in the pocket robot 0 holds: they step out on robot
    #   0's behalf and carry at least robot 0's age (battery.close_tasks). Right of way:
    #   the oldest task; among robots 0, 1 and 2 at one age, the turn at step 2,
    #   (K - 1) - (k - 2) mod K: robot 2 (4) before robot 0 (1) and robot 1 (0).
    team.step([FIRST] * 5)
    assert s.pos[0].tolist() == [1, 11, 12, 2, 5]
    assert s.wait[0, :3].tolist() == [1, 1, 1]
    assert s.since[0, :3].tolist() == ([-9, -9, -9] if longest == 0 else [0, 0, -9])
    assert s.token[0] == 2


# --- 8. the room past the narrowest door -----------------------------------------------

# A row of 11 cells, H on cell 0 (its pocket: cell 0 alone, the junction 1), a spur of
# three cells (11, 12, 13) under cell 1.
ROW_SPUR = "H..........\n#.#########\n#.#########\n#.#########\n"


def test_the_room_past_the_narrowest_door_by_hand():
    """A robot homing to H from cell 2 asks for the junction 1; with it on 2 and H's
    pocket closed, a push from 1 can use 1 and the spur: 4 cells. From the spur (11 ->
    1: the row 1..10, 10 cells; 12 -> 11: 11 cells) and from farther along the row
    (3 -> 2: 2..10 with 1 and the spur, 12 cells) the room is larger. So at most 4
    robots, and the error names the door, cell 1 at row 0, col 1."""
    m = parse_map(ROW_SPUR)
    p = world.make_params(from_flat({"agents": 4, "battery.capacity": 40}), m)
    assert p.pocket_of.tolist()[:2] == [0, -1] and p.pocket_entry.tolist() == [1]
    room, door = battery.door_room(m.neighbors, p.homes, p.home_dir, p.pocket_of, p.pocket_entry)
    assert (room, door) == (4, 1)
    with pytest.raises(ConfigError) as e:
        world.make_params(from_flat({"agents": 5, "battery.capacity": 40}), m)
    assert str(e.value).startswith("agents: 5 robots with battery.enabled")
    assert "door at row 0, col 1" in str(e.value) and "allowed: at most 4 " in str(e.value)


def _reached(nbrs: list[list[int]], v: int, u: int, removed) -> int:
    """Cells a breadth-first search from v reaches without entering u or removed cells."""
    seen, todo = {v}, [v]
    while todo:
        for w in nbrs[todo.pop()]:
            if w >= 0 and w != u and not removed[w] and w not in seen:
                seen.add(w)
                todo.append(w)
    return len(seen)


def _room_by_search(m, p) -> int:
    """The room rule's number from its definition: for every station and cell, one
    breadth-first search of the part the push may use (an independent implementation
    of :func:`battery.door_room`, which computes all at once from one depth-first
    search)."""
    nbrs = m.neighbors.tolist()
    best = m.n_cells
    for i in range(p.homes.size):
        entry = p.pocket_entry
        same = (entry[np.maximum(p.pocket_of, 0)] == entry[i]) & (entry[i] >= 0)
        removed = (p.pocket_of >= 0) & ~(same & (p.pocket_of != i))
        for u in range(m.n_cells):
            d = int(p.home_dir[i, u])
            if removed[u] or d < 0 or removed[nbrs[u][d]]:
                continue
            best = min(best, _reached(nbrs, nbrs[u][d], u, removed))
    return best


@given(
    seed=st.integers(0, 10**6),
    loops=st.sampled_from([0.0, 0.1, 0.3]),
    rows=st.integers(2, 5),
    cols=st.integers(2, 6),
    dead=st.booleans(),
)
@settings(max_examples=60)
def test_the_room_ahead_matches_a_search_from_its_definition(seed, loops, rows, cols, dead):
    m = parse_map(mazes.random_maze(rows, cols, seed, loops, dead_end_stations=dead))
    p = world.make_params(from_flat({"agents": 1, "battery.capacity": 10**5}), m)
    room, door = battery.door_room(m.neighbors, p.homes, p.home_dir, p.pocket_of, p.pocket_entry)
    assert room == _room_by_search(m, p)
    assert (door >= 0) == (room < m.n_cells)


@given(
    seed=st.integers(0, 10**6),
    loops=st.sampled_from([0.0, 0.2, 0.5]),
    cut=st.floats(0.0, 0.2),
)
@settings(max_examples=40)
def test_every_room_ahead_matches_a_search(seed, loops, cut):
    """The room of every move u -> v (one depth-first search with low points) against a
    breadth-first search of v's part without u, on mazes with random cells taken away."""
    m = parse_map(mazes.random_maze(4, 5, seed, loops))
    nbrs = m.neighbors.tolist()
    removed = (np.random.default_rng(seed).random(m.n_cells) < cut).tolist()
    room = battery._rooms_ahead(nbrs, removed)
    for u in range(m.n_cells):
        for v in nbrs[u]:
            if v < 0 or removed[u] or removed[v]:
                continue
            assert room(u, v) == _reached(nbrs, v, u, removed), (u, v)
