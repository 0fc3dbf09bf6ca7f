"""Report sections computed from hand-made figure tables (qpatrol.study.report)."""

from __future__ import annotations

import pandas as pd

from qpatrol.study import report


def study_table(rows: list[tuple]) -> pd.DataFrame:
    """A policies table: (map, K, policy, learns, avg, worst) per row, 10 runs each."""
    df = pd.DataFrame(rows, columns=["map", "agents", "policy", "learns", "avg", "worst"])
    out = pd.DataFrame(
        {
            "map": df["map"],
            "agents": df["agents"],
            "policy": df["policy"],
            "learns": df["learns"],
            "runs": 10,
            "frozen": 0,
            "avg_idleness_mean": df["avg"],
            "avg_idleness_n": 10,
            "worst_idleness_mean": df["worst"],
            "walk_length": 20,
            "bound_per_robot": 20 / df["agents"],
            "warmup": [5000 if x else 100 for x in df["learns"]],
            "window": 1000,
        }
    )
    return out


def test_policies_section_by_hand():
    fig = study_table(
        [
            ("m", 1, "qlearning", True, 30.0, 200),
            ("m", 1, "conscientious", False, 10.0, 40),
            ("m", 1, "cyclic", False, 12.0, 20),
            ("m", 2, "qlearning", True, 4.0, 30),
            ("m", 2, "conscientious", False, 5.0, 25),
            ("m", 2, "cyclic", False, 6.0, 10),
        ]
    )
    sec = report.policies(fig)
    text = "\n".join(sec.findings)
    # K = 1: best average 10 (conscientious), learner 30 = 3x; best worst 20 (cyclic), 200 = 10x
    assert "| m | 1 | 20 | 10 (conscientious) | 20 (cyclic) | 30 (3x) | 200 (10x) |" in text
    # K = 2: the learner wins on average (4 against 5: 0.8x), loses on worst (30 / 10 = 3x)
    assert "| m | 2 | 10 | 5 (conscientious) | 10 (cyclic) | 4 (0.8x) | 30 (3x) |" in text
    assert "beats the best classic strategy's average idleness on 1 of 2" in text
    assert "0.8 times the best at its closest (m, K = 2) and 3 times at its farthest" in text
    assert "100 steps for the strategies that do not learn, 5,000 for qlearning" in text


def test_learning_section_by_hand():
    rows = []
    for w, avg in enumerate([100.0, 60.0, 40.0, 30.0]):
        rows.append(("qlearning", True, w, (w + 1) * 10, avg))
    for w in range(3):
        rows.append(("cyclic", False, w, (w + 1) * 10, 50.0 if w == 0 else 35.0))
    df = pd.DataFrame(
        rows, columns=["policy", "learns", "window", "last_step", "avg_idleness_mean"]
    )
    df["avg_idleness_lo"] = df["avg_idleness_mean"] - 1
    df["avg_idleness_hi"] = df["avg_idleness_mean"] + 1
    df["worst_idleness_mean"] = df["avg_idleness_mean"] * 4
    df["runs"], df["map"], df["agents"] = 4, "m", 2
    text = "\n".join(report.learning(df).findings)
    # cyclic's level is the mean after its first window: 35; the learner first gets to 30
    # <= 35 in window 3, ending at step 40; half of 100 -> 30 is 65, reached at step 20
    assert "cyclic 35" in text
    assert "first reaches cyclic's level (35) in the window ending at step 40" in text
    assert "Half of its improvement is made by step 20" in text


def test_policies_goal_of_a_learner_beyond_the_paper():
    """Worst within 1.5 x cyclic's (31 > 1.5 x 20 = 30: no), average below conscientious
    reactive's (9 < 10: yes); a point with coverage below 1 is named."""
    fig = study_table(
        [
            ("m", 1, "qlearning", True, 30.0, 200),
            ("m", 1, "qlearning-idleness", True, 9.0, 31),
            ("m", 1, "conscientious", False, 10.0, 40),
            ("m", 1, "cyclic", False, 12.0, 20),
        ]
    )
    fig["coverage_mean"] = [0.5, 1.0, 1.0, 1.0]
    fig["episodes_truncated_mean"] = [2.5, 0.0, 0.0, 0.0]
    text = "\n".join(report.policies(fig).findings)
    assert "| qlearning-idleness | m | 1 | 31 | 30 | no | 9 | 10 | yes |" in text
    assert "Met in 0 of 1 cells: the worst idleness is within 1.5x in 0, the average" in text
    assert "qlearning at 1 point (lowest 0.5: m, K = 1)" in text
    assert "5,000 for qlearning, 5,000 for qlearning-idleness" in text
    assert "max_episode_steps (no idleness measure uses them): qlearning at 1 point " in text
    assert "(most: m, K = 1, 2.5 per run)" in text
    # the length-blindness of idleness-paid rewards (docs/model.md), stated for the learners
    assert "By reward per step neither learner can tell a short tour from a long one" in text


def test_figure_2_names_its_runs_that_went_wrong():
    """A frozen run, a run without idleness and cut episodes are counted by hand."""
    fig = pd.DataFrame(
        {
            "multiplier": [1.0, 1.0, 100.0, 100.0],
            "action": ["W", "N", "E", "W"],
            "heading": "E",
        }
    )
    res = pd.DataFrame(
        {
            "learning.multiplier": [1.0, 1.0, 100.0, 100.0],
            "avg_idleness": [900.0, float("nan"), 50.0, 60.0],
            "episodes_completed": [1, 0, 9, 8],
            "episodes_truncated": [4, 7, 0, 0],
            "live": [True, True, False, True],
        }
    )
    text = "\n".join(report.figure_2(fig, res).findings)
    assert "Runs that went wrong: 1 frozen, 1 without an idleness value." in text
    assert "cut at max_episode_steps" in text and "1x 5.5 per run." in text
    assert "100x" not in text.split("cut at max_episode_steps")[1].split("\n")[0]


def test_runs_without_an_ended_episode_are_named():
    """Runs whose mean_steps_per_episode is empty (no dot episode ended in the window)
    are counted by hand, per strategy, map and team size; none: no sentence."""
    res = pd.DataFrame(
        {
            "map": ["m", "m", "m", "n"],
            "policy": ["random", "random", "cyclic", "random"],
            "agents": [1, 1, 1, 2],
            "mean_steps_per_episode": [float("nan"), float("nan"), 12.0, float("nan")],
        }
    )
    text = report._no_episode(res)
    assert "): 3 of 4: random 2 at m K = 1, 1 at n K = 2." in text
    assert report._no_episode(res.assign(mean_steps_per_episode=1.0)) == ""
    assert "3 of 4: random" in "\n".join(
        report.policies(
            study_table([("m", 1, "qlearning", True, 3.0, 9), ("m", 1, "cyclic", False, 2.0, 4)]),
            res,
        ).findings
    )


def test_wide_spread_is_found_within_each_interaction():
    """Runs whose average idleness spreads wider than its mean are named per way robots
    meet: pooled with the calm runs of another interaction (mean 11.7, deviation 9.5)
    the spread of the exclusive point (mean 3.4, deviation 5.7) would go unseen."""
    res = pd.DataFrame(
        {
            "map": ["m"] * 6,
            "policy": ["p"] * 6,
            "agents": [2] * 6,
            "team.interaction": ["exclusive"] * 3 + ["none"] * 3,
            "avg_idleness": [0.1, 0.1, 10.0, 20.0, 20.0, 20.0],
        }
    )
    text = report._wide_spread(res)
    assert "1: p at m K = 2 (exclusive) (mean 3.4, worst run 10)" in text, text
    assert report._wide_spread(res.drop(columns="team.interaction")) == ""
