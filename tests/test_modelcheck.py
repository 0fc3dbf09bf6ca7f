"""Exhaustive model checking of the movement and battery rules (``tests/modelcheck.py``).

On every tree and one-loop map of a few cells, for every team size up to the density
limit, the checker explores every state the rules reach when the strategy is an
adversary, from every placement of the robots, and looks for a reachable cycle on which
a task never ends: a robot that has a task (patrols, homes or queues) and neither ends
it nor hands it on at every step, or the oldest task of the team kept on every step,
whoever carries it (a livelock). The default family runs in about two minutes of one
core; ``QPATROL_MODELCHECK=full`` runs a larger one (7 cells without battery, three
robots with the battery on 6 cells, two stations, 40 sampled three-robot cases on 7 and
8 cells), for a benchmark or a release (docs/model.md gives its counts).

The tests print how many maps, cases, states and transitions they explored (``pytest -s``).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time

import modelcheck as mc
import numpy as np
import pytest

from qpatrol import world
from qpatrol.config import ConfigError
from qpatrol.world import battery, traffic

#: The referee's counterexample to the earlier rules: 3 robots, battery on, the
#: smallest capacity, charging 1 step, staggered charges; one station is a cut vertex.
COUNTEREXAMPLE = mc.Case("..H..\n#.#H.\n", 3, battery=True)


def _cases(part: str, full: bool) -> list[mc.Case]:
    """The family's cases of one part: ``off`` (battery off), ``on`` (battery on, the
    adversary that chooses among open moves), ``goal`` (battery on, robots heading for
    goals and insisting) and ``sample`` (three robots on 7 and 8 cells)."""
    if part == "off":
        if full:
            return (
                mc.family(range(4, 8))
                + mc.family(range(4, 7), adversary="legal")
                + mc.family(range(4, 7), adversary="goal")
            )
        # every shape of 4-6 cells with two robots, one in four of 6 cells with three
        # (the density limit, K <= C / 2); the insisting adversaries on 4-5 cells
        return (
            mc.family(range(4, 7), ks=range(2, 3))
            + mc.family(range(6, 7), ks=range(3, 4), every=4)
            + mc.family(range(4, 6), adversary="legal")
            + mc.family(range(4, 6), adversary="goal")
        )
    if part == "on":
        cases = (
            # a station at a dead end, on a junction, on a corridor cell that cuts the
            # map and on a loop: the smallest capacity the config accepts (charging 0
            # and 1 steps), and with the departure added
            mc.family(range(4, 6), battery=True, charge_steps=0, corridor=True)
            + mc.family(range(4, 6), battery=True, charge_steps=1, corridor=True)
            + mc.family(range(4, 7), ks=range(2, 3), battery=True, departure=True)
            # two stations at two dead ends (on a T, pockets of one junction)
            + mc.family(range(4, 7), ks=range(2, 3), battery=True, dead_pair=True)
            + [COUNTEREXAMPLE]
        )
        if full:
            cases += (
                mc.family(range(4, 7), battery=True, two_stations=True, extra_capacity=4)
                + mc.family(range(6, 8), ks=range(3, 4), battery=True, dead_pair=True)
                + mc.family(range(6, 7), ks=range(3, 4), battery=True, corridor=True)
                + mc.family(range(4, 6), battery=True, charge_steps=2, initial_charge="full")
            )
        return cases
    if part == "goal":
        sizes = range(4, 7) if full else range(4, 6)
        return mc.family(sizes, ks=range(2, 3), battery=True, adversary="goal", corridor=True)
    if part == "head-on":
        # the goal adversary with rule 2's exchange head on (dta robots), battery off
        # and on
        sizes = range(4, 7) if full else range(4, 6)
        cases = mc.family(sizes, adversary="goal") + mc.family(
            sizes, ks=range(2, 3), battery=True, adversary="goal", corridor=True
        )
        return [dataclasses.replace(c, head_on=True) for c in cases]
    if part == "early":
        # the goal adversary with the walk followers' exchange before meeting (goals, task
        # ages and the right of way), battery off and on; the battery cases a sample of 24
        # drawn with seed 1 (all 92 take 64 s of one core), every one in the full family
        sizes = range(4, 7) if full else range(4, 6)
        cases = mc.family(sizes, adversary="goal") + mc.family(
            sizes, ks=range(2, 3), battery=True, adversary="goal", corridor=True,
            sample=None if full else 24, seed=1,
        )  # fmt: skip
        return [dataclasses.replace(c, early=True) for c in cases]
    # three robots and two stations: rule (b) refuses every such case up to 6 cells, so
    # a sample of the accepted ones on 7 and 8 cells (stations at dead ends, junctions,
    # cut corridor cells and loops, and two at once), drawn with seed 1
    return mc.family(
        range(7, 9), ks=range(3, 4), battery=True, corridor=True, two_stations=True,
        sample=40 if full else 5, seed=1,
    )  # fmt: skip


FULL = os.environ.get("QPATROL_MODELCHECK", "") == "full"


@functools.cache
def _explored(part: str) -> tuple[list[mc.Result], float]:
    """The family's cases of ``part``, explored: each test explores its own part, so
    that workers share the family."""
    cases = _cases(part, FULL)
    t0 = time.perf_counter()
    # a state space that blows up (a counter the rules gain that never stops growing)
    # fails here rather than running for hours
    results = mc.check_all(cases, max_states=3_000_000 if not FULL else 20_000_000)
    return results, time.perf_counter() - t0


def _summary(results: list[mc.Result], seconds: float | None = None) -> str:
    maps = {r.case.text for r in results}
    bad = [r for r in results if r.livelocks]
    took = f", {seconds:.1f} s" if seconds is not None else ""
    return (
        f"{len(maps)} maps, {len(results)} cases (map, K, battery, adversary), "
        f"{sum(r.states for r in results)} states (at most "
        f"{max(r.states for r in results)} in one), {sum(r.edges for r in results)} "
        f"transitions, {len(bad)} cases with a livelock{took}"
    )


def _no_livelock(results: list[mc.Result]) -> None:
    assert all(r.complete for r in results), "a state space grew beyond max_states"
    bad = sorted(
        (r for r in results if r.livelocks),
        key=lambda r: (r.checker.p.n_cells, r.case.k, len(r.livelocks[0].cycle)),
    )
    if bad:
        first = bad[0]
        pytest.fail(
            f"{len(bad)} of {len(results)} cases have a livelock; the smallest:\n"
            + first.checker.report(first.livelocks[0])
        )


def test_no_task_starves_without_battery():
    """Zero livelocks with the battery off, every team up to half the free cells, the
    three adversaries (the theorem of docs/model.md); prints what was explored."""
    off, seconds = _explored("off")
    print(f"\nmodel check, battery off: {_summary(off, seconds)}")
    assert len(off) > 400
    assert {r.case.adversary for r in off} == {"open", "legal", "goal"}
    _no_livelock(off)


#: With the battery on the config refuses what no rule of today serves
#: (:func:`qpatrol.world.check_battery_room`), and the family keeps only the cases it
#: accepts (:func:`modelcheck.accepted`). The refused kinds, each with a small
#: livelock (``test_refused_teams_would_starve`` explores them with the check off):
#: A. a one-wide line without a station K - 1 cells or more from both ends (``H....``,
#:    K = 2; ``.H.....``, K = 3): robots never change order on a line, so the one behind
#:    the others never reaches the station (no rule can: docs/model.md);
#: D. more robots than half the free cells outside stations and their pockets: on the
#:    6-cell T with a pocket station (``#H#/#.#/.../##.``, K = 3) the homing robot cannot
#:    get past a queued robot, and on ``H../#.#/..#`` (K = 3, the station alone in its
#:    pocket) the robot on the pocket's junction steps aside into the homing robot's way.
#: (B., a capacity too small to cover the moves of leaving a station, is refused too.)
REFUSED = [
    ("line", mc.Case("H....\n", 2, battery=True), "a one-wide line without a station"),
    ("line-k3", mc.Case(".H.....\n", 3, battery=True), "a one-wide line without a station"),
    ("pocket", mc.Case("#H#\n#.#\n...\n##.\n", 3, battery=True), "leave no room to yield"),
    ("crowded", mc.Case("H..\n#.#\n..#\n", 3, battery=True), "leave no room to yield"),
]


def test_no_task_starves_with_battery():
    """Zero livelocks with the battery on, on every case of the family the config
    accepts (stations at a dead end, on a junction, on a cut corridor cell, on a loop,
    two at once) and the referee's counterexample; prints what was explored."""
    on, seconds = _explored("on")
    print(f"\nmodel check, battery on: {_summary(on, seconds)}")
    assert len(on) > 400
    assert any(r.case == COUNTEREXAMPLE for r in on)
    _no_livelock(on)


def test_no_task_starves_with_battery_and_goals():
    """Zero livelocks with the battery on when patrolling robots head for goals and
    insist on a shortest way (goal and walk followers; the adversary keeps a goal until
    it is reached)."""
    goal, seconds = _explored("goal")
    print(f"\nmodel check, battery on, goals: {_summary(goal, seconds)}")
    assert len(goal) > 80
    _no_livelock(goal)


def test_no_task_starves_with_goals_exchanged_head_on():
    """Zero livelocks, battery off and on, when the holder head on with a robot heading
    for a goal exchanges tasks with it rather than pushing (rule 2 for the ``dta``
    strategies)."""
    cases, seconds = _explored("head-on")
    print(f"\nmodel check, goals exchanged head on: {_summary(cases, seconds)}")
    assert all(r.case.head_on and r.case.adversary == "goal" for r in cases)
    assert len(cases) > 100
    _no_livelock(cases)


def test_no_task_starves_with_goals_exchanged_before_meeting():
    """Zero livelocks, battery off and on, when two robots each asking for the other's
    cell exchange goals and the ages of their tasks before the step, and a task handed to
    the robot on its aim ends (the walk followers' exchange before meeting)."""
    cases, seconds = _explored("early")
    print(f"\nmodel check, goals exchanged before meeting: {_summary(cases, seconds)}")
    assert all(r.case.early and r.case.adversary == "goal" for r in cases)
    assert len(cases) > 100 and sum(r.case.battery for r in cases) >= 24
    _no_livelock(cases)


def _ages_stay(s, rr, kk, jj):
    """Goals exchanged, ages and right of way not."""


def _no_end(s, rr, kk, jj):
    """Ages and right of way exchanged; a task handed to the robot on its aim goes on."""
    s.since[rr, kk], s.since[rr, jj] = s.since[rr, jj].copy(), s.since[rr, kk].copy()
    tok = s.token[rr]
    held_k, held_j = tok == kk, tok == jj
    s.token[rr[held_k]] = jj[held_k]
    s.token[rr[held_j]] = kk[held_j]


def _token_stays(s, rr, kk, jj):
    """Ages exchanged and handed tasks ended, but the holder keeps the right of way."""
    tok = s.token.copy()
    _EXCHANGE(s, rr, kk, jj)
    s.token[:] = tok


_EXCHANGE = traffic.exchange_plans


@pytest.mark.parametrize("broken", [_ages_stay, _no_end, _token_stays])
def test_an_exchange_before_meeting_that_leaves_the_task_behind_livelocks(monkeypatch, broken):
    """Deliberate breaks of the exchange before meeting (``traffic.exchange_plans``),
    each found on the map ``..#/...`` with two robots: the ages stay with the robots (a
    robot handed back goal after goal keeps its age and never ends a task), a task handed
    to the robot on its aim does not end (the old age comes back), or the holder keeps
    the right of way after handing its task on (it pushes the robot carrying it back)."""
    monkeypatch.setattr(traffic, "exchange_plans", broken)
    res = mc.Checker(mc.Case("..#\n...\n", 2, adversary="goal", early=True)).explore()
    assert res.complete and res.livelocks


def test_no_task_starves_with_three_robots_and_two_stations():
    """Zero livelocks in the sample of three-robot battery cases on 7 and 8 cells."""
    sample, seconds = _explored("sample")
    print(f"\nmodel check, 3 robots on 7-8 cells: {_summary(sample, seconds)}")
    assert all(r.case.k == 3 and r.case.battery for r in sample)
    _no_livelock(sample)


def test_the_counterexample_is_live():
    """The referee's counterexample (42 livelocks in 286,979 states under the earlier
    rules) has none under today's: every task ends."""
    res = mc.check_all([COUNTEREXAMPLE])[0]
    assert res.complete and not res.livelocks and res.states > 100_000


#: Lines the config accepts (a station K - 1 cells or more from both ends): the family's
#: stations are at dead ends and junctions only, so these are checked here.
LINES = [(".H...\n", 2), ("..H..\n", 2), ("..H....\n", 3), ("...H....\n", 3)]


@pytest.mark.parametrize("text, k", LINES)
def test_no_robot_is_starved_on_lines_the_config_accepts(text, k):
    """A line with a station far enough from both ends has no livelock."""
    res = mc.check_all([mc.Case(text, k, battery=True)])
    assert res[0].complete
    _no_livelock(res)


@pytest.mark.parametrize("name, case, words", REFUSED, ids=[r[0] for r in REFUSED])
def test_refused_teams_would_starve(monkeypatch, name, case, words):
    """Each kind the config refuses is a real livelock: refused with one line naming
    ``agents``, and, with :func:`qpatrol.world.check_battery_room` switched off, the
    checker finds a robot failing for ever (replayed with R = 1, its wait grows)."""
    assert not mc.accepted(case)
    with pytest.raises(ConfigError, match=words) as e:
        mc.Checker(case)
    assert str(e.value).startswith("agents: ") and "\n" not in str(e.value)
    monkeypatch.setattr(world, "check_battery_room", lambda *a: None)
    ck = mc.Checker(case)
    res = ck.explore()
    assert res.complete and res.livelocks
    waits = mc.replay(ck, res.livelocks[0], loops=3)
    assert (np.diff(waits) > 0).all()


def test_shapes_are_the_fixed_polyominoes_with_at_most_one_loop():
    """There are 1, 2, 6, 19, 63 and 216 fixed polyominoes of 1 to 6 cells; only the 2 x 3
    rectangle (two ways round) has two loops, and only the 2 x 2 square of 4 cells one."""
    assert [len(mc.shapes(n)) for n in range(1, 7)] == [1, 2, 6, 19, 63, 214]
    assert [len(mc.shapes(n, max_cycles=0)) for n in range(1, 5)] == [1, 2, 6, 18]


def test_strong_components_match_reachability():
    """Tarjan's components against the definition: u, v together iff each reaches the other."""
    rng = np.random.default_rng(5)
    for _ in range(30):
        n = int(rng.integers(1, 12))
        m = int(rng.integers(0, 3 * n))
        src, dst = rng.integers(0, n, m), rng.integers(0, n, m)
        comp = mc.strong_components(n, src, dst)
        reach = np.eye(n, dtype=bool)
        reach[src, dst] = True
        for k in range(n):
            reach |= reach[:, [k]] & reach[[k], :]
        together = reach & reach.T
        assert (together == (comp[:, None] == comp[None, :])).all()


@pytest.mark.parametrize(
    "case",
    [
        mc.Case(mc.map_text(mc.shapes(6)[40]), 3),
        mc.Case(mc.map_text(mc.shapes(6)[100]), 2, adversary="legal"),
        mc.Case("H..\n#.#\n#.#\n", 2, battery=True, charge_steps=1),
        mc.Case("..H.\n.##.\n", 2, battery=True, charge_steps=0),
    ],
    ids=["off-K3", "off-legal", "dead-end-station", "junction-station"],
)
def test_abstraction_is_exact(case):
    """States that agree up to the order of their task starts and queue times, and
    differ in every field the rules do not read, have the same successors under every
    choice."""
    ck = mc.Checker(case)
    ck.explore(max_states=200_000)
    rng = np.random.default_rng(11)
    keys = [ck.order[i] for i in rng.choice(len(ck.order), size=min(300, len(ck.order)))]
    K = case.k
    by_mod: dict[int, list[bytes]] = {}
    for key in keys:
        by_mod.setdefault(key[0], []).append(key)

    def scramble(s):
        R = s.pos.shape[0]
        # task starts: a random strictly increasing map of the ranks, all before t;
        # waits: read by no rule, garbage
        gaps = rng.integers(1, 50, size=(R, K)).cumsum(axis=1)
        s.since = np.take_along_axis(gaps, s.since, axis=1)
        s.wait = rng.integers(0, 10**6, size=s.wait.shape)
        queued = s.mode == battery.QUEUED
        spread = rng.integers(1, 7, size=(R, K)).cumsum(axis=1)
        s.queued_since = np.where(queued, np.take_along_axis(spread, s.queued_since, 1), 0)
        s.queued_since += np.where(queued, 0, rng.integers(0, 10**6, size=(R, K)))
        s.head = rng.integers(0, 4, size=s.head.shape)
        s.last = rng.integers(0, 10**6, size=s.last.shape)
        s.dots = rng.random(s.dots.shape) < 0.5
        s.dots_left = s.dots.sum(axis=2) + 1
        s.ep_dots = rng.integers(0, 9, size=s.ep_dots.shape)
        s.ep_visits = s.ep_dots + rng.integers(1, 9, size=s.ep_dots.shape)
        s.ep_start = rng.integers(0, 10, size=s.ep_start.shape)

    for tmod, group in by_mod.items():
        rows = np.frombuffer(b"".join(group), dtype=np.int8).reshape(len(group), -1)
        want = ck.successors(rows)
        t = 10**6 * K + tmod  # far later, the same turn
        got = ck.successors(rows, t=t, perturb=scramble)
        for a, b in zip(want, got, strict=True):
            assert (a == b).all()


def _corridor_checker(**kw) -> mc.Checker:
    return mc.Checker(mc.Case("....\n", 2, **kw))


def test_a_broken_token_is_a_livelock(monkeypatch):
    """Deliberate break: the right of way never passes. Two robots that insist on each
    other's cell in a corridor then wait forever, and the checker says so; the witness,
    replayed with one run, shows the wait growing."""
    ck = _corridor_checker(adversary="legal")
    assert not ck.explore().livelocks  # the real rules: none
    monkeypatch.setattr(traffic, "pass_token", lambda *a, **k: None)
    ck = _corridor_checker(adversary="legal")
    res = ck.explore()
    assert res.livelocks
    waits = mc.replay(ck, res.livelocks[0], loops=3)
    assert (np.diff(waits) > 0).all()


def test_stations_never_given_are_a_livelock(monkeypatch):
    """Deliberate break: a robot that needs a station is never given one; it waits for
    ever where it stands, and the checker finds the cycle (on a T whose station ends an
    arm, where the real rules have none)."""
    case = mc.Case("H..\n#.#\n#.#\n", 2, battery=True, charge_steps=1)
    assert not mc.Checker(case).explore().livelocks
    monkeypatch.setattr(battery, "_assign_stations", lambda s, p: None)
    res = mc.Checker(case).explore()
    assert res.livelocks
    assert not res.livelocks[0].pushed  # it never leaves its cell


def test_tasks_passed_round_for_ever_are_a_livelock(monkeypatch):
    """Deliberate break: no push ever succeeds, so a holder always hands its task on.
    Two robots insisting on each other's cell in a corridor then exchange their tasks
    for ever and neither moves: each robot hands its task on every other step, so no
    robot fails at every step, and only the second part of the criterion (the oldest
    task kept, witness robot K) sees the cycle."""
    assert not _corridor_checker(adversary="legal").explore().livelocks
    monkeypatch.setattr(traffic, "_holder_move", lambda *a, **k: (-1, []))
    ck = _corridor_checker(adversary="legal")
    res = ck.explore()
    assert res.livelocks and {w.robot for w in res.livelocks} == {ck.case.k}
    ages = mc.replay(ck, res.livelocks[0], loops=3)
    assert (np.diff(ages) > 0).all()


def test_robots_exchanging_tasks_head_on_hand_theirs_on():
    """Three robots on a 6-cell line with the exchange head on: each shuttles on a third
    of the line and hands its tasks on, which end at the line's ends; counted as keeping
    its task, the robot in the holder's way made this look like six livelocks."""
    res = mc.Checker(mc.Case("......\n", 3, adversary="goal", head_on=True)).explore()
    assert res.complete and res.states > 100_000 and not res.livelocks
