"""The world (qpatrol.world, traffic, battery) against hand-computed values on tiny maps.

Ported from the old ``tests/test_env.py`` (written for the deleted ``qpatrol/env.py``,
whose one ``env.step`` chose, moved and learned). One team step is now
``qpatrol.engines.numpy_loop.advance``: ``world.begin_step`` -> ``strategy.act`` ->
``world.step`` -> ``strategy.learn``. Where the model is unchanged (the Q-learning rule,
the rewards, episodes) the hand-computed values of the old tests are kept; where it changed on
purpose (simultaneous moves resolved by :mod:`qpatrol.world.traffic`; the battery rules of
:mod:`qpatrol.world.battery`) the test says so in its docstring and checks the new rule.

Tests that drive the world alone give every robot's move explicitly (``go``), so the
world's rules are checked independently of any strategy.
"""

from __future__ import annotations

import signal
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import pytest
from conftest import RING, ROOMS

from qpatrol import strategies, world
from qpatrol.config import Config, ConfigError, from_flat
from qpatrol.engines import numpy_loop
from qpatrol.maps import EAST, NORTH, SOUTH, WEST, Map, parse_map
from qpatrol.measures.records import Recorder
from qpatrol.run import simulate
from qpatrol.strategies.base import Strategy
from qpatrol.world.battery import CHARGING, HOMING, PATROL, QUEUED
from qpatrol.world.rng import Streams, run_seeds

NONE = -1  # no move asked


@dataclass
class World:
    cfg: Config
    m: Map
    p: world.Params
    s: world.State
    strat: Strategy


def build(text: str, starts=None, runs: int = 1, **flat) -> World:
    """A world on map ``text`` with hand-picked defaults (multiplier 1, no battery).

    ``starts``: the robots' cells (one run), or None to place them as ``simulate`` does
    with ``default_rng(r)`` for run r.
    """
    base = {"agents": 1 if starts is None else len(starts), "battery.enabled": False}
    base["learning.multiplier"] = 1
    cfg = from_flat({**base, **flat})
    m = parse_map(text)
    p = world.make_params(cfg, m)
    if starts is None:
        cells = np.stack([world.place_agents(p, m, np.random.default_rng(r)) for r in range(runs)])
    else:
        cells = np.array([starts] * runs, dtype=np.int64)
    s = world.init_state(p, cells)
    return World(cfg, m, p, s, strategies.make(cfg["policy"], cfg, m, p, cells))


def u_for(pick: float, runs: int = 1, agents: int = 1, explore: float = 0.99) -> np.ndarray:
    """Uniforms [R, K, 2] with a chosen tie-break value."""
    u = np.empty((runs, agents, 2))
    u[..., 0] = explore
    u[..., 1] = pick
    return u


def go(w: World, choice) -> world.Outcome:
    """One team step of run 0 with the moves given explicitly (no strategy)."""
    obs = world.begin_step(w.s, w.p)
    return world.step(w.s, w.p, obs, np.array([choice], dtype=np.int64))


def put(s: world.State, k: int, cell: int, r: int = 0) -> None:
    """Move robot k of run r to ``cell`` by hand, keeping ``occ`` consistent."""
    s.occ[r, s.pos[r, k]] = -1
    s.pos[r, k] = cell
    s.occ[r, cell] = k


@contextmanager
def deadline(seconds: float):
    """Raise TimeoutError if the block runs longer than ``seconds`` (a hang is a failure)."""

    def boom(signum, frame):
        raise TimeoutError(f"still running after {seconds} s")

    old = signal.signal(signal.SIGALRM, boom)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


# --- the learner on the world: update rule and rewards (model unchanged) ----------------


def test_update_rule_by_hand_on_the_ring():
    # ring: 0 1 2 / 3 # 4 / 5 6 7 ; agent at 0 heading North; gamma 0.1, q_init N3 E2 S1 W2,
    # dot 1, incremental 1 saturating at 100 steps, lambda weight 1.
    w = build(RING, [0])
    q = w.strat.q
    q0 = q.copy()
    # step 1: legal E (2) and S (1) -> East to cell 1. r = dot 1 + 1*1/100 + lambda 1/1
    # target = 2.01 + 0.1 * max(Q(1,E,E)=2, Q(1,E,W)=2) = 2.21, alpha = 1
    out = numpy_loop.advance(w.s, w.p, w.strat, u_for(0.0))
    assert w.s.pos[0, 0] == 1 and w.s.head[0, 0] == EAST
    assert out.reward[0, 0] == pytest.approx(2.01, abs=1e-12)
    assert q[0, 0, 0, 0, EAST] == pytest.approx(2.21, abs=1e-12)
    assert w.strat.n[0, 0, 0, 0, EAST] == 1
    # step 2: at (1, E) East and West tie at 2; u=0.75 takes the second candidate, West.
    # back on cell 0 (its dot is eaten now): r = 1 + 2/100 + 2/2 = 2.02
    # target = 2.02 + 0.1 * max(Q(0,W,E)=2, Q(0,W,S)=1) = 2.22
    numpy_loop.advance(w.s, w.p, w.strat, u_for(0.75))
    assert w.s.pos[0, 0] == 0 and w.s.head[0, 0] == WEST
    assert q[0, 0, 1, EAST, WEST] == pytest.approx(2.22, abs=1e-12)
    # step 3: at (0, W): East 2 > South 1 -> cell 1, no dot left: r = (3-1)/100 + 2/3
    # target = r + 0.1 * max(Q(1,E,W)=2.22, Q(1,E,E)=2)
    numpy_loop.advance(w.s, w.p, w.strat, u_for(0.0))
    r3 = 0.02 + 2 / 3
    assert q[0, 0, 0, WEST, EAST] == pytest.approx(r3 + 0.222, abs=1e-12)
    # step 4: at (1, E): West 2.22 > East 2 -> cell 0; r = (4-2)/100 + 2/4 = 0.52
    # target = 0.52 + 0.1 * max(Q(0,W,E)=r3+0.222, Q(0,W,S)=1) = 0.62; second visit: alpha 1/2
    numpy_loop.advance(w.s, w.p, w.strat, u_for(0.0))
    assert w.strat.n[0, 0, 1, EAST, WEST] == 2
    assert q[0, 0, 1, EAST, WEST] == pytest.approx(2.22 + 0.5 * (0.62 - 2.22), abs=1e-12)
    # nothing else moved in the table
    changed = np.argwhere(q != q0)
    assert {tuple(x[2:]) for x in changed} == {(0, 0, EAST), (1, EAST, WEST), (0, WEST, EAST)}


def test_reward_parts():
    line = "0o-.\n"  # start, big dot, empty, dot
    for flat, expected in [
        ({}, 5.0 + 0.01 + 1.0),
        ({"reward.lambda": 0.0}, 5.0 + 0.01),
        ({"reward.lambda": 0.0, "reward.incremental_value": 0.0}, 5.0),
        ({"reward.lambda": 0.0, "reward.idle_horizon": 0.5}, 5.0 + 1.0),
        (
            {"reward.lambda": 2.0, "reward.big_dot_value": 3.0, "reward.incremental_value": 4.0},
            3.0 + 0.04 + 2.0,
        ),
    ]:
        w = build(line, [0], **flat)
        q_next = w.strat.q[0, 0, 1, EAST].copy()
        out = numpy_loop.advance(w.s, w.p, w.strat, u_for(0.0))
        assert out.reward[0, 0] == pytest.approx(expected, abs=1e-12), flat
        boot = w.strat.gamma * max(q_next[EAST], q_next[WEST])
        assert w.strat.q[0, 0, 0, 0, EAST] == pytest.approx(expected + boot, abs=1e-12), flat
    # the empty cell: no dot, incremental only, lambda = 1 dot / 2 visits
    w = build(line, [0], **{"learning.q_init.west": 0.0})
    numpy_loop.advance(w.s, w.p, w.strat, u_for(0.0))
    out = numpy_loop.advance(
        w.s, w.p, w.strat, u_for(0.0)
    )  # East is the only best move from (1, E)
    assert w.s.pos[0, 0] == 2 and not out.eaten[0, 0]
    assert out.reward[0, 0] == pytest.approx(0.02 + 0.5, abs=1e-12)
    boot = w.strat.gamma * 2.0
    assert w.strat.q[0, 0, 1, EAST, EAST] == pytest.approx(0.02 + 0.5 + boot, abs=1e-12)


def test_episode_ends_when_all_dots_are_eaten_and_restarts():
    w = build("0..\n", [0])
    rec = Recorder(np.array([0]))
    for pick in (0.0, 0.0, 0.0, 0.99):  # E, E (tie, first), W (only move), W (tie, second)
        numpy_loop.advance(w.s, w.p, w.strat, u_for(pick), rec)
    s = w.s
    assert s.pos[0, 0] == 0
    ep = rec.episode_table()
    assert ep[
        ["episode", "start_step", "steps", "dots_eaten", "distinct_cells", "complete"]
    ].values.tolist() == [[0, 1, 4, 3, 3, 1]]
    # all dots back, counters reset, Q kept, agents where they were
    assert s.dots.all() and s.dots_left[0, 0] == 3 and s.ep_count[0, 0] == 1
    assert s.ep_start[0, 0] == 4 and s.ep_visits[0, 0] == 0
    assert w.strat.n.sum() == 4


def test_truncated_episodes():
    cfg = from_flat(
        {
            "map": "map_b",
            "agents": 1,
            "battery.enabled": False,
            "steps": 60,
            "max_episode_steps": 20,
        }
    )
    r = simulate(cfg)
    assert r.episodes["complete"].tolist() == [0, 0, 0]
    assert r.episodes["steps"].tolist() == [20, 20, 20]
    assert r.summary[0]["episodes_truncated"] == 3


def test_communication_off_gives_private_dot_maps():
    two = "0...1\n"
    w = build(two, **{"agents": 2, "team.communication": False})
    assert w.s.dots.shape == (1, 2, 5)
    numpy_loop.advance(w.s, w.p, w.strat, u_for(0.0, agents=2))
    # agent 0 ate cell 1 on its own map only; agent 1 ate cell 3 on its own map only
    assert w.s.dots[0, 0].tolist() == [True, False, True, True, True]
    assert w.s.dots[0, 1].tolist() == [True, True, True, False, True]
    w = build(two, agents=2)
    numpy_loop.advance(w.s, w.p, w.strat, u_for(0.0, agents=2))
    assert w.s.dots.shape == (1, 1, 5)
    assert w.s.dots[0, 0].tolist() == [True, False, True, False, True]


def test_state_space_cell_uses_heading_slot_zero(rooms_map):
    cfg = from_flat(
        {
            "map": str(rooms_map),
            "agents": 2,
            "steps": 300,
            "learning.state_space": "cell",
            "battery.enabled": False,
        }
    )
    r = simulate(cfg)
    assert r.strategy.n[..., 1:, :].sum() == 0 and r.strategy.n.sum() > 0


# --- runs, episodes, records -------------------------------------------------------------


def test_runs_do_not_depend_on_their_batch(rooms_map):
    cfg = from_flat(
        {
            "map": str(rooms_map),
            "agents": 3,
            "runs": 3,
            "steps": 400,
            "learning.epsilon": 0.1,
            "battery.capacity": 40,
        }
    )
    whole = simulate(cfg)
    alone = simulate(cfg, runs=range(1, 2))
    assert np.array_equal(whole.strategy.q[1], alone.strategy.q[0])
    assert np.array_equal(whole.measures.visits[1], alone.measures.visits[0])
    assert np.array_equal(whole.state.pos[1], alone.state.pos[0])
    assert np.array_equal(whole.state.charge[1], alone.state.charge[0])
    assert whole.summary[1] == alone.summary[0]
    e = whole.episodes[whole.episodes.run == 1].reset_index(drop=True)
    assert e.equals(alone.episodes)
    other_seed = simulate(cfg.replace(seed=1), runs=range(1, 2))
    assert not np.array_equal(other_seed.strategy.q[0], alone.strategy.q[0])


def test_episode_quota_stops_each_run(rooms_map):
    cfg = from_flat(
        {
            "map": str(rooms_map),
            "agents": 1,
            "runs": 3,
            "steps": 100000,
            "episodes": 2,
            "battery.enabled": False,
        }
    )
    r = simulate(cfg)
    assert r.episodes.groupby("run").size().tolist() == [2, 2, 2]
    ends = r.episodes.groupby("run").apply(lambda e: (e.start_step + e.steps - 1).max())
    assert [x["steps"] for x in r.summary] == ends.tolist()


def test_trajectory_tail_ends_at_the_final_positions(rooms_map):
    cfg = from_flat(
        {
            "map": str(rooms_map),
            "agents": 2,
            "runs": 3,
            "steps": 5000,
            "episodes": 2,
            "record.trajectory": 7,
            "battery.enabled": False,
        }
    )
    r = simulate(cfg)
    tr = r.trajectory
    for i, summary in enumerate(r.summary):
        mine = tr[tr.run == i]
        assert mine.step.min() == summary["steps"] - 6 and mine.step.max() == summary["steps"]
        last = mine[mine.step == summary["steps"]].sort_values("agent")
        assert last.cell.tolist() == r.state.pos[i].tolist()
        # consecutive cells of an agent are equal or neighbours
        for _, a in mine.groupby("agent"):
            c = a.cell.to_numpy()
            assert all(y == x or y in r.map.neighbors[x] for x, y in zip(c, c[1:], strict=False))


# --- placing the team -----------------------------------------------------------------


def test_extra_agents_are_spread_on_distinct_free_cells():
    """Changed on purpose: with ``team.avoid_collisions`` a team may fill at most half the
    free cells (robots need room to yield); without it, every free cell."""
    cfg = from_flat({"agents": 9, "battery.enabled": False})
    m = parse_map(ROOMS)  # 28 free cells, start digits on cells 0, 5, 22, 27
    p = world.make_params(cfg, m)
    cells = world.place_agents(p, m, np.random.default_rng(0))
    assert cells[:4].tolist() == m.starts.tolist() == [0, 5, 22, 27]
    assert len(set(cells.tolist())) == 9
    world.make_params(cfg.replace(agents=14), m)  # 2 x 14 = 28 cells: fits
    with pytest.raises(ConfigError, match=r"agents: 15 robots .* leave no room to yield"):
        world.make_params(cfg.replace(agents=15), m)
    loose = cfg.replace(**{"agents": 28, "team.avoid_collisions": False})
    world.make_params(loose, m)
    with pytest.raises(ConfigError, match="agents: 29 agents do not fit"):
        world.make_params(loose.replace(agents=29), m)


# --- moves: simultaneous choice, resolved by traffic ------------------------------------

CORRIDOR = "........\n"  # cells 0..7 in a row


def test_robots_choose_together_and_may_follow_a_robot_that_leaves():
    """Changed on purpose: robots no longer act one after the other, each seeing the cells
    the earlier ones claimed; all choose at once and traffic resolves the moves. A robot
    may enter the cell of a robot that leaves it in the same step (the old rule masked
    any cell occupied at the start of the step)."""
    w = build(CORRIDOR, [1, 2])
    out = go(w, [EAST, EAST])  # robot 0 follows robot 1, whatever their priority order
    assert w.s.pos[0].tolist() == [2, 3]
    assert out.as_asked[0].tolist() == [True, True]
    assert w.s.wait[0].tolist() == [0, 0]
    assert w.s.occ[0].tolist() == [-1, -1, 0, 1, -1, -1, -1, -1]


def test_head_on_robots_never_swap_and_the_token_holder_pushes_through():
    """New rule (traffic): two robots asking for each other's cell both stay (no swap),
    wait one step and the robot of higher priority gets the right of way; in the next
    step it pushes the other one cell back along the corridor."""
    w = build(CORRIDOR, [2, 3])
    out = go(w, [EAST, WEST])
    assert w.s.pos[0].tolist() == [2, 3]
    assert out.moved[0].tolist() == [False, False]
    assert out.blocked_by[0].tolist() == [1, 0]
    assert w.s.wait[0].tolist() == [1, 1]
    # priority for step 2: equal class and wait, turn (K-1) - (k - t) % K = 1 - k % 2
    # at t = 2, so robot 0 goes first and gets the token
    assert w.s.token[0] == 0
    out = go(w, [EAST, WEST])
    assert w.s.pos[0].tolist() == [3, 4]  # robot 1 pushed from 3 to 4, robot 0 took 3
    assert out.moved[0].tolist() == [True, True]
    assert out.as_asked[0].tolist() == [True, False]
    assert w.s.wait[0].tolist() == [0, 2]
    # both entered a target (no aim: their task ends there), robot 1 pushed; robot 1,
    # the only blocked robot, takes the right of way
    assert out.progressed[0].tolist() == [True, True]
    assert w.s.token[0] == 1 and w.s.token_held[0] == 0


def test_two_robots_asking_for_one_cell_the_turn_decides():
    """New rule (traffic): among robots of equal class and wait, the turn ``(K-1) - (k -
    t) % K`` decides; it rotates with the step, so neither robot always loses."""
    w = build(CORRIDOR, [1, 3])
    out = go(w, [EAST, WEST])  # t = 1: turns 1 - (0-1)%2 = 0 and 1 - (1-1)%2 = 1
    assert w.s.pos[0].tolist() == [1, 2]
    assert out.as_asked[0].tolist() == [False, True]
    assert out.blocked_by[0].tolist() == [1, -1]
    w = build(CORRIDOR, [1, 3])
    w.s.t = 1
    go(w, [EAST, WEST])  # t = 2: turns 1 and 0
    assert w.s.pos[0].tolist() == [2, 3]


def _walk(cfg: Config, m: Map, steps: int):
    p = world.make_params(cfg, m)
    streams = Streams(run_seeds(cfg["seed"], cfg["runs"]), p.n_agents)
    starts = np.stack([world.place_agents(p, m, g) for g in streams.generators])
    s = world.init_state(p, starts)
    strat = strategies.make(cfg["policy"], cfg, m, p, starts)
    for _ in range(steps):
        old = s.pos.copy()
        numpy_loop.advance(s, p, strat, streams.next())
        yield p, s, old, s.pos.copy()


@pytest.mark.parametrize("avoid", [True, False])
def test_agents_never_share_a_cell_never_swap_never_enter_walls(avoid):
    cfg = from_flat(
        {
            "agents": 6,
            "runs": 16,
            "learning.epsilon": 0.3,
            "team.avoid_collisions": avoid,
            "battery.capacity": 40,
            "battery.charge_steps": 5,
            "seed": 3,
        }
    )
    m = parse_map(ROOMS)
    shared = swaps = 0
    rows = np.arange(cfg["runs"])[:, None]
    for _, s, old, new in _walk(cfg, m, 400):
        moved = new != old
        nb = m.neighbors[old]  # [R, K, 4]
        assert ((nb == new[..., None]).any(-1) | ~moved).all()  # only moves to a free neighbour
        srt = np.sort(new, axis=1)
        shared += int((srt[:, 1:] == srt[:, :-1]).sum())
        swaps += int(
            (
                (new[:, :, None] == old[:, None, :])
                & (new[:, None, :] == old[:, :, None])
                & moved[:, :, None]
            ).sum()
        )
        if avoid:  # the occupancy grid is the positions, seen from the cells
            assert (s.occ[rows, new] == np.arange(cfg["agents"])[None, :]).all()
            assert ((s.occ >= 0).sum(axis=1) == cfg["agents"]).all()
    if avoid:
        assert shared == 0 and swaps == 0
    else:  # the check would catch it: without avoidance agents do meet
        assert shared > 0


# --- batteries --------------------------------------------------------------------------


def test_battery_teams_need_room_to_reach_a_station():
    """Rule (docs/model.md, "What is proven"): with batteries a team of K >= 2 is refused
    on a one-wide line without a station K - 1 cells or more from both ends (robots keep
    their order on a line), and beyond half the free cells that are neither a station nor
    in a station's pocket."""
    on = {"battery.enabled": True, "battery.capacity": 30}

    def make(text: str, k: int, **flat):
        return world.make_params(from_flat({**on, "agents": k, **flat}), parse_map(text))

    line = r"agents: .* a one-wide line without a station"
    with pytest.raises(ConfigError, match=line + r" 1 cell or more .* allowed: at most 1 "):
        make("H....\n", 2)  # the station at an end
    with pytest.raises(ConfigError, match=line):
        make("H...H\n", 2)  # both stations at an end
    with pytest.raises(ConfigError, match=line + r" 2 cells or more .* allowed: at most 2 "):
        make(".H.....\n", 3)  # 1 cell on one side, 2 needed
    make("H....\n", 1)  # one robot
    make(".H...\n", 2)  # a station in the middle: 1 cell on each side
    make("..H....\n", 3)  # 2 cells on each side
    make("H....\n#.###\n", 2)  # a spur under cell 1: not a line
    make("H....\n", 2, **{"battery.enabled": False})  # no battery
    make("H....\n", 2, **{"team.avoid_collisions": False})  # robots may share cells
    # the T #H#/#.#/.../##.: 6 cells, the station and its pocket cell 1 closed: 4 left
    t = "#H#\n#.#\n...\n##.\n"
    with pytest.raises(ConfigError, match=r"agents: 3 robots .* 2 of them stations .* most 2 "):
        make(t, 3)
    make(t, 2)
    make(t, 3, **{"battery.enabled": False})  # 2 x 3 <= 6
    # a station on the junction of the T ..H./.##. is in no pocket: 6 - 1 = 5 cells left
    with pytest.raises(ConfigError, match=r"1 of them stations or in their pockets"):
        make("..H.\n.##.\n", 3)
    make("..H.\n.##.\n", 2)


LINE_H = "H.....0\n"  # H is cell 0, the agent starts on cell 6 (6 moves from H)


def test_battery_config_checked_against_map():
    """The capacity must exceed the farthest distance + margin + 1 (the ``+ 1`` of the
    switching rule) + the moves of leaving a station, 2 x depart_len (its charge is not
    checked while it leaves): 6 moves from H, margin 0, and depart_len 1 (no junction)
    need 6 + 0 + 1 + 2 = 9, so 10."""
    m = parse_map(LINE_H)
    on = {"agents": 1, "battery.enabled": True, "battery.margin": 0}
    with pytest.raises(ConfigError, match="battery.capacity: 9 is too small"):
        world.make_params(from_flat({**on, "battery.capacity": 9}), m)
    world.make_params(from_flat({**on, "battery.capacity": 10}), m)
    # H... over ##.#: the farthest cells 3 moves from H, the junction 2 (depart_len 2):
    # 3 + 0 + 1 + 2 x 2 = 8, so 9
    t = parse_map("H...\n##.#\n")
    with pytest.raises(ConfigError, match="battery.capacity: 8 is too small"):
        world.make_params(from_flat({**on, "battery.capacity": 8}), t)
    world.make_params(from_flat({**on, "battery.capacity": 9}), t)
    with pytest.raises(ConfigError, match="no charging station"):
        world.make_params(from_flat({**on, "battery.capacity": 10}), parse_map("......0\n"))


@pytest.mark.parametrize("capacity", [10, 11])
def test_battery_trip_home_and_back(capacity):
    """Changed on purpose: a robot switches to a station when ``charge <= distance +
    margin + 1`` (was ``<= distance + margin``), so right after the switch and its first
    move home ``charge - distance`` is ``margin`` or ``margin + 1`` (here 0 or 1, as the
    parity of the capacity decides); it then goes straight home without Q-updates and
    never runs out. How long it rests on the station (the old test counted 3 resting
    steps per trip) is checked exactly by the next test."""
    flat = {
        "battery.enabled": True,
        "battery.capacity": capacity,
        "battery.margin": 0,
        "battery.charge_steps": 3,
        "battery.initial_charge": "full",
    }
    w = build(LINE_H, [6], **flat)
    s = w.s
    streams = Streams(run_seeds(7, 1), 1)
    trips = 0
    for _ in range(300):
        before = (int(s.pos[0, 0]), int(s.mode[0, 0]), int(s.charge[0, 0]), int(w.strat.n.sum()))
        numpy_loop.advance(s, w.p, w.strat, streams.next())
        pos, mode, charge = int(s.pos[0, 0]), int(s.mode[0, 0]), int(s.charge[0, 0])
        assert 0 <= charge <= capacity
        assert mode != QUEUED  # alone, it always gets the station at once
        if before[1] == PATROL and mode == HOMING:
            # switched: before the move charge <= distance + 1, and charge >= distance
            assert charge - pos in (0, 1)
            assert charge - pos == (capacity - 6) % 2  # parity of charge - distance is kept
        if mode == HOMING or (before[1] == HOMING and mode != PATROL):
            assert pos == before[0] - 1  # straight home along the shortest path
            assert charge == before[2] - 1  # one unit per move
            assert w.strat.n.sum() == before[3]  # homing moves do not update Q
        if before[1] == HOMING and pos == 0:
            trips += 1
            assert mode == CHARGING and charge >= 0
        if before[1] == CHARGING:
            if mode == CHARGING:  # resting: on the station, no move, no Q-update
                assert pos == 0 and charge == before[2] and w.strat.n.sum() == before[3]
            else:  # done: full again (minus the move it may make in the same step)
                assert mode == PATROL and charge + (pos != 0) == capacity
    assert trips >= 5


@pytest.mark.parametrize("charge_steps", [1, 3])
def test_charging_keeps_the_robot_on_its_station_for_charge_steps_steps(charge_steps):
    """The old test's check, kept: after arriving, the robot stays on the station (and is
    not asked to move) for ``charge_steps`` team steps, then leaves with a full charge."""
    w = build(
        LINE_H,
        [1],
        **{
            "battery.enabled": True,
            "battery.capacity": 10,
            "battery.margin": 0,
            "battery.charge_steps": charge_steps,
            "battery.initial_charge": "full",
        },
    )
    w.s.charge[0, 0] = 2  # 1 move from H: 2 <= 1 + 0 + 1, so it goes home at once
    out = go(w, [EAST])
    assert w.s.pos[0, 0] == 0 and w.s.mode[0, 0] == CHARGING  # arrived at step 1
    still = 0
    while True:
        out = go(w, [EAST])  # asks East whenever it is asked at all
        if out.moved[0, 0]:
            break
        assert not out.choosing[0, 0]
        still += 1
    assert still == charge_steps
    assert w.s.charge[0, 0] == 10 - 1


def test_initial_charge_full_and_staggered():
    """New: ``battery.initial_charge``. ``full``: capacity for all; ``staggered``: robot k
    of K starts with ``capacity - floor(k capacity / K)``, but never below ``distance to
    the nearest station + margin + 1`` from its start cell."""
    # H = cell 0, cell c of the row is c moves from H; a spur (cells 11-13) under cell 1
    # (a battery team on a line with a station at an end is refused, and four robots
    # need four cells past the door at cell 1: cell 1 and the spur)
    line = "H..........\n#.#########\n#.#########\n#.#########\n"
    starts = [2, 4, 10, 9]
    flat = {"agents": 4, "battery.enabled": True, "battery.capacity": 22, "battery.margin": 1}
    w = build(line, starts, **flat, **{"battery.initial_charge": "full"})
    assert w.s.charge[0].tolist() == [22, 22, 22, 22]
    w = build(line, starts, **flat, **{"battery.initial_charge": "staggered"})
    # 22 - floor(k 22 / 4) = 22, 17, 11, 6; floors 2+2, 4+2, 10+2, 9+2 = 4, 6, 12, 11
    assert w.s.charge[0].tolist() == [22, 17, 12, 11]
    # battery off: the charge is irrelevant, and full
    w = build(line, starts, agents=4, **{"battery.capacity": 22})
    assert w.s.charge[0].tolist() == [22, 22, 22, 22]


def test_margin_zero_no_longer_lets_the_charge_reach_minus_one():
    """The old bug: with ``charge <= distance + margin`` and margin 0, a robot 3 moves from
    H with charge 4 kept patrolling (4 > 3), stepped away to 4 moves with charge 3, then
    switched and needed 4 moves: the charge reached -1. New rule: 4 <= 3 + 0 + 1, so it
    turns home at once and arrives with 1."""
    w = build(
        LINE_H,
        [3],
        **{
            "battery.enabled": True,
            "battery.capacity": 10,
            "battery.margin": 0,
            "battery.initial_charge": "full",
        },
    )
    w.s.charge[0, 0] = 4
    seen = []
    for _ in range(3):
        out = go(w, [EAST])  # East (away from H) whenever its strategy is asked
        assert not out.choosing[0, 0]  # it never is: it needs a station from step 1 on
        seen.append((int(w.s.pos[0, 0]), int(w.s.charge[0, 0]), int(w.s.mode[0, 0])))
    assert seen == [(2, 3, HOMING), (1, 2, HOMING), (0, 1, CHARGING)]


@pytest.mark.parametrize("capacity", [21, 22])
@pytest.mark.parametrize("policy", ["random", "qlearning"])
def test_margin_zero_charge_never_negative_over_a_long_run(capacity, policy):
    """Margin 0, odd and even capacity: the charge of no robot ever goes below 0."""
    cfg = from_flat(
        {
            "agents": 4,
            "runs": 16,
            "policy": policy,
            "learning.epsilon": 0.2,
            "battery.capacity": capacity,
            "battery.margin": 0,
            "battery.charge_steps": 2,
            "seed": 5,
        }
    )
    m = parse_map(ROOMS)  # the farthest cell is 5 moves from H
    trips = 0
    lowest = cfg["battery.capacity"]
    for p, s, old, new in _walk(cfg, m, 500):
        assert s.charge.min() >= 0
        lowest = min(lowest, int(s.charge.min()))
        arrived = (s.mode == CHARGING) & (new != old)
        trips += int(arrived.sum())
        # a robot needing a station always has the charge to reach it
        need = (s.mode == HOMING) | (s.mode == QUEUED)
        dist = np.where(
            s.mode == HOMING, p.home_dist[np.maximum(s.goal, 0), s.pos], p.nearest_home_dist[s.pos]
        )
        assert (s.charge[need] >= dist[need]).all()
    assert trips > 500  # the battery really was exercised (about 1100 trips)
    assert lowest == 0  # robots did arrive with an empty battery: the edge was reached


def test_a_station_is_held_by_one_robot_first_come_first_served():
    """New rule (battery): stations are held, one robot at a time, in the order in which
    robots began to need one. Robot 1 needs a station first (step 1) although robot 0 is
    nearer when it needs one (step 2): robot 1 holds it; robot 0 waits where it is
    (QUEUED, no move, no charge spent) until robot 1 has charged and left, holding the
    station for 2 x depart_len = 2 more steps, then goes home. (``charge_steps`` 0, so
    the timing does not depend on how charging steps are counted.)"""
    line = "......H......\n"  # H = cell 6, no junction: depart_len 1
    w = build(
        line,
        [3, 11],
        **{
            "battery.enabled": True,
            "battery.capacity": 20,
            "battery.margin": 0,
            "battery.charge_steps": 0,
            "battery.initial_charge": "full",
        },
    )
    s = w.s
    s.charge[0] = [5, 6]
    # step 1: robot 1 (5 from H, charge 6 <= 5+0+1) needs a station, takes it, moves to 10;
    #   robot 0 (3 from H, charge 5 > 3+0+1) patrols West to cell 2 (charge 4)
    # step 2: robot 0 (4 from H, charge 4 <= 4+0+1) needs one: held by robot 1, it waits
    # steps 2-5: robot 1 goes 9, 8, 7, 6: on H with charge 1, full at once (20), holding
    #   H while it leaves: steps 6 and 7 East (depart_left 2 -> 0), released after step 7
    # step 8: robot 0 takes H and goes 3, 4, 5, 6 (steps 8-11), arriving with charge 0
    expect_pos0 = [2] * 7 + [3, 4, 5, 6]
    expect_mode0 = [PATROL] + [QUEUED] * 6 + [HOMING] * 3 + [PATROL]
    expect_holder = [1] * 6 + [-1] + [0] * 4
    got_pos0, got_mode0, got_holder, got_wait0 = [], [], [], []
    for _ in range(11):
        out = go(w, [WEST, EAST])
        got_pos0.append(int(s.pos[0, 0]))
        got_mode0.append(int(s.mode[0, 0]))
        got_holder.append(int(s.reserved[0, 0]))
        got_wait0.append(int(s.wait[0, 0]))
        if s.mode[0, 0] == QUEUED:
            assert out.waiting_for_station[0, 0] and not out.moved[0, 0]
            assert s.charge[0, 0] == 4
    assert got_pos0 == expect_pos0
    assert got_mode0 == expect_mode0
    assert got_holder == expect_holder
    assert got_wait0 == [0, 1, 2, 3, 4, 5, 6, 0, 0, 0, 0]
    assert s.pos[0].tolist() == [6, 12]
    assert s.charge[0].tolist() == [20, 20 - 6]  # robot 1 left at step 6: 6 moves East


def test_stations_are_never_shared_over_a_long_run():
    """Invariants of the station rules over many random steps: a station is held by at
    most one robot, every robot homing or charging holds exactly the station it heads for
    or stands on, and a charging robot stands on its station."""
    cfg = from_flat(
        {
            "agents": 6,
            "runs": 16,
            "policy": "random",
            "battery.capacity": 30,
            "battery.charge_steps": 4,
            "seed": 11,
        }
    )
    m = parse_map(ROOMS)
    charged = 0
    K = cfg["agents"]
    rows = np.arange(cfg["runs"])[:, None]
    for p, s, _, _ in _walk(cfg, m, 400):
        held = s.reserved  # [R, H]
        holder = np.maximum(held, 0)
        assert ((held < 0) | (s.goal[rows, holder] == np.arange(p.homes.size))).all()
        busy = (s.mode == HOMING) | (s.mode == CHARGING)
        goal = np.maximum(s.goal, 0)
        assert (s.goal[busy] >= 0).all()
        assert (held[rows, goal] == np.arange(K))[busy].all()
        charging = s.mode == CHARGING
        assert (s.pos == p.homes[goal])[charging].all()
        assert (s.goal[s.mode == QUEUED] == -1).all()
        assert (charging.sum(axis=1) <= p.homes.size).all()
        charged += int(charging.sum())
    assert charged > 100


def test_pushes_are_free_yields():
    """New rule (battery + traffic): a robot pushed aside by the token holder pays no
    charge; one on its way to a station is credited the distance the push added; the
    holder pays for its own move as usual."""
    # H = cell 0, cell c of the row is c moves from H; a spur (cell 9) under cell 1 (a
    # battery team on a line with a station at an end is refused)
    line = "H........\n#.#######\n"
    on = {
        "battery.enabled": True,
        "battery.capacity": 20,
        "battery.margin": 0,
        "battery.initial_charge": "full",
    }
    # a patrolling robot in the way
    w = build(line, [2, 3], **on)
    w.s.token[0] = 0
    out = go(w, [EAST, NONE])
    assert w.s.pos[0].tolist() == [3, 4]
    assert out.as_asked[0].tolist() == [True, False] and out.moved[0].tolist() == [True, True]
    assert w.s.charge[0].tolist() == [19, 20]
    # a homing robot in the way, pushed from 3 to 4 moves from H: credited 1
    w = build(line, [2, 3], **on)
    s = w.s
    s.token[0] = 0
    s.mode[0, 1], s.goal[0, 1], s.reserved[0, 0] = HOMING, 0, 1
    s.charge[0] = [20, 12]
    out = go(w, [EAST, NONE])
    assert out.ask[0].tolist() == [EAST, WEST]  # robot 1 asked to go home
    assert s.pos[0].tolist() == [3, 4]
    assert s.charge[0].tolist() == [19, 13]


def test_the_token_holder_is_offered_only_moves_a_push_can_make_room_for():
    """Rule (battery on): the holder of the right of way sees as open the moves into an
    empty cell or into one a push empties, not a move into a full dead end, so a holder
    that chooses among open moves always makes the move it chose."""
    # cells 0-6, the station H on the junction 3 (in no pocket), dead end 7 (under 3), 8
    text = "...H...\n###.###\n###.###\n"
    on = {"battery.enabled": True, "battery.capacity": 50, "policy": "random"}
    w = build(text, [3, 7, 8, 4], **on)
    w.s.token[0] = 0
    obs = world.begin_step(w.s, w.p)
    # N: wall; E: robot 3 pushed to 5; S: the dead end is full; W: empty
    assert obs.open[0, 0].tolist() == [False, True, False, True]
    assert obs.open[0, 3].tolist() == [False, True, False, False]  # not the holder
    out = world.step(w.s, w.p, obs, np.array([[EAST, -1, -1, -1]]))
    assert out.as_asked[0, 0] and w.s.pos[0].tolist() == [4, 7, 8, 5]
    # a move it was not offered (into the full dead end: an insisting robot's) cannot be
    # made: the holder's task goes on through the robot in its way, robot 1 on 7 (both
    # patrol: they exchange tasks, and robot 1 takes the right of way)
    w = build(text, [3, 7, 8, 4], **on)
    w.s.token[0] = 0
    w.s.since[0] = [-4, 0, 0, 0]
    obs = world.begin_step(w.s, w.p)
    out = world.step(w.s, w.p, obs, np.array([[SOUTH, -1, -1, -1]]))
    assert not out.moved[0, 0] and w.s.pos[0].tolist() == [3, 7, 8, 4]
    assert out.swapped[0].tolist() == [1, 0, -1, -1]
    assert w.s.since[0].tolist() == [0, -4, 0, 0] and w.s.token[0] == 1


# --- homing around a busy station ---------------------------------------------------------

RING_WITH_TWO_STATIONS = "H1.0..\n.####.\n...H..\n"
# the same ring with a one-cell spur under cell 8 (cell 14): cell 8 is a junction
RING_WITH_TWO_STATIONS_AND_SPUR = "H1.0..\n.####.\n...H..\n.#####\n"


@pytest.mark.parametrize(
    "text, charge, margin, holder, path",
    [
        # station 0 is busy (robot 1 charging there): go round to station 11 (old test)
        (RING_WITH_TWO_STATIONS, 9, 6, "charging", [4, 5, 7, 13, 12, 11]),
        (RING_WITH_TWO_STATIONS_AND_SPUR, 9, 6, "charging", [4, 5, 7, 13, 12, 11]),
        # station 11 is out of reach: robot 0 waits on 3 (QUEUED) while robot 1, charged,
        # leaves station 0 going South, holding it for 2 x depart_len steps or until it
        # stops asking. Ring: depart_len 1, released after step 2, home 2, 1, 0 in steps
        # 3-5. With the spur: depart_len 2 (0 -> 6 -> 8), robot 1 goes 6, 8, 14 and at
        # step 4 asks for no move (South of 14 is a wall): released; home in steps 5-7.
        pytest.param(RING_WITH_TWO_STATIONS, 5, 2, "leaving", [3, 3, 2, 1, 0]),
        (RING_WITH_TWO_STATIONS_AND_SPUR, 5, 2, "leaving", [3, 3, 3, 3, 2, 1, 0]),
    ],
)
def test_homing_bypasses_an_occupied_station_it_can_avoid(text, charge, margin, holder, path):
    """Changed on purpose: a robot needing a station takes the nearest *free* one its
    charge can reach; if there is none it waits where it is (it used to walk towards the
    nearest station and wait in front of it), until the station is released."""
    # ring of 14 cells: top row 0-5 (H at 0, agent 1 starts at 1, agent 0 at 3), cells 6
    # and 7 down the sides, bottom row 8-13 with a second H at 11 (+ cell 14 under 8)
    flat = {
        "battery.enabled": True,
        "battery.capacity": 20,
        "battery.margin": margin,
        "battery.charge_steps": 2,
        "battery.initial_charge": "full",
    }
    with deadline(0.5):
        w = build(text, [3, 1], **flat)
    s, p = w.s, w.p
    assert p.homes.tolist() == [0, 11]
    put(s, 1, 0)  # agent 1 on station 0, holding it
    s.goal[0, 1], s.reserved[0, 0] = 0, 1
    if holder == "charging":
        s.mode[0, 1], s.rest[0, 1] = CHARGING, 2
    else:  # just charged: patrolling again, still holding the station while it leaves
        s.depart_left[0, 1] = 2 * p.depart_len[0]
    s.charge[0, 0] = charge
    seen = []
    for _ in path:
        go(w, [NORTH, SOUTH])  # agent 0's choice is never asked for: it needs a station
        seen.append(int(s.pos[0, 0]))
    assert seen == path
    assert s.mode[0, 0] == CHARGING
    assert s.charge[0, 0] == charge - len(set(path) - {3}) >= 0  # one unit per move


def test_a_station_on_a_plain_ring_is_accepted():
    m = parse_map("H..\n.#.\n...\n")  # 8-cell ring, station on cell 0, no junction
    with deadline(0.5):
        p = world.make_params(from_flat({"agents": 1, "battery.capacity": 20}), m)
    assert p.pocket_of.tolist() == [-1] * 8 and p.pocket_entry.tolist() == [-1]


def test_dead_end_station_pocket_is_found():
    """The pocket of a station at the end of a dead end (battery.station_pockets): the
    corridor from the junction, depths counted from it."""
    # cells: 0 1 2 3 4 in the top row, 5 under 2 (a junction at 2), H at 6 under 5
    m = parse_map("..-..\n##.##\n##H##\n")
    p = world.make_params(from_flat({"agents": 1, "battery.capacity": 20}), m)
    assert p.homes.tolist() == [6]
    assert p.pocket_entry.tolist() == [2]
    assert p.pocket_of.tolist() == [-1, -1, -1, -1, -1, 0, 0]
    assert p.pocket_depth.tolist() == [0, 0, 0, 0, 0, 1, 2]
    assert p.depart_len.tolist() == [2]


def test_outcome_active_covers_the_step_that_meets_the_episode_quota():
    w = build("0..\n", [0], episodes=1)
    for pick in (0.0, 0.0, 0.0):  # E, E, W: dots of cells 1 and 2 eaten, cell 0's left
        out = numpy_loop.advance(w.s, w.p, w.strat, u_for(pick))
        assert out.active.tolist() == [True]
    out = numpy_loop.advance(w.s, w.p, w.strat, u_for(0.99))  # W: the last dot, episode 1 ends
    assert out.moved[0, 0] and out.episodes.runs.tolist() == [0]
    assert w.s.steps_done.tolist() == [4] and w.s.active.tolist() == [False]
    assert out.active.tolist() == [True]  # "the runs that took this step"


def test_a_task_ends_when_its_aim_is_entered_not_while_its_robot_stands_on_it():
    """A task ends when its robot enters its aim (or is handed a task whose aim is its
    cell); a robot that waits on its aim (a walk follower held for its spacing) makes
    no progress, so its stall grows. Standing counted as progress would let a team
    that stands still look live (every robot on its aim, ``max_stall`` 0)."""
    w = build(CORRIDOR, [2, 5])
    obs = world.begin_step(w.s, w.p)
    aim = np.array([[3, 5]], dtype=np.int64)  # robot 0 enters 3; robot 1 waits on 5
    out = world.step(w.s, w.p, obs, np.array([[EAST, -1]]), aim)
    assert out.progressed[0].tolist() == [True, False]
    assert w.s.since[0].tolist() == [1, 0]
    obs = world.begin_step(w.s, w.p)
    out = world.step(w.s, w.p, obs, np.array([[-1, -1]]), np.array([[3, 5]]))
    assert out.progressed[0].tolist() == [False, False]
    assert w.s.since[0].tolist() == [1, 0]


def test_plans_exchanged_before_meeting_carry_their_tasks():
    """``traffic.exchange_plans`` by hand: two pairs in one run, (0, 1) and (2, 3), the
    holder of the right of way (robot 3) in the second. The ages are swapped within each
    pair; a task handed to the robot standing on its aim ends (since = t + 1); the right
    of way goes to the holder's partner, and a pair without the holder leaves it alone
    (two pairs of one run: a scatter over the run's rows would let the last pair win)."""
    from qpatrol.world import traffic

    w = build("........\n", starts=[0, 1, 4, 5], agents=4, **{"team.avoid_collisions": True})
    s = w.s
    s.t = 10
    s.since[:] = [[1, 2, 3, 4]]
    # robot 0 heads for cell 1 (robot 1's), robot 1 for cell 0, robot 2 for 7, robot 3 for 4
    s.aim[:] = [[1, 0, 7, 4]]
    s.token[:] = 3
    ended = traffic.exchange_plans(s, np.array([0, 0]), np.array([0, 2]), np.array([1, 3]))
    # robot 0 gets robot 1's task (aim 0, its cell: ends), robot 1 robot 0's (aim 1: ends),
    # robot 2 robot 3's (aim 4, its cell: ends), robot 3 robot 2's (aim 7: goes on, age 3)
    assert ended.tolist() == [[True, True, True, False]]
    assert s.since.tolist() == [[11, 11, 11, 3]]
    assert s.token.tolist() == [2]
    s.token[:] = 0  # the holder in the first pair, the second pair after it
    traffic.exchange_plans(s, np.array([0, 0]), np.array([0, 2]), np.array([1, 3]))
    assert s.token.tolist() == [1]
