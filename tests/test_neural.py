"""``policy: neural``: a trained policy evaluated as a strategy, and the reference learner
(when PyTorch is installed: ``qpatrol[rl]``)."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from qpatrol import run
from qpatrol.config import ConfigError, from_flat
from qpatrol.strategies import features, neural


def test_a_port_is_drawn_by_the_inverse_of_the_cumulative_probabilities():
    logits = np.array([[[0.0, np.log(3.0), 5.0, 1.0]]] * 4).reshape(4, 1, 4)
    mask = np.array([[[1, 1, 0, 0]], [[1, 1, 0, 0]], [[0, 0, 0, 1]], [[0, 0, 0, 0]]], dtype=bool)
    u = np.array([[0.2], [0.3], [0.99], [0.5]])
    # ports 0 and 1 with probabilities 1/4 and 3/4: u = 0.2 takes 0, u = 0.3 takes 1;
    # port 3 alone is taken whatever u; no allowed port: none
    assert neural.sample(logits, mask, u)[:, 0].tolist() == [0, 1, 3, -1]


def flat(**kw) -> dict:
    base = {"map": "ps_example", "agents": 3, "runs": 2, "steps": 300, "policy": "neural"}
    return {**base, "team.interaction": "interference", "record.warmup": 100, **kw}


def test_train_runs_the_shipped_policy_on_numpy_under_every_measure(tmp_path):
    """The compiled engine falls back to numpy and says why; the run is reproducible,
    names its weights, and is measured as every strategy is."""
    result = run.simulate(from_flat(flat(engine="numba")))
    assert result.engine == "numpy" and "policy neural" in result.engine_note
    again = run.simulate(from_flat(flat(engine="numpy")))
    assert [r["avg_idleness"] for r in result.summary] == [r["avg_idleness"] for r in again.summary]
    folder = run.write_run(result, tmp_path / "run", meta={})
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["strategy"]["weights"] == neural.SHIPPED.name
    assert summary["runs"][0]["coverage"] == 1.0
    assert summary["runs"][0]["avg_idleness"] > 0


def test_greedy_and_drawn_ports_differ_and_both_patrol():
    drawn = run.simulate(from_flat(flat()))
    greedy = run.simulate(from_flat(flat(**{"neural.greedy": True})))
    a = [r["avg_idleness"] for r in drawn.summary]
    b = [r["avg_idleness"] for r in greedy.summary]
    assert a != b and all(r["coverage"] == 1.0 for r in drawn.summary + greedy.summary)


def test_a_file_that_is_no_policy_is_refused(tmp_path):
    bad = tmp_path / "bad.npz"
    np.savez(bad, format=np.array(neural.FORMAT), features=np.array(["idle"]))
    for path in (bad, tmp_path / "missing.npz"):
        with pytest.raises(ConfigError, match="neural.weights"):
            run.simulate(from_flat(flat(**{"neural.weights": str(path)})))


def test_the_shipped_weights_are_small_and_name_how_they_were_made():
    for path in sorted(neural.WEIGHTS_DIR.glob("*.npz")):
        assert path.stat().st_size < 100_000
        with np.load(path) as z:
            assert str(z["command"]).startswith("python -m qpatrol.learners.ppo")
            assert tuple(str(x) for x in z["features"]) == features.PORT


@pytest.mark.skipif(importlib.util.find_spec("torch") is None, reason="needs qpatrol[rl]")
@pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="needs qpatrol[fast]")
def test_a_short_training_lowers_the_idleness_on_a_small_graph(tmp_path):
    """PPO on ps_grid with 2 robots (a few seconds): the last batches of episodes
    patrol with a lower average idleness than the first (a nearly uniform policy)."""
    from qpatrol.learners import ppo

    out = tmp_path / "w.npz"
    args = ppo.parse(
        ["--map", "ps_grid", "--agents", "2", "--runs", "16", "--episode", "100",
         "--rollout", "50", "--updates", "16", "--epochs", "2", "--minibatches", "2",
         "--seed", "1", "--out", str(out), "--quiet"]
    )  # fmt: skip
    curve = ppo.train(args)
    first, last = curve[0]["avg_idleness"], np.mean([r["avg_idleness"] for r in curve[-2:]])
    assert last < 0.7 * first, [r["avg_idleness"] for r in curve]
    # its weights are a policy train can run
    result = run.simulate(from_flat(flat(**{"neural.weights": str(out)})))
    assert all(r["coverage"] == 1.0 for r in result.summary)
