"""The simulator against hand-computed values on tiny maps, and its invariants."""

from pathlib import Path

import numpy as np
import pytest

from qpatrol import env
from qpatrol.config import ConfigError, from_flat
from qpatrol.maps import EAST, WEST
from qpatrol.rng import Streams, run_seeds
from qpatrol.run import prepare, simulate


def world(map_path, runs=1, **flat):
    """Params and initial state with hand-picked defaults (multiplier 1, no battery)."""
    base = {"map": str(map_path), "agents": 1, "battery.enabled": False, "learning.multiplier": 1}
    cfg = from_flat({**base, **flat})
    m, p = prepare(cfg)
    starts = np.stack([env.place_agents(p, m, np.random.default_rng(r)) for r in range(runs)])
    return cfg, m, p, env.init_state(p, starts)


def u_for(pick, runs=1, agents=1, explore=0.99):
    """Uniforms [R, K, 2] with a chosen tie-break value."""
    u = np.empty((runs, agents, 2))
    u[..., 0] = explore
    u[..., 1] = pick
    return u


def test_update_rule_by_hand_on_the_ring(ring_map):
    # ring: 0 1 2 / 3 # 4 / 5 6 7 ; agent at 0 heading North; gamma 0.1, q_init N3 E2 S1 W2,
    # dot 1, incremental 1 saturating at 100 steps, lambda weight 1.
    _, _, p, s = world(ring_map)
    q0 = s.q.copy()
    # step 1: legal E (2) and S (1) -> East to cell 1. r = dot 1 + 1*1/100 + lambda 1/1
    # target = 2.01 + 0.1 * max(Q(1,E,E)=2, Q(1,E,W)=2) = 2.21, alpha = 1
    env.step(s, p, u_for(0.0))
    assert s.pos[0, 0] == 1 and s.head[0, 0] == EAST
    assert s.q[0, 0, 0, 0, EAST] == pytest.approx(2.21, abs=1e-12)
    assert s.n[0, 0, 0, 0, EAST] == 1
    # step 2: at (1, E) East and West tie at 2; u=0.75 takes the second candidate, West.
    # back on cell 0 (its dot is eaten now): r = 1 + 2/100 + 2/2 = 2.02
    # target = 2.02 + 0.1 * max(Q(0,W,E)=2, Q(0,W,S)=1) = 2.22
    env.step(s, p, u_for(0.75))
    assert s.pos[0, 0] == 0 and s.head[0, 0] == WEST
    assert s.q[0, 0, 1, EAST, WEST] == pytest.approx(2.22, abs=1e-12)
    # step 3: at (0, W): East 2 > South 1 -> cell 1, no dot left: r = (3-1)/100 + 2/3
    # target = r + 0.1 * max(Q(1,E,W)=2.22, Q(1,E,E)=2)
    env.step(s, p, u_for(0.0))
    r3 = 0.02 + 2 / 3
    assert s.q[0, 0, 0, WEST, EAST] == pytest.approx(r3 + 0.222, abs=1e-12)
    # step 4: at (1, E): West 2.22 > East 2 -> cell 0; r = (4-2)/100 + 2/4 = 0.52
    # target = 0.52 + 0.1 * max(Q(0,W,E)=r3+0.222, Q(0,W,S)=1) = 0.62; second visit: alpha 1/2
    env.step(s, p, u_for(0.0))
    assert s.n[0, 0, 1, EAST, WEST] == 2
    assert s.q[0, 0, 1, EAST, WEST] == pytest.approx(2.22 + 0.5 * (0.62 - 2.22), abs=1e-12)
    # nothing else moved in the table
    changed = np.argwhere(s.q != q0)
    assert {tuple(x[2:]) for x in changed} == {(0, 0, EAST), (1, EAST, WEST), (0, WEST, EAST)}


def test_reward_parts(tmp_path: Path):
    p_ = tmp_path / "line.txt"
    p_.write_text("0o-.\n")  # start, big dot, empty, dot
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
        cfg, _, p, s = world(p_, **flat, **{"record.transitions": True})
        q_next = s.q[0, 0, 1, EAST].copy()
        env.step(s, p, u_for(0.0))
        boot = p.gamma * max(q_next[EAST], q_next[WEST])
        assert s.q[0, 0, 0, 0, EAST] == pytest.approx(expected + boot, abs=1e-12), flat
    # the empty cell: no dot, incremental only, lambda = 1 dot / 2 visits
    cfg, _, p, s = world(p_, **{"learning.q_init.west": 0.0})
    env.step(s, p, u_for(0.0))
    env.step(s, p, u_for(0.0))  # East is the only best move from (1, E)
    assert s.pos[0, 0] == 2
    boot = p.gamma * 2.0
    assert s.q[0, 0, 1, EAST, EAST] == pytest.approx(0.02 + 0.5 + boot, abs=1e-12)


def test_episode_ends_when_all_dots_are_eaten_and_restarts(tmp_path: Path):
    p_ = tmp_path / "corr.txt"
    p_.write_text("0..\n")
    from qpatrol.records import Recorder

    _, _, p, s = world(p_)
    rec = Recorder(np.array([0]))
    for pick in (0.0, 0.0, 0.0, 0.99):  # E, E (tie, first), W (only move), W (tie, second)
        env.step(s, p, u_for(pick), rec)
    assert s.pos[0, 0] == 0
    ep = rec.episode_table()
    assert ep[
        ["episode", "start_step", "steps", "dots_eaten", "distinct_cells", "complete"]
    ].values.tolist() == [[0, 1, 4, 3, 3, 1]]
    # all dots back, counters reset, Q kept, agents where they were
    assert s.dots.all() and s.dots_left[0, 0] == 3 and s.ep_count[0, 0] == 1
    assert s.ep_start[0, 0] == 4 and s.ep_visits[0, 0] == 0
    assert s.n.sum() == 4


def test_truncated_episodes(tmp_path: Path):
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


def test_battery_trip_home_and_back(tmp_path: Path):
    p_ = tmp_path / "corr.txt"
    p_.write_text("H.....0\n")  # H is cell 0, the agent starts on cell 6
    flat = {
        "battery.enabled": True,
        "battery.capacity": 10,
        "battery.margin": 0,
        "battery.charge_steps": 3,
        "learning.multiplier": 1,
    }
    _, _, p, s = world(p_, **flat)
    streams = Streams(run_seeds(7, 1), 1)
    trips, rest_seen = 0, 0
    for _ in range(300):
        before = (int(s.pos[0, 0]), int(s.mode[0, 0]), int(s.charge[0, 0]), int(s.n.sum()))
        env.step(s, p, streams.next())
        pos, mode, charge = int(s.pos[0, 0]), int(s.mode[0, 0]), int(s.charge[0, 0])
        assert 0 <= charge <= 10
        if before[1] == env.PATROL and mode == env.HOMING:
            assert charge <= pos  # switched because charge <= distance home + margin
        if mode == env.HOMING or before[1] == env.HOMING:
            assert pos == before[0] - 1  # straight home along the shortest path
            assert s.n.sum() == before[3]  # homing moves do not update Q
        if before[1] == env.HOMING and pos == 0:
            trips += 1
            assert mode == env.CHARGING and s.rest[0, 0] == 3
        if before[1] == env.CHARGING:
            rest_seen += 1
            assert pos == 0 and s.n.sum() == before[3]
            if mode == env.PATROL:
                assert charge == 10  # full again after 3 steps of rest
    assert trips >= 5 and rest_seen == pytest.approx(3 * trips, abs=3)


def test_battery_config_checked_against_map(tmp_path: Path):
    p_ = tmp_path / "corr.txt"
    p_.write_text("H.....0\n")
    with pytest.raises(ConfigError, match="battery.capacity: 6 is too small"):
        world(p_, **{"battery.enabled": True, "battery.capacity": 6, "battery.margin": 0})
    p_.write_text("......0\n")
    with pytest.raises(ConfigError, match="no charging station"):
        world(p_, **{"battery.enabled": True})


def _walk(cfg, steps):
    m, p = prepare(cfg)
    streams = Streams(run_seeds(cfg["seed"], cfg["runs"]), p.n_agents)
    s = env.init_state(p, np.stack([env.place_agents(p, m, g) for g in streams.generators]))
    for _ in range(steps):
        old = s.pos.copy()
        env.step(s, p, streams.next())
        yield m, old, s.pos.copy()


@pytest.mark.parametrize("avoid", [True, False])
def test_agents_never_share_a_cell_never_swap_never_enter_walls(rooms_map, avoid):
    cfg = from_flat(
        {
            "map": str(rooms_map),
            "agents": 6,
            "runs": 4,
            "learning.epsilon": 0.3,
            "team.avoid_collisions": avoid,
            "battery.capacity": 40,
            "battery.charge_steps": 5,
            "seed": 3,
        }
    )
    shared = swaps = 0
    for m, old, new in _walk(cfg, 1500):
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
    if avoid:
        assert shared == 0 and swaps == 0
    else:  # the check would catch it: without avoidance agents do meet
        assert shared > 0


def test_extra_agents_are_spread_on_distinct_free_cells(rooms_map):
    cfg = from_flat({"map": str(rooms_map), "agents": 9, "battery.enabled": False})
    m, p = prepare(cfg)
    cells = env.place_agents(p, m, np.random.default_rng(0))
    assert cells[:4].tolist() == m.starts.tolist()
    assert len(set(cells.tolist())) == 9
    with pytest.raises(ConfigError, match="agents: 40 agents do not fit"):
        prepare(cfg.replace(agents=40))


def test_communication_off_gives_private_dot_maps(ring_map, tmp_path):
    p_ = tmp_path / "two.txt"
    p_.write_text("0...1\n")
    _, _, p, s = world(p_, agents=2, **{"team.communication": False})
    assert s.dots.shape == (1, 2, 5)
    env.step(s, p, u_for(0.0, agents=2))
    # agent 0 ate cell 1 on its own map only; agent 1 ate cell 3 on its own map only
    assert s.dots[0, 0].tolist() == [True, False, True, True, True]
    assert s.dots[0, 1].tolist() == [True, True, True, False, True]
    _, _, p, s = world(p_, agents=2)
    env.step(s, p, u_for(0.0, agents=2))
    assert s.dots.shape == (1, 1, 5)
    assert s.dots[0, 0].tolist() == [True, False, True, False, True]


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
    assert r.state.n[..., 1:, :].sum() == 0 and r.state.n.sum() > 0


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
    assert np.array_equal(whole.state.q[1], alone.state.q[0])
    assert np.array_equal(whole.state.visits[1], alone.state.visits[0])
    e = whole.episodes[whole.episodes.run == 1].reset_index(drop=True)
    assert e.equals(alone.episodes)
    other_seed = simulate(cfg.replace(seed=1), runs=range(1, 2))
    assert not np.array_equal(other_seed.state.q[0], alone.state.q[0])


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


RING_WITH_TWO_STATIONS = "H1.0..\n.####.\n...H..\n"


@pytest.mark.parametrize(
    "charge, margin, path",
    [
        (9, 6, [4, 5, 7, 13, 12, 11]),  # station 0 is busy: go round to station 11
        (5, 2, [2, 1, 1, 0]),  # station 11 is out of reach: wait one step for station 0
    ],
)
def test_homing_bypasses_an_occupied_station_it_can_avoid(tmp_path, charge, margin, path):
    # ring of 14 cells: top row 0-5 (H at 0, agent 1 starts at 1, agent 0 at 3), cells 6 and 7
    # down the sides, bottom row 8-13 with a second H at 11
    p_ = tmp_path / "ring.txt"
    p_.write_text(RING_WITH_TWO_STATIONS)
    flat = {
        "agents": 2,
        "battery.enabled": True,
        "battery.capacity": 20,
        "battery.margin": margin,
        "battery.charge_steps": 2,
    }
    _, m, p, s = world(p_, **flat)
    assert p.homes.tolist() == [0, 11]
    s.pos[0, 1], s.mode[0, 1], s.rest[0, 1] = 0, env.CHARGING, 2  # agent 1 charging at 0
    s.charge[0, 0] = charge
    seen = []
    for _ in path:
        env.step(s, p, u_for(0.0, agents=2))
        seen.append(int(s.pos[0, 0]))
    assert seen == path
    assert s.mode[0, 0] == env.CHARGING and s.charge[0, 0] >= 0
