"""The edges of the measuring window, by hand, in each engine on its own.

Every measure of ``summary.json`` counts the team steps ``t > record.warmup`` (the
window, ``docs/model.md``, "Patrolling measures"); the timeline's windows are runs of
``record.timeline`` steps from step 1. Each test below puts an event (a visit, the end
of an interval, the peak of a gap, a wait, an episode's start, a cycle's completion)
exactly at step ``warmup``, ``warmup + 1`` or the last step, on a tiny map whose walk
is known by hand, and checks each engine against the hand value (never against the
other engine): ``numpy`` always, ``numba`` when it is installed.

The maps (their walks are asserted first, :func:`test_the_walks_the_hand_values_rest_on`):

* ``CORRIDOR``, a dead end of 8 cells 0..7, one ``cyclic`` robot on cell 0: it enters
  cell ``t`` at steps 1..7, then ``14 - t`` at 8..14, ``t - 14`` at 15..21, and so on
  (period 14: cell 0 at 14, 28; cell 7 at 7, 21). Last visits after step 13: cells 0..7
  at 0, 13, 12, 11, 10, 9, 8, 7.
* ``CORRIDOR_B``, the same with the robot on cell 2: cells 1, 0, 1, 2, ..., 7 at steps
  1..9, then 6..0 at 10..16 and 1..7 at 17..23.
* ``SHUTTLE``, a vertical corridor of two cells: a Q-learner has one legal move in
  either and shuttles, entering cell 1 at odd steps and cell 0 at even ones (two robots
  without collision avoidance: each enters the other's cell at every step).
* ``RING12`` with two cyclic robots, gathered 6 cells apart by step 60.
* ``PAIR``, a corridor of 7 cells with two cyclic robots at its ends: robot 1 waits
  one step at steps 4 and 10 and at no other step up to 10.

Each window edge broken on purpose, one at a time in a scratch copy (numpy breaks run
with the numpy tests, compiled ones with the numba tests; the shared code with both),
and the tests that then failed (the rest passed):

numpy, ``qpatrol/measures``:

* ``observe``: ``in_window = t >= warmup``: coverage, intervals, idleness, target
  averages, division of labour, waits, both shuttles; its visit block alone: the same
  but waits; its step block alone: idleness, waits, shuttles; only ``window_visits`` at
  ``t == warmup``: coverage, idleness (freq_std), division of labour, shuttles; only
  ``idle_total``/``measured``: idleness, shuttles; only ``max_wait``, only
  ``wait_total``, only ``interferences``: waits.
* ``observe``: worst ``t - 1 >= warmup``: worst idleness (the issue's 13 for 9).
* ``observe``: cycle ``t > start``; ``cycle_start = warmup``: cycles, shuttles.
* ``worst_idleness``: open gaps ``steps_done - 1``: worst idleness.
* ``target_averages``: open gap ``steps_done - 1``: target averages.
* ``summarize``: ``start_step >= warmup``: steps per episode.
* ``Timeline.observe``: ``t - 1 >= start - 1``, and ``t - 1 > start``: timeline
  (windows of 13, of 12); open gaps ``t - 1`` at a window's end (``_close``, and the
  cut-short last window in ``table``): timeline.

compiled, ``qpatrol/engines``:

* ``observe.visit``: ``t >= warmup``: as numpy's visit block; worst ``t - 1 >=
  warmup``: worst idleness; cycle ``t > c_start``: cycles, shuttles.
* ``observe.step_measures``: ``t >= warmup``: idleness, waits; ``run_block``'s
  interferences ``t >= warmup``: waits.
* ``observe.timeline``: ``t - 1 >= start - 1``, ``t - 1 > start``, open gaps ``t - 1``
  at a window's end: timeline.
* ``episodes.end``: an episode's start written one step early: steps per episode.
* ``_solo_qlearning``'s ``t >= warmup``: the lone shuttle; ``_team_qlearning``'s: the
  team shuttle (one condition guards its idleness, waits and interferences).

Not pinned, because no run can show it: ``_solo_qlearning``'s ``t_end > warmup``
guards ``max(max_wait, 0)``, a no-op (a lone robot never waits); ``worst_idleness``'s
``steps_done > warmup`` differs from ``>=`` only for a run with no window step, whose
worst idleness is None either way.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from typing import Any

import pytest
from test_measures import RING12, write

from qpatrol.config import from_flat
from qpatrol.run import RunResult, simulate

HAS_NUMBA = importlib.util.find_spec("numba") is not None
ENGINES = [
    "numpy",
    pytest.param("numba", marks=pytest.mark.skipif(not HAS_NUMBA, reason="numba not installed")),
]

CORRIDOR = "0.......\n"
CORRIDOR_B = "..0.....\n"
SHUTTLE = "0\n.\n"
PAIR = "0....1.\n"
NO_AVOID = {"team__avoid_collisions": False}


def run(
    tmp_path: Path,
    engine: str,
    text: str,
    warmup: int,
    steps: int,
    policy: str = "cyclic",
    agents: int = 1,
    **extra: Any,
) -> RunResult:
    """One run of ``policy`` on the map ``text`` (battery off), on ``engine``; ``extra``:
    more config keys, with ``__`` for a dot (``record__timeline``)."""
    flat = {
        "map": write(tmp_path, text),
        "agents": agents,
        "policy": policy,
        "battery.enabled": False,
        "record.warmup": warmup,
        "steps": steps,
        "engine": engine,
        **{k.replace("__", "."): v for k, v in extra.items()},
    }
    result = simulate(from_flat(flat))
    assert result.engine == engine
    return result


def corridor_cell(t: int) -> int:
    """The cell ``CORRIDOR``'s robot enters at step t (a walk of period 14)."""
    return t % 14 if t % 14 <= 7 else 14 - t % 14


@pytest.mark.parametrize("engine", ENGINES)
def test_the_walks_the_hand_values_rest_on(tmp_path, engine):
    """The walks the hand values below assume (the world's rules, tested elsewhere)."""
    r = run(tmp_path, engine, CORRIDOR, 0, 30, record__trajectory=30)
    assert r.trajectory.cell.tolist() == [corridor_cell(t) for t in range(1, 31)]
    r = run(tmp_path, engine, CORRIDOR_B, 0, 23, record__trajectory=23)
    assert r.trajectory.cell.tolist() == [1, 0, *range(1, 8), *range(6, -1, -1), *range(1, 8)]
    r = run(tmp_path, engine, SHUTTLE, 0, 6, "qlearning", record__trajectory=6)
    assert r.trajectory.cell.tolist() == [1, 0, 1, 0, 1, 0]
    r = run(tmp_path, engine, SHUTTLE, 0, 3, "qlearning", 2, record__trajectory=3, **NO_AVOID)
    assert r.trajectory.sort_values(["step", "agent"]).cell.tolist() == [1, 0, 0, 1, 1, 0]


# --- worst idleness ---------------------------------------------------------------------


@pytest.mark.parametrize("engine", ENGINES)
def test_worst_idleness_ignores_a_peak_at_step_warmup(tmp_path, engine):
    """The case of the issue: cell 0, the corridor's start, is first entered at step 14
    = warmup + 1; its gap (from step 0) peaked at 13 at step 13 = warmup, outside the
    window. In the window 14..16 the visits close gaps peaking at 15 - 1 - 13 = 1 and
    16 - 1 - 12 = 3, and cell 7 (last entered at 7) is 16 - 7 = 9 idle at the end:
    worst idleness 9, where taking the peak at step warmup gives 13."""
    assert run(tmp_path, engine, CORRIDOR, 13, 16).summary[0]["worst_idleness"] == 9


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "warmup, steps, worst",
    [
        (12, 16, 13),  # the peak at step 13 = warmup + 1 is in the window
        (13, 16, 9),  # ... at step 13 = warmup it is not (above)
        (13, 21, 13),  # cell 7 entered at the last step, 21, after 7: peak 13 at step 20
        (13, 14, 7),  # no gap closes in the window; cell 7's open gap at step 14: 7
    ],
)
def test_worst_idleness_at_both_edges(tmp_path, engine, warmup, steps, worst):
    assert run(tmp_path, engine, CORRIDOR, warmup, steps).summary[0]["worst_idleness"] == worst


# --- coverage, intervals, idleness, frequencies ------------------------------------------


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "warmup, steps, coverage",
    [
        (6, 8, 2 / 8),  # cells 7 (step 7 = warmup + 1) and 6 (step 8, the last)
        (7, 8, 1 / 8),  # cell 7's visit is at step 7 = warmup: only cell 6
    ],
)
def test_coverage_at_both_edges(tmp_path, engine, warmup, steps, coverage):
    s = run(tmp_path, engine, CORRIDOR, warmup, steps).summary[0]
    assert s["coverage"] == coverage
    assert s["division_of_labour"] == 1.0  # one robot


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "warmup, steps, mean, largest, qmi, spread",
    [
        # step 13 = warmup + 1 enters cell 1 after step 1: 12; step 14 enters cell 0
        # first (no interval)
        (12, 14, 12, 12, 12, 0),
        # the window is step 14 alone: no interval ends in it (13's is at warmup)
        (13, 14, None, None, None, None),
        # step 15 (the last) enters cell 1 after step 13: 2
        (13, 15, 2, 2, 2, 0),
        # ... and step 16 enters cell 2 after step 12: 4; qmi sqrt((4 + 16) / 2),
        # std sqrt(2 x 20 - 6^2) / 2 = 1
        (13, 16, 3, 4, math.sqrt(10), 1),
    ],
)
def test_intervals_at_both_edges(tmp_path, engine, warmup, steps, mean, largest, qmi, spread):
    s = run(tmp_path, engine, CORRIDOR, warmup, steps).summary[0]
    assert s["mean_interval"] == mean and s["max_interval"] == largest
    assert s["qmi"] == qmi and s["std_interval"] == spread


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "warmup, steps, idle, freq_std",
    [
        # idleness summed over the 8 cells after steps 13, 14, 15, 16: 34 (13, 0, 1, 2,
        # 3, 4, 5, 6), 28 (0..7), 34 (1, 0, 3..8), 38 (2, 1, 0, 5..9)
        (12, 16, (34 + 28 + 34 + 38) / 32, math.sqrt(8 * 6 - 4**2) / (8 * 4)),
        (13, 16, (28 + 34 + 38) / 24, math.sqrt(8 * 3 - 3**2) / (8 * 3)),
        (15, 16, 38 / 8, math.sqrt(8 * 1 - 1**2) / (8 * 1)),
    ],
)
def test_idleness_and_frequencies_at_both_edges(tmp_path, engine, warmup, steps, idle, freq_std):
    """Window visits for freq_std: (12, 16): cell 1 twice (13, 15), cells 0 and 2 once;
    (13, 16): cells 0, 1, 2 once; (15, 16): cell 2 once (step 16, the last):
    ``sqrt(T sum v^2 - (sum v)^2) / (T W)`` with T = 8 cells and W window steps."""
    r = run(tmp_path, engine, CORRIDOR, warmup, steps)
    assert r.measures.measured[0] == steps - warmup
    assert r.summary[0]["avg_idleness"] == idle
    assert r.summary[0]["freq_std"] == freq_std


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "warmup, steps, averages",
    [
        # window 13..14: cell 1's interval 12 ends at 13 = warmup + 1; cell 0 (entered
        # at the last step, first visit) is 0 idle at the end, cell c >= 2: 14 - (14 - c)
        (12, 14, [0, 12, 2, 3, 4, 5, 6, 7]),
        # window 14: no interval; cell 1 (entered at 13 = warmup) is 1 idle at the end
        (13, 14, [0, 1, 2, 3, 4, 5, 6, 7]),
    ],
)
def test_target_averages_at_both_edges(tmp_path, engine, warmup, steps, averages):
    """Each target's average interval in the window, or its idleness at the end when no
    interval of it ends there: worst, mean, median (of 8: the mean of the middle two)
    and population std of the 8 averages."""
    s = run(tmp_path, engine, CORRIDOR, warmup, steps).summary[0]
    mean = sum(averages) / 8
    middle = sorted(averages)[3:5]
    assert s["worst_avg_idleness"] == max(averages)
    assert s["mean_avg_idleness"] == mean
    assert s["median_idleness"] == sum(middle) / 2
    assert s["std_idleness"] == math.sqrt(sum((a - mean) ** 2 for a in averages) / 8)


# --- patrol cycles -------------------------------------------------------------------------


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "warmup, steps, cycles",
    [
        # the first cycle starts at step 14 = warmup + 1, entering cell 0, then cells
        # 1..7 at 15..21: complete at the last step, 21
        (13, 21, 1),
        (13, 20, 0),
        # it starts at 15: cell 0 (entered at 14 = warmup) is not in it before step 28
        (14, 21, 0),
    ],
)
def test_cycles_at_both_edges(tmp_path, engine, warmup, steps, cycles):
    assert run(tmp_path, engine, CORRIDOR, warmup, steps).summary[0]["cycles"] == cycles


# --- division of labour ---------------------------------------------------------------------


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "warmup, steps, dol",
    [
        (60, 66, 1.0),  # 6 steps: each of the 12 cells entered once
        # 7 steps: the cell robot A enters at step 60 = warmup + 1 is entered by robot
        # B at 66 (the last step), and the one B enters at 60 by A at 66: 2 cells
        # shared 1 / 2, 10 entered once
        (59, 66, (10 + 2 * 0.5) / 12),
    ],
)
def test_division_of_labour_at_both_edges(tmp_path, engine, warmup, steps, dol):
    """Two cyclic robots on the 12-ring, 6 cells apart once gathered (by step 60,
    tests/test_measures.py), each entering one cell per step: robot B enters at t + 6
    the cell A entered at t."""
    s = run(tmp_path, engine, RING12, warmup, steps, agents=2).summary[0]
    assert s["coverage"] == 1.0
    assert s["division_of_labour"] == dol


# --- waits ---------------------------------------------------------------------------------


@pytest.mark.parametrize("engine", ENGINES)
def test_waits_at_both_edges(tmp_path, engine):
    """Two cyclic robots at the ends of a 7-cell corridor meet at cells 3 and 4: robot 1
    waits one step at steps 4 and 10 (its wait after the runs of 1..10 steps, below),
    then moves on. The window 4..9 holds the wait at 4 = warmup + 1; 5..9 none (step
    4 = warmup); 5..10 the wait at 10, the last step. With the battery off every wait
    is an interference."""
    waited = [
        t for t in range(1, 11) if run(tmp_path, engine, PAIR, 0, t, agents=2).state.wait[0, 1]
    ]
    assert waited == [4, 10]
    for warmup, steps, n in [(3, 9, 1), (4, 9, 0), (4, 10, 1)]:
        s = run(tmp_path, engine, PAIR, warmup, steps, agents=2).summary[0]
        assert (s["waits"], s["max_wait"], s["interferences"]) == (n, n, n), (warmup, steps)


# --- steps per episode ----------------------------------------------------------------------


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "warmup, steps, per_episode",
    [
        (0, 23, (9 + 14) / 2),  # episode 0 starts at step 1 = warmup + 1
        (1, 23, 14),  # ... at step 1 = warmup: only episode 1 counts
        (9, 23, 14),  # episode 1 starts at step 10 = warmup + 1, ends at 23 (the last)
        (10, 23, None),  # ... at step 10 = warmup
        (9, 22, None),  # ... and is not over by step 22
    ],
)
def test_steps_per_episode_at_both_edges(tmp_path, engine, warmup, steps, per_episode):
    """Every cell holds a dot. On ``CORRIDOR_B`` episode 0 (steps 1..9) ends when cell 7
    is entered; episode 1 (from step 10, all dots back) eats cells 6..0 at 10..16 and
    ends on entering cell 7 again at 23: 14 steps."""
    r = run(tmp_path, engine, CORRIDOR_B, warmup, steps)
    done = r.episodes[r.episodes.complete == 1]
    assert (
        list(zip(done.start_step, done.steps, strict=True))
        == [(1, 9), (10, 14)][: 1 + (steps >= 23)]
    )
    assert r.summary[0]["mean_steps_per_episode"] == per_episode


# --- the timeline's windows -----------------------------------------------------------------


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "window, rows",
    [
        # window 1 (14..16): cell 0's gap peaked at 13 at step 13, in window 0, and is
        # closed at step 14; in window 1 the gaps closed peak at 1 and 3, cell 7 is 9
        # idle at step 16. Window 0 (1..13): cell 0 is 13 idle at its end; idleness sums
        # after steps 1..13: 7, 13, 18, 22, 25, 27, 28, 34, 38, 40, 40, 38, 34 (364)
        (13, [(0, 1, 13, 364 / (8 * 13), 13), (1, 14, 16, 100 / (8 * 3), 9)]),
        # window 1 (13..16): cell 0's gap peaks at 13 at step 13, its first step; cell
        # 1's, closed at 13, peaked at 11 at step 12, in window 0, whose end sees cell 0
        # 12 idle
        (12, [(0, 1, 12, 330 / (8 * 12), 12), (1, 13, 16, 134 / (8 * 4), 13)]),
    ],
)
def test_timeline_windows_at_both_edges(tmp_path, engine, window, rows):
    """The corridor's robot, timeline windows of 13 and of 12 steps over 16 steps (a
    shorter last window); each row: window, first and last step, average and worst
    idleness."""
    df = run(tmp_path, engine, CORRIDOR, 0, 16, record__timeline=window).timeline
    got = df[["window", "first_step", "last_step", "avg_idleness", "worst_idleness"]]
    assert [tuple(x) for x in got.itertuples(index=False)] == rows


# --- the compiled Q-learning loops ------------------------------------------------------------


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "warmup, steps, freq_std, cycles",
    [
        # window 3..5: cell 1 entered at 3 and 5, cell 0 at 4: sqrt(2 x 5 - 3^2) / (2 x 3);
        # a cycle (both cells) completes at 4, the next is under way
        (2, 5, 1 / 6, 1),
        (3, 5, 0.0, 1),  # window 4..5: each cell once
        (2, 6, 0.0, 2),  # window 3..6: the second cycle completes at 6, the last step
    ],
)
def test_a_lone_shuttle_at_both_edges(tmp_path, engine, warmup, steps, freq_std, cycles):
    """A Q-learner alone on the two-cell corridor (on numba its own loop): after any step
    the cell entered is 0 idle and the other 1 (counted from step 0 at step 1):
    average 1/2, worst 1; every interval is 2 from step 3 on."""
    r = run(tmp_path, engine, SHUTTLE, warmup, steps, "qlearning")
    if engine == "numba":
        assert r.loop == "qlearning-solo"
    s = r.summary[0]
    assert r.measures.measured[0] == steps - warmup
    assert s["freq_std"] == freq_std and s["cycles"] == cycles
    assert s["avg_idleness"] == 0.5 and s["worst_idleness"] == 1
    assert s["coverage"] == 1.0 and s["mean_interval"] == 2


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "warmup, steps, dol",
    [
        # window 3..5: robot 1 enters cell 0 at 3 and 5, robot 0 at 4 (and the other way
        # round for cell 1): 2/3 each
        (2, 5, 2 / 3),
        (3, 5, 1 / 2),  # window 4..5
    ],
)
def test_a_team_shuttle_at_both_edges(tmp_path, engine, warmup, steps, dol):
    """Two Q-learners on the two-cell corridor without collision avoidance (on numba the
    team loop): at every step each enters the other's cell, so both cells are entered
    at every step by one robot each: idleness 0, intervals 1, a cycle per step."""
    r = run(tmp_path, engine, SHUTTLE, warmup, steps, "qlearning", 2, **NO_AVOID)
    if engine == "numba":
        assert r.loop == "qlearning-team"
    s = r.summary[0]
    assert r.measures.measured[0] == steps - warmup
    assert s["division_of_labour"] == dol and s["cycles"] == steps - warmup
    assert s["avg_idleness"] == 0.0 and s["mean_interval"] == 1
    assert s["waits"] == 0 and s["interferences"] == 0
