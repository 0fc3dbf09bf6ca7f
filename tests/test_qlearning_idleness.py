"""``qlearning-idleness`` (beyond the paper): state encoding, reward, update rule.

Hand-made situations on the plus map of test_strategies, a shadow table kept by the
test over a whole run, a behavioural check that fails when the reward is broken, and
determinism. Liveness is covered with every other strategy in test_liveness.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ROOMS
from test_strategies import HISTORY, PLUS, forced, run_steps, setup, start, u_for

from qpatrol import run, world
from qpatrol.config import FIELDS, KEYS, from_flat
from qpatrol.maps import EAST, NORTH, SOUTH, WEST, get_map, parse_map
from qpatrol.strategies import qlearning_idleness as qi

POLICY = "qlearning-idleness"


def test_keys_are_listed_and_only_read_by_this_policy():
    keys = [k for k in KEYS if k.startswith("qidle.")]
    assert len(keys) >= 8
    assert all(FIELDS[k].used_by == (POLICY,) for k in keys)


# --- state encoding -----------------------------------------------------------------------


def test_idlest_reads_the_oldest_non_wall_neighbour_first_in_nesw_order():
    # cell 4 of the plus: N 1, E 5, S 7, W 3
    neighbors = parse_map(PLUS).neighbors
    last = np.zeros((1, 9), dtype=np.int64)
    last[0, [1, 3, 5, 7]] = [1, 2, 3, 5]
    assert qi.idlest(last, np.array([4]), neighbors).tolist() == [NORTH]
    last[0, 1] = 9  # now W (2) is the oldest
    assert qi.idlest(last, np.array([4]), neighbors).tolist() == [WEST]
    last[0, 3] = 3  # E and W tie at 3: East first
    assert qi.idlest(last, np.array([4]), neighbors).tolist() == [EAST]
    # cell 1 (N arm): only N (0) and S (4) are not walls, whatever the walls' slots hold
    last[0, [0, 4]] = [7, 6]
    assert qi.idlest(last, np.array([1]), neighbors).tolist() == [SOUTH]


def test_the_state_feature_uses_the_teams_map_or_the_robots_own():
    """After HISTORY (test_strategies): the team's last visits around the centre are
    N 1, W 2, E 3, S 5, so robot 0 on the centre sees North as the idlest; without
    communication its own map has W never entered: West."""
    _, _, p, s, strat = setup(PLUS, [4, 2], POLICY)
    for choice in HISTORY:
        forced(s, p, strat, choice)
    np.testing.assert_array_equal(strat.last, s.last)  # its map is the world's
    assert strat.features(s.pos)[0, 0] == NORTH
    _, _, p, s, strat = setup(PLUS, [4, 2], POLICY, **{"team.communication": False})
    for choice in HISTORY:
        forced(s, p, strat, choice)
    np.testing.assert_array_equal(strat.last, s.last)
    assert strat.features(s.pos)[0, 0] == WEST
    # the ablation without the feature: always slot 0
    _, _, p, s, strat = setup(PLUS, [4, 2], POLICY, **{"qidle.state": "cell_heading"})
    for choice in HISTORY:
        forced(s, p, strat, choice)
    assert strat.features(s.pos)[0, 0] == 0 and strat.q.shape[4] == 1


# --- reward and update rule, by hand ------------------------------------------------------


def test_one_update_by_hand_with_the_known_reward():
    """One robot on the centre of the plus (9 cells, scale = 9 / 1), gamma 0.5, alpha
    0.5, Q 1 everywhere. Step 1: it moves North into cell 1. The state it left: (4,
    heading N, idlest N: all neighbours tie at 0), action N. In cell 1 at step 2 the
    moves N (cell 0) and S (cell 4) would each earn (2 - 0) / 9 (the start cell counts
    as never entered), so

        target = gamma x max(2/9 + 1, 2/9 + 1) = 11/18
        Q = 1 + 0.5 x (11/18 - 1) = 29/36,  N = 1

    and nothing else changed."""
    flat = {"qidle.gamma": 0.5, "qidle.alpha": 0.5, "qidle.q_init": 1.0}
    _, _, p, s, strat = setup(PLUS, [4], POLICY, **flat)
    forced(s, p, strat, [NORTH])
    assert strat.q[0, 0, 4, NORTH, NORTH, NORTH] == pytest.approx(29 / 36, abs=1e-15)
    assert strat.n[0, 0, 4, NORTH, NORTH, NORTH] == 1
    assert strat.n.sum() == 1 and (np.delete(strat.q.ravel(), strat.n.ravel().argmax()) == 1).all()
    # step 2: back South into the centre; left state (1, heading N, idlest: N (cell 0)
    # never entered vs S (cell 4) never entered: tie, N first), action S. At step 3 in
    # the centre: N (cell 1) would earn (3 - 1) / 9, E, S, W (3 - 0) / 9; Q(4, S, E, .)
    # is still 1 (idlest at the centre is now E: cell 1 was entered at step 1)
    forced(s, p, strat, [SOUTH])
    assert strat.features(s.pos)[0, 0] == EAST
    want, n = qi.td_step(
        1.0, 0, 0.0, np.array([2 / 9, 3 / 9, 3 / 9, 3 / 9]) + 1, [True] * 4, 0.5, 0.5
    )
    assert want == pytest.approx(1 + 0.5 * (0.5 * (1 + 3 / 9) - 1), abs=1e-15) and n == 1
    assert strat.q[0, 0, 1, NORTH, NORTH, SOUTH] == pytest.approx(want, abs=1e-15)


def test_one_update_by_hand_as_plain_q_learning_with_alpha_one_over_n():
    """``qidle.known_reward: off``: the reward is paid into the target. Step 1 North
    into cell 1, which was never entered: r = min(3, (1 - 0) / 9) = 1/9; Q(1, N, N, .)
    is 2 everywhere: target = 1/9 + 0.5 x 2; alpha = 1/N = 1: Q = target = 10/9."""
    flat = {
        "qidle.gamma": 0.5,
        "qidle.alpha": 0.0,
        "qidle.q_init": 2.0,
        "qidle.known_reward": False,
    }
    _, _, p, s, strat = setup(PLUS, [4], POLICY, **flat)
    forced(s, p, strat, [NORTH])
    assert strat.q[0, 0, 4, NORTH, NORTH, NORTH] == pytest.approx(1 / 9 + 1, abs=1e-15)
    # the choice is greedy over Q alone: in cell 1, N and S tie at 2 (tie-break u)
    obs = world.begin_step(s, p)
    assert strat.act(obs, u_for(0.2))[0, 0] == NORTH
    assert strat.act(obs, u_for(0.7))[0, 0] == SOUTH


def test_the_choice_adds_the_known_idleness_to_q():
    """Robot 0 on the centre after HISTORY, Q 0: it goes to the team's idlest
    neighbour (North); lift Q of East in its state by more than the idleness gap and it
    goes East."""
    _, _, p, s, strat = setup(PLUS, [4, 2], POLICY)
    for choice in HISTORY:
        forced(s, p, strat, choice)
    strat.q[:] = 0.0
    obs = world.begin_step(s, p)
    assert strat.act(obs, u_for(0.5, agents=2))[0, 0] == NORTH
    # known rewards at step 7 (scale 9 / 2): N (7 - 1) / 4.5, E (7 - 3) / 4.5
    strat.q[0, 0, 4, s.head[0, 0], NORTH, EAST] = 2 / 4.5 + 1e-9
    assert strat.act(obs, u_for(0.5, agents=2))[0, 0] == EAST


def _shadow_run(flat, steps=300):
    """Run ``flat`` on ROOMS (battery on: homing and pushed robots do not learn) and
    replay every update on a shadow table, robot by robot in step order; the shadow
    must equal the strategy's tables after every step."""
    cfg = from_flat(
        {
            "policy": POLICY,
            "agents": 3,
            "runs": 2,
            "seed": 11,
            "battery.capacity": 30,
            "battery.charge_steps": 3,
            "qidle.epsilon": 0.3,
            "qidle.q_init": 0.5,
            **flat,
        }
    )
    m = parse_map(ROOMS)
    p, s, strat, streams = start(cfg, m)
    q = strat.q.copy()
    n = strat.n.copy()
    gamma, alpha, cap = cfg["qidle.gamma"], cfg["qidle.alpha"], cfg["qidle.reward_cap"]
    known = cfg["qidle.known_reward"]
    scale = p.n_cells / p.n_agents
    shared = cfg["qidle.share"] and cfg["team.communication"]
    updates = 0
    for _ in range(steps):
        before = s.last.copy()
        obs = world.begin_step(s, p)
        feat = qi.idlest(s.last[:, [0] * 3], s.pos, p.neighbors)
        out = world.step(s, p, obs, strat.act(obs, streams.next()))
        strat.learn(out)
        last_now = before.copy()
        for k in range(3):
            for r in range(2):
                if out.moved[r, k]:
                    c = out.pos[r, k]
                    idle = out.t - last_now[r, 0, c]
                    last_now[r, 0, c] = out.t
                    if out.choosing[r, k] and out.as_asked[r, k]:
                        pk = 0 if shared else k
                        a, c0 = out.ask[r, k], out.prev_pos[r, k]
                        nb = p.neighbors[c]
                        nxt = qi.idlest(s.last[r, 0][None], np.array([c]), p.neighbors)[0]
                        q_next = q[r, pk, c, a, nxt].copy()
                        reward = min(cap, idle / scale)
                        if known:
                            q_next += np.minimum(
                                cap, (out.t + 1 - s.last[r, 0, np.maximum(nb, 0)]) / scale
                            )
                            reward = 0.0
                        idx = (r, pk, c0, out.prev_head[r, k], feat[r, k], a)
                        q[idx], n[idx] = qi.td_step(
                            q[idx], n[idx], reward, q_next, nb >= 0, gamma, alpha
                        )
                        updates += 1
        np.testing.assert_array_equal(last_now, s.last)
        np.testing.assert_allclose(strat.q, q, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(strat.n, n)
    return updates


@pytest.mark.parametrize(
    "flat",
    [
        {},
        {"qidle.known_reward": False, "qidle.alpha": 0.0},
        {"qidle.share": False, "qidle.gamma": 0.7},
    ],
    ids=["default", "plain-1/N", "own-tables"],
)
def test_every_update_follows_the_rule_on_a_shadow_table(flat):
    assert _shadow_run(flat) > 800


# --- the reward matters: a check that a broken reward fails -------------------------------


def patrols_well(cfg, m):
    """The team patrols: every cell visited in the window, and the average idleness at
    most 1.25 x the average of a perfect even patrol's ``cells / (2 robots)``."""
    res = run.simulate(cfg, prepared=(m, world.make_params(cfg, m)))
    for r in res.summary:
        assert r["coverage"] == 1.0, r
        assert r["avg_idleness"] <= 1.25 * m.n_cells / cfg["agents"], r
    return res


CHECK = {
    "policy": POLICY,
    "map": "map_b",
    "agents": 2,
    "runs": 2,
    "steps": 1500,
    "record.warmup": 500,
    "battery.enabled": False,
}


def test_the_learner_patrols_map_b():
    patrols_well(from_flat(CHECK), get_map("map_b"))


def test_a_reward_with_its_sign_flipped_fails_the_check(monkeypatch):
    real = qi.Strategy.reward_of
    monkeypatch.setattr(qi.Strategy, "reward_of", lambda self, *a: -real(self, *a))
    with pytest.raises(AssertionError):  # (the numpy engine: the one the patch is in)
        patrols_well(from_flat({**CHECK, "engine": "numpy"}), get_map("map_b"))


# --- determinism --------------------------------------------------------------------------


def test_same_seed_same_tables_and_moves():
    cfg = from_flat({**CHECK, "steps": 400, "record.warmup": 0, "qidle.epsilon": 0.2})
    m = get_map("map_b")
    a = [s.pos.copy() for _, s, _, _, _ in run_steps(cfg, m, 300)]
    b = [s.pos.copy() for _, s, _, _, _ in run_steps(cfg, m, 300)]
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    r1 = run.simulate(cfg)
    r2 = run.simulate(cfg)
    np.testing.assert_array_equal(r1.strategy.q, r2.strategy.q)
    assert r1.summary == r2.summary


def test_with_gamma_zero_it_moves_as_shared_conscientious():
    """No discount, nothing learned (Q stays 0): the choice is the idlest open neighbour
    on the team's map, as ``shared-conscientious``, move for move (the cap lifted, so
    that no two old neighbours tie at it)."""
    m = get_map("map_b")
    flat = {"agents": 2, "runs": 2, "seed": 3, "battery.enabled": False}
    ours = from_flat({**flat, "policy": POLICY, "qidle.gamma": 0.0, "qidle.reward_cap": 1e6})
    theirs = from_flat({**flat, "policy": "shared-conscientious"})
    a = [s.pos.copy() for _, s, _, _, _ in run_steps(ours, m, 300)]
    b = [s.pos.copy() for _, s, _, _, _ in run_steps(theirs, m, 300)]
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
