"""Progress under ``exclusive``: what ``live`` sees, and the three rules that keep it.

A robot makes progress when its task ends: it reaches its aim (a goal follower's goal,
a walk follower's next walk cell, the vertex ahead on an edge, its station) or, without
an aim, enters a target (:func:`qpatrol.world.step`). ``max_stall`` is the longest
stretch without progress; ``live`` is false when it exceeds ``stall_bound`` or a target
stays unvisited for the whole window. Each of the three rules of issue "Exclusive cells,
honestly live" is broken here on purpose, and each break is seen:

1. ``live`` by progress: a robot that shuttles never waits long, so only the stall sees
   it (the waits stay within the old ``(K - 1)(D + 1) + 1``);
2. the right of way by the task's age: with the turn alone deciding, insisting robots
   starve on small maps (the model checker finds the cycles);
3. hand on (exchange tasks with the robot in the way): without it, two ``cc`` robots on
   the 7-cell T block each other for good.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from qpatrol.config import from_flat
from qpatrol.run import simulate
from qpatrol.world import traffic

sys.path.insert(0, str(Path(__file__).parent))
import modelcheck as mc  # noqa: E402

#: The 7-cell T of the issue: a corridor of 5 cells with a stem of 2 under its middle.
T7 = "#######\n#.....#\n###.###\n###.###\n#######\n"


def _t_runs(tmp_path: Path, engine: str = "numpy") -> list[dict]:
    """``cc``, 2 robots, battery off, seed 3, 4 runs x 1,500 steps, warm-up 500."""
    path = tmp_path / "t7.txt"
    path.write_text(T7)
    flat = {
        "map": str(path), "agents": 2, "policy": "cc", "runs": 4, "steps": 1500, "seed": 3,
        "record.warmup": 500, "battery.enabled": False, "engine": engine,
    }  # fmt: skip
    return simulate(from_flat(flat)).summary


@pytest.mark.parametrize("engine", ["numpy", "numba"])
def test_two_cc_robots_on_the_t_are_live(tmp_path, engine):
    """The issue's shuttle: every run covers all 7 cells and no stretch without progress
    exceeds the bound, K (D + 2) = 2 x 6 = 12 (D = 4: an arm's end to the stem's)."""
    for r in _t_runs(tmp_path, engine):
        assert r["stall_bound"] == 2 * (4 + 2)
        assert r["live"] and r["coverage"] == 1.0 and r["max_stall"] <= 12


def test_without_hand_on_the_t_freezes(tmp_path, monkeypatch):
    """Break rule 3: a holder that cannot push only hands the token on (no exchange of
    tasks, no exchange of ages). Two ``cc`` robots heading for each other's side then
    block each other in the corridor for good: every run ends ``live: false``."""

    def no_exchange(s, r, k, b, res):
        res.handoff[r] = b

    monkeypatch.setattr(traffic, "hand_on", no_exchange)
    runs = _t_runs(tmp_path)
    assert not any(r["live"] for r in runs)
    assert all(r["max_stall"] > 1000 for r in runs)


def test_a_shuttle_is_seen_by_its_stall_not_by_its_waits(tmp_path, monkeypatch):
    """Break rule 3 the way the earlier rules did it: a holder that cannot push steps
    aside into an empty neighbour. The two robots then shuttle: they move nearly every
    step (the longest wait is 1, within the old ``(K - 1)(D + 1) + 1`` = 6), cover 3 of
    the 7 cells, and no task ever ends. The stall (rule 1) sees it: ``max_stall`` above
    the bound and ``live: false``."""
    seen = {}
    resolve = traffic.resolve

    def remember(s, p, want, plans=False):
        seen["p"] = p
        return resolve(s, p, want, plans)

    def step_aside(s, r, k, b, res):
        for c in traffic._neighbour_lists(seen["p"])[int(s.pos[r, k])]:
            if c >= 0 and s.occ[r, c] < 0:
                traffic._move(s, r, k, c)
                res.moved[r, k] = True
                return

    monkeypatch.setattr(traffic, "resolve", remember)
    monkeypatch.setattr(traffic, "hand_on", step_aside)
    for r in _t_runs(tmp_path):
        assert r["max_wait"] <= (2 - 1) * (4 + 1) + 1
        assert r["max_stall"] > r["stall_bound"] and not r["live"]
        assert r["coverage"] < 1.0


def test_without_the_age_insisting_robots_starve(monkeypatch):
    """Break rule 2: every task as young as the others when the token passes, so the
    turn alone decides. On the 4- and 5-cell maps with two robots heading for goals
    (the model checker's goal adversary) robots then starve; with the age, none does."""
    cases = mc.family(range(4, 6), ks=range(2, 3), adversary="goal")
    assert not any(r.livelocks for r in mc.check_all(cases))
    pass_token = traffic.pass_token

    def by_turn(s, p, want, res, progressed):
        kept = s.since.copy()
        s.since[:] = s.t + 1
        try:
            pass_token(s, p, want, res, progressed)
        finally:
            s.since[:] = kept

    monkeypatch.setattr(traffic, "pass_token", by_turn)
    starved = [r for r in mc.check_all(cases) if r.livelocks]
    assert len(starved) >= 10
    w = starved[0].livelocks[0]
    stalls = mc.replay(starved[0].checker, w, loops=3)
    assert (np.diff(stalls) > 0).all()


def _on_ps_example(
    policy: str, agents: int, runs: int, steps: int, engine: str, battery: bool = False
) -> list[dict]:
    """``agents`` robots of ``policy`` on ps_example (a patrol graph with dead-end spurs),
    battery off (or on), ``exclusive``: ``runs`` x ``steps``, warm-up 500."""
    flat = {
        "map": "ps_example", "policy": policy, "agents": agents, "runs": runs, "steps": steps,
        "record.warmup": 500, "battery.enabled": battery, "team.interaction": "exclusive",
        "engine": engine,
    }  # fmt: skip
    return simulate(from_flat(flat)).summary


def test_walk_followers_crowding_dead_end_spurs_turn_round_and_stay_live():
    """12 ``cyclic`` robots on ps_example (a patrol graph with dead-end spurs): a robot
    travelling into a spur whose plan is handed back behind it (it meets one waiting on
    the spur's end) turns round on the edge. Every run is live, every vertex visited,
    and the engines agree on every measure."""
    by_engine = [_on_ps_example("cyclic", 12, 1, 1500, e) for e in ("numpy", "numba")]
    assert by_engine[0] == by_engine[1]
    (r,) = by_engine[0]
    assert r["live"] and r["coverage"] == 1.0 and r["max_stall"] <= r["stall_bound"], r


def test_walk_followers_exchanging_plans_exchange_their_tasks_ages():
    """16 ``learned-tour`` robots on ps_example, 2 runs: two robots that exchange plans
    before they meet exchange their tasks' ages too, and a task handed to the robot on its
    aim ends. Every run is live, every vertex visited, and the engines agree on every
    measure."""
    by_engine = [_on_ps_example("learned-tour", 16, 2, 1500, e) for e in ("numpy", "numba")]
    assert by_engine[0] == by_engine[1]
    for r in by_engine[0]:
        assert r["live"] and r["coverage"] == 1.0 and r["max_stall"] <= r["stall_bound"], r


def test_plans_exchanged_without_their_ages_leave_a_robot_stalled(monkeypatch):
    """Deliberate break: plans exchanged before meeting leave the ages where they were. In
    the second run a robot travelling ps_example's spur between vertices 5 and 1 meets a
    robot at each end, is handed back the plan behind it each time and hands on its own,
    which the other carries on at once: it shuttles on the spur, its age grows past the
    bound while the plans it passes on advance, and it keeps the right of way."""
    from qpatrol.strategies import follow

    monkeypatch.setattr(follow.WalkFollower, "ages_with_plans", False)
    runs = _on_ps_example("learned-tour", 16, 2, 1500, "numpy")
    assert runs[1]["max_stall"] > runs[1]["stall_bound"] and not runs[1]["live"], runs[1]


def test_walk_followers_with_a_common_plan_exchange_nothing():
    """16 ``cyclic`` robots with the battery on ps_example, one run of 4,000 steps: two
    robots about to meet with the same plan (walk and target: one waits on it, the other
    comes in) exchange nothing, so the right of way stays with the holder. The run is live
    and the engines agree on every measure."""
    by_engine = [_on_ps_example("cyclic", 16, 1, 4000, e, battery=True) for e in ("numpy", "numba")]
    assert by_engine[0] == by_engine[1]
    (r,) = by_engine[0]
    assert r["live"] and r["coverage"] == 1.0 and r["max_stall"] <= r["stall_bound"], r


def test_walk_followers_exchanging_a_common_plan_freeze(monkeypatch):
    """Deliberate break: robots with the same plan exchange it before meeting. The
    holder, on the edge into vertex 12 where a robot waits on their common target, hands
    it the right of way at every step; the waiting robot does not use it, and the team
    freezes (from step 1,641)."""
    from qpatrol.strategies import follow

    monkeypatch.setattr(follow.WalkFollower, "skip_same_plans", False)
    (r,) = _on_ps_example("cyclic", 16, 1, 4000, "numpy", battery=True)
    assert r["max_stall"] > r["stall_bound"] and not r["live"], r


def _far_goals(engine: str) -> dict:
    """16 ``dta-ssi-part`` robots on ps_cumberland, battery off, ``exclusive``: one run
    of 1,200 steps, warm-up 200."""
    flat = {
        "map": "ps_cumberland", "policy": "dta-ssi-part", "agents": 16, "runs": 1,
        "steps": 1200, "record.warmup": 200, "battery.enabled": False,
        "team.interaction": "exclusive", "engine": engine,
    }  # fmt: skip
    (r,) = simulate(from_flat(flat)).summary
    return r


def test_far_goal_followers_head_on_exchange_tasks():
    """A holder of the right of way head on with a robot whose goal is an allocated task
    (both ask for the other's cell) exchanges tasks with it rather than pushing it back: 16
    ``dta-ssi-part`` robots on ps_cumberland visit every vertex, no robot stalls past the
    bound, and the engines agree on every measure."""
    by_engine = [_far_goals(e) for e in ("numpy", "numba")]
    assert by_engine[0] == by_engine[1]
    r = by_engine[0]
    assert r["live"] and r["coverage"] == 1.0 and r["avg_idleness"] < 8.0, r


def test_far_goal_followers_pushed_back_head_on_starve_a_vertex(monkeypatch):
    """Deliberate break: the holder pushes a ``dta`` robot head on with it back, as it
    does any robot. A robot heading for vertex 36 through the edge where another
    shuttles between its two vertices is pushed back every time they meet, and each
    push ends its task at the vertex behind it (its age starts again): the vertices
    beyond wait, and the average idleness is at least twice the one with the rule."""
    from qpatrol.strategies import dta

    kept = _far_goals("numpy")
    monkeypatch.setattr(dta.DTA, "keeps_plans", False)
    pushed = _far_goals("numpy")
    assert pushed["avg_idleness"] > 2 * kept["avg_idleness"], (pushed, kept)


def test_a_team_waiting_on_its_aims_is_not_live(monkeypatch):
    """Deliberate break: travellers never turn round. Robots travelling into a spur and
    robots waiting on its end then exchange plans back and forth, and the rest of the
    team waits on its walk vertices for them: no task ends for two thousand steps, and
    the stall says so (its bound counts the walk followers' spacing waits). (When a robot
    standing on its aim counted as making progress, every waiting robot ``progressed``
    every step: a ``max_stall`` of 13.)"""
    from qpatrol.strategies import follow

    monkeypatch.setattr(follow.WalkFollower, "plans_on_edges", False)
    (r,) = _on_ps_example("cyclic", 12, 1, 2500, "numpy")
    assert r["max_stall"] > 2 * r["stall_bound"] and not r["live"]


def _own_records(policy: str, engine: str) -> list[dict]:
    """Two ``cc`` or ``hpcc`` robots on ps_example: 2 runs x 2,000 steps."""
    return _on_ps_example(policy, 2, 2, 2000, engine)


@pytest.mark.parametrize("policy", ["cc", "hpcc"])
def test_a_goal_handed_on_counts_as_served_in_the_own_record(policy):
    """Robots that keep their own records (``cc``, ``hpcc``) count a goal they handed on
    to the robot in their way as served. Then two robots on ps_example (dead-end spurs)
    cover every vertex, and the engines agree on every measure."""
    by_engine = [_own_records(policy, e) for e in ("numpy", "numba")]
    assert by_engine[0] == by_engine[1]
    for r in by_engine[0]:
        assert r["live"] and r["coverage"] == 1.0, r


@pytest.mark.parametrize("policy", ["cc", "hpcc"])
def test_a_goal_handed_on_and_forgotten_is_chased_by_both(policy, monkeypatch):
    """Deliberate break: the record forgets the goal handed on. The robot that took it
    and the robot that handed it on choose the same next goals, one behind the other:
    a run leaves most of the graph unvisited, and the average idleness at least
    triples."""
    import importlib

    mod = importlib.import_module(f"qpatrol.strategies.{policy}")

    def forgetful(self, out, rec=None):
        rr, kk = np.nonzero(out.moved)
        self.memory[rr, kk, out.pos[rr, kk]] = out.t

    kept = _own_records(policy, "numpy")
    monkeypatch.setattr(mod.Strategy, "learn", forgetful)
    forgot = _own_records(policy, "numpy")
    assert min(r["coverage"] for r in forgot) < 0.5
    idle = [np.mean([r["avg_idleness"] for r in rs]) for rs in (kept, forgot)]
    assert idle[1] > 3 * idle[0], idle
