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
@pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="needs numba")
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


@pytest.mark.skipif(importlib.util.find_spec("torch") is None, reason="needs qpatrol[rl]")
@pytest.mark.parametrize("net", ["mlp", "graph"])
def test_numpy_evaluates_the_learners_network_as_torch_does(tmp_path, net):
    """The weights saved by the learner, read by ``policy: neural``, give the logits of
    the torch network they came from (float32 against float64: to 1e-4)."""
    import argparse

    import torch

    from qpatrol.learners import ppo
    from qpatrol.maps import get_map
    from qpatrol.world import make_params

    torch.manual_seed(0)
    cfg = from_flat({"map": "ps_example", "agents": 3})
    tab = features.Tables(get_map("ps_example"), make_params(cfg, get_map("ps_example")))
    p, f_n, v_n = len(features.PORT), len(features.NODE), tab.targets.size
    if net == "graph":
        agent = ppo.GraphAgent(p, f_n, 16, tab.adjacency())
    else:
        agent = ppo.Agent(p, 16)
    for w in agent.parameters():  # weights large enough to matter
        torch.nn.init.normal_(w, 0.0, 0.5)
    args = argparse.Namespace(map="ps_example", agents=3, seed=0)
    ppo.save(agent, tmp_path / "w.npz", args, 0)
    rng = np.random.default_rng(0)
    x = rng.random((5, p, 4)).astype(np.float32)
    nodes = rng.random((5, v_n, f_n)).astype(np.float32)
    pos = tab.targets[rng.integers(0, v_n, 5)]
    port_nodes = tab.port_nodes(pos)
    mask = torch.ones((5, 4), dtype=torch.bool)
    g = (torch.from_numpy(nodes), torch.from_numpy(port_nodes)) if net == "graph" else ()
    want = agent(torch.from_numpy(x), mask, *g)[0].detach().numpy()
    policy = neural.PortPolicy(tmp_path / "w.npz")
    if net == "graph":
        got = policy.logits(x, nodes, tab.adjacency(), port_nodes)
    else:
        got = policy.logits(x)
    assert got == pytest.approx(want, abs=1e-4)
