"""qpatrol.envs: the PettingZoo and Gymnasium envs follow their APIs and the train loop.

The API checks run with warnings turned into errors. The trajectory test drives the
env with qpatrol's own ``qlearning`` strategy, fed the uniforms the env exposes (the
ones ``train`` draws for the run), and compares cells per step, final Q-table and the
patrol measures with :func:`qpatrol.run.simulate` on the same config and seed.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import RING

pytest.importorskip("pettingzoo")
gymnasium = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import check_env  # noqa: E402
from pettingzoo.test import api_test, parallel_api_test  # noqa: E402
from pettingzoo.utils.conversions import parallel_to_aec  # noqa: E402

from qpatrol import run, strategies  # noqa: E402
from qpatrol.config import ConfigError, load_config  # noqa: E402
from qpatrol.envs import FEATURES, PatrolEnv, PatrolParallelEnv  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: one worker under pytest-xdist runs this file: its module fixtures are built once
pytestmark = [pytest.mark.filterwarnings("error"), pytest.mark.xdist_group("envs")]


def paper_env(**kw):
    return PatrolParallelEnv("paper", ["runs=1"], **kw)


def test_parallel_api():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_api_test(paper_env(max_steps=300), num_cycles=1000)


def test_parallel_api_until_termination(tmp_path):
    """A tiny map with an episode quota: every agent terminates, then the test resets."""
    ring = tmp_path / "ring.txt"
    ring.write_text(RING)
    over = ["battery.enabled=false", "episodes=2", "agents=2"]
    env = PatrolParallelEnv(None, over, map=str(ring), max_steps=1000)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_api_test(env, num_cycles=1000)
    _, infos = env.reset(seed=3)
    rng = np.random.default_rng(0)
    done = False
    while not done:
        acts = {a: int(rng.choice(np.flatnonzero(infos[a]["action_mask"]))) for a in env.agents}
        _, _, term, trunc, infos = env.step(acts)
        done = all(term.values()) or all(trunc.values())
    assert all(term.values()) and not any(trunc.values()) and env.agents == []
    assert env.metrics()["episodes_completed"] == 2


def test_aec_api():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        api_test(parallel_to_aec(paper_env(max_steps=300, render_mode="ansi")), num_cycles=1000)


@pytest.mark.parametrize("teammates", [None, "conscientious"])
def test_gymnasium_check_env(teammates):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        kw = {"agents": 4} if teammates else {}
        env = gymnasium.make(
            "qpatrol/Patrol-v0", config="paper", teammates=teammates, max_steps=200, **kw
        )
        check_env(env.unwrapped)  # also renders every mode, through the registered spec
        obs, info = env.reset(seed=0)
        for _ in range(250):
            obs, r, term, trunc, info = env.step(env.action_space.sample(info["action_mask"]))
            if term or trunc:
                break
        assert trunc and not term and info["t"] == 200
        env.close()


def test_spaces_are_stable_and_observation_layout():
    env = paper_env(idleness_map=True)
    a = "agent_1"
    assert env.observation_space(a) is env.observation_space(a)
    assert env.action_space(a) is env.action_space(a)
    obs, infos = env.reset(seed=5)
    c = env.params.n_cells
    assert obs[a].shape == (len(FEATURES) + c,) and obs[a].dtype == np.float32
    s = env.world_state
    k = 1
    assert obs[a][0] == s.pos[0, k] and obs[a][3] == s.head[0, k] and obs[a][4] == s.charge[0, k]
    walls = env.params.neighbors[s.pos[0, k]] < 0
    assert (obs[a][6:14:2][walls] == -1).all() and (obs[a][7:14:2][walls] == -1).all()
    assert infos[a]["action_mask"].dtype == np.int8


def test_determinism_1000_steps():
    def play(seed):
        env = paper_env(max_steps=1000)
        obs, infos = env.reset(seed=seed)
        rng = np.random.default_rng(7)  # the same actions for both plays
        trace = [({"u": env.uniforms.copy()}, obs, infos)]
        for _ in range(1000):
            acts = {a: int(rng.integers(4)) for a in env.agents}
            u = {"u": env.uniforms.copy()} if env.agents else {}
            trace.append((u, *env.step(acts)))
        return trace, env.metrics()

    (a, ma), (b, mb) = play(11), play(11)
    assert ma == mb
    for x, y in zip(a, b, strict=True):
        for dx, dy in zip(x, y, strict=True):
            assert dx.keys() == dy.keys()
            for key in dx:
                if isinstance(dx[key], dict):
                    for f in dx[key]:
                        assert np.array_equal(dx[key][f], dy[key][f])
                else:
                    assert np.array_equal(dx[key], dy[key])
    # on map_a every robot starts on a digit, so a seed changes only the uniforms
    c, _ = play(12)
    assert not np.array_equal(a[0][0]["u"], c[0][0]["u"])


def test_reset_without_seed_walks_through_the_runs():
    env = paper_env(max_steps=10)
    env.reset(seed=4)
    assert (env.sim.seed, env.sim.run) == (4, 0)
    env.reset()
    assert (env.sim.seed, env.sim.run) == (4, 1)
    env.reset(options={"run": 7})
    assert (env.sim.seed, env.sim.run) == (4, 7)


STEPS = 400


@pytest.fixture(scope="module")
def train_run():
    cfg = load_config("paper", ["runs=1", f"steps={STEPS}", f"record.trajectory={STEPS}"])
    assert cfg["battery.enabled"] and cfg["agents"] == 4
    return cfg, run.simulate(cfg)


def test_qlearning_through_the_env_reproduces_train(train_run):
    cfg, res = train_run
    env = PatrolParallelEnv(cfg)
    obs, infos = env.reset(seed=cfg["seed"])  # run 0 of train
    learner = strategies.make("qlearning", cfg, env.map, env.params, env.world_state.pos.copy())
    cells, world_moved = [], 0
    while env.agents:
        wo = env.world_observation
        choice = learner.act(wo, env.uniforms[None])[0]
        for k, a in enumerate(env.agents):
            assert infos[a]["choosing"] == wo.choosing[0, k]
            if infos[a]["choosing"]:  # the strategy picks inside the env's action mask
                assert infos[a]["action_mask"][choice[k]] == 1
            else:
                world_moved += 1
                assert not infos[a]["action_mask"].any()
        # robots the world moves get a junk action: the env must ignore it
        acts = {a: int(choice[k]) if infos[a]["choosing"] else 3 for k, a in enumerate(env.agents)}
        obs, rewards, term, trunc, infos = env.step(acts)
        learner.learn(env.last_outcome)
        cells.append([int(obs[a][0]) for a in env.possible_agents])
    assert world_moved > 0  # the battery took over some robots in these steps
    assert all(trunc.values()) and not any(term.values())
    want = res.trajectory.pivot(index="step", columns="agent", values="cell").to_numpy()
    assert np.array_equal(np.array(cells), want)
    assert np.array_equal(learner.q, res.strategy.q) and np.array_equal(learner.n, res.strategy.n)
    assert env.metrics() == res.summary[0]


def test_metrics_match_simulate_for_a_baseline_team():
    """Teammates driven by a strategy inside PatrolEnv: the run is train's run 2."""
    cfg = load_config("paper", ["runs=3", "steps=300", "policy=conscientious", "seed=9"])
    res = run.simulate(cfg)
    env = PatrolEnv(cfg, teammates="conscientious", agent=2)
    env.reset(seed=9, options={"run": 2})
    mirror = strategies.make("conscientious", cfg, env.map, env.params, env.world_state.pos.copy())
    done = False
    while not done:
        action = mirror.act(env.world_observation, env.uniforms[None])[0, 2]
        _, _, term, trunc, _ = env.step(int(max(action, 0)))
        mirror.learn(env.last_outcome)
        done = term or trunc
    assert env.metrics() == res.summary[2]
    assert np.array_equal(env.world_state.pos, res.state.pos[2:3])


def test_render_modes():
    env = paper_env(render_mode="rgb_array")
    env.reset(seed=0)
    img = env.render()
    rows, cols = env.map.free.shape
    assert img.shape == (rows * 8, cols * 8, 3) and img.dtype == np.uint8
    text = paper_env(render_mode="ansi")
    text.reset(seed=0)
    grid = text.render().splitlines()
    assert grid[:rows] and all(len(line) == cols for line in grid[:rows])
    assert "0" in "".join(grid[:rows]) and "H" in "".join(grid[:rows])


@pytest.mark.parametrize(
    ("make", "error", "words"),
    [
        (lambda: PatrolParallelEnv(42), TypeError, "config"),
        (lambda: PatrolParallelEnv("paper", ["learning.gamma=7"]), ConfigError, "gamma"),
        (lambda: PatrolParallelEnv("paper", "agents=2"), TypeError, "overrides"),
        (lambda: PatrolParallelEnv(map="no_such_map"), ValueError, "no_such_map"),
        (lambda: PatrolParallelEnv(agents="four"), TypeError, "agents"),
        (lambda: PatrolParallelEnv(max_steps=0), ValueError, "max_steps"),
        (lambda: PatrolParallelEnv(render_mode="human"), ValueError, "render_mode"),
        (lambda: PatrolEnv(teammates="nobody", agents=2), ValueError, "teammates"),
        (lambda: PatrolEnv(agents=3), ValueError, "teammates"),
        (lambda: PatrolEnv(agents=2, teammates="random", agent=2), ValueError, "agent"),
    ],
)
def test_bad_constructor_arguments(make, error, words):
    with pytest.raises(error, match=words):
        make()


def test_bad_actions_and_order():
    env = paper_env(max_steps=5)
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="0..3"):
        env.step({"agent_0": 4})
    with pytest.raises(ValueError, match="unknown agent"):
        env.step({"robot_9": 0})


def test_example_runs():
    path = ROOT / "examples" / "pettingzoo_qlearning.py"
    spec = importlib.util.spec_from_file_location("pettingzoo_qlearning", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    m = module.main(steps=300, seed=1)
    assert m["steps"] == 300 and m["avg_idleness"] > 0


def test_core_does_not_import_the_rl_libraries():
    """The base install works without pettingzoo/gymnasium: only qpatrol.envs imports them."""
    code = (
        "import sys, qpatrol.run, qpatrol.cli, qpatrol.study.sweep, qpatrol.study.reproduce\n"
        "bad = [m for m in ('pettingzoo', 'gymnasium') if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)
