"""``qpatrol sweep neural``: its points, and the report's section from a table by hand."""

from __future__ import annotations

import pandas as pd

from qpatrol.config import load_config
from qpatrol.strategies import NAMES, neural
from qpatrol.study import report
from qpatrol.study.sweep import NAMED_SWEEPS, NEURAL_MAPS, NEURAL_SEEDS


def test_the_neural_sweep_measures_every_strategy_and_each_seed_with_and_without_failures():
    sweep = NAMED_SWEEPS["neural"]
    points = [p.overrides for p in sweep.points()]
    study = [p for p in points if p["steps"] != 1000]
    assert len(study) == (len(NAMES) + len(NEURAL_SEEDS)) * len(NEURAL_MAPS) * 2
    assert {p["policy"] for p in study} == set(NAMES) | {"neural"}
    assert {(p["failures.robots"], p["agents"]) for p in study} == {(0, 6), (2, 6)}
    base = load_config(sweep.config)
    for p in points:
        cfg = base.replace(**p)
        if p["policy"] == "neural":  # a shipped file, found by its name
            assert (neural.WEIGHTS_DIR / cfg["neural.weights"]).is_file()
    lines = [p for p in points if p["steps"] == 1000]
    assert {p["policy"] for p in lines} == {"cyclic", "sebs"}


def row(m, f, pol, seed, mean, worst=None, run=0):
    return {
        "kind": "study", "map": m, "failures": f, "policy": pol, "seed": seed, "runs": 10,
        "avg_idleness_mean": mean, "worst_idleness_mean": 2 * mean, "worst_run": run,
        "worst_run_avg_idleness": worst or mean, "coverage_min": 1.0,
    }  # fmt: skip


def test_the_report_ranks_the_policy_by_its_mean_over_seeds():
    fig = pd.DataFrame(
        [
            # on a: seeds 10 and 14 (mean 12) beat sebs 13 and cyclic 20: rank 1 of 3
            row("a", 0, "neural", 0, 10.0, 11.0, 3),
            row("a", 0, "neural", 1, 14.0, 19.0, 7),
            row("a", 0, "sebs", -1, 13.0),
            row("a", 0, "cyclic", -1, 20.0),
            # on a with 2 failing: mean 30, behind cyclic 25 and ahead of sebs 40: rank 2
            row("a", 2, "neural", 0, 30.0),
            row("a", 2, "neural", 1, 30.0, 33.0, 4),
            row("a", 2, "sebs", -1, 40.0),
            row("a", 2, "cyclic", -1, 25.0),
        ]
    )
    sec = report.neural(fig)
    assert sec.verdict == "neural best in 1 of 2 settings; median rank 1.5 of 3"
    # the table is one finding (one markdown table, no blank lines between its rows)
    (block,) = [x for x in sec.findings if x.startswith("| map |")]
    table = [x for x in block.split("\n") if x.startswith("| a |")]
    assert table[0] == ("| a | 0 | 12 [10 to 14] | 1 | sebs (13) | 13 | 20 | seed 1, run 7: 19 |")
    assert table[1] == ("| a | 2 | 30 [30 to 30] | 2 | cyclic (25) | 40 | 25 | seed 1, run 4: 33 |")
    assert "Where it is best: a with 0 failing." in sec.findings
