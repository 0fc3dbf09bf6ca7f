"""The batched env: driven by a strategy it writes ``train``'s files on both engines; its
kernel calls run_block's phases in run_block's order; masks, rewards and autoreset as
documented; the features against hand values on a small graph."""

from __future__ import annotations

import ast
import inspect
import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gymnasium")

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from qpatrol import run, strategies, world  # noqa: E402
from qpatrol.config import from_flat  # noqa: E402
from qpatrol.envs import PatrolGymVectorEnv, PatrolParallelEnv, PatrolVectorEnv  # noqa: E402
from qpatrol.maps import get_map  # noqa: E402
from qpatrol.strategies import features  # noqa: E402

HAS_NUMBA = pytest.importorskip is not None and __import__("importlib").util.find_spec("numba")
ENGINES = ["numpy", pytest.param("numba", marks=pytest.mark.skipif(not HAS_NUMBA, reason="numba"))]
#: one worker runs this file: the env's kernel is loaded from numba's cache once
pytestmark = pytest.mark.xdist_group("vector_env")

SQUARE = """\
; name: square
; kind: graph
v 0 0 0 start=0
v 1 2 0 start=1
v 2 0 2
v 3 2 2
e 0 1 2
e 1 3 1
e 0 2 1
e 2 3 3
"""

#: Configs driven by conscientious's choices through the env (patrol graphs with
#: waypoints: robots decide at vertices), covering the interaction models, the battery,
#: failures, an episode quota with communication off, and the recorders.
DRIVEN = [
    {"map": "ps_cumberland", "agents": 6, "runs": 3, "steps": 300,
     "team.interaction": "interference", "failures.robots": 2, "failures.at": 120},
    {"map": "ps_example", "agents": 4, "runs": 3, "steps": 400, "team.interaction": "exclusive",
     "battery.enabled": True, "battery.capacity": 400, "record.trajectory": 30,
     "record.timeline": 100},
    {"map": "ps_grid", "agents": 3, "runs": 2, "steps": 300, "team.interaction": "none",
     "team.communication": False, "episodes": 2},
]  # fmt: skip


def drive(
    flat: dict, engine: str, policy: str = "conscientious", threads: int = 1
) -> run.RunResult:
    """``flat``'s runs moved through the env by ``policy``'s choices (fed the env's
    observation and uniforms, learning from its outcomes); the batch's result."""
    over = [f"{k}={json.dumps(v) if isinstance(v, bool) else v}" for k, v in flat.items()]
    kw = {"num_envs": flat["runs"], "engine": engine, "autoreset": False, "threads": threads}
    env = PatrolVectorEnv(None, [*over, f"policy={policy}"], **kw)
    b = env.batch
    env.reset(seed=int(b.cfg["seed"]))
    team = strategies.make(policy, b.cfg, b.map, b.params, b.starts)
    while not b.done_all:
        env.step(team.act(env.world_observation, env.uniforms))
        team.learn(env.last_outcome)
    return env.result(team)


def folder_bytes(path: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in path.iterdir() if p.name not in ("meta.json",)}


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("flat", DRIVEN, ids=lambda f: f["map"])
def test_driven_by_conscientious_it_writes_trains_files(tmp_path, flat, engine):
    cfg = from_flat({**flat, "policy": "conscientious", "engine": engine})
    ref = run.write_run(run.simulate(cfg), tmp_path / "train", meta={})
    got = run.write_run(drive(flat, engine), tmp_path / "env", meta={})
    a, b = folder_bytes(ref), folder_bytes(got)
    assert sorted(a) == sorted(b)
    for name in a:
        assert a[name] == b[name], name
    if "episodes" in flat:  # the quota ended runs early: they sat out, as in train
        steps = [r["steps"] for r in json.loads(a["summary.json"])["runs"]]
        assert min(steps) < flat["steps"]


@pytest.mark.skipif(not HAS_NUMBA, reason="numba")
def test_lanes_of_runs_in_threads_give_the_same_files(tmp_path):
    """Two lanes of runs, each stepped by its own thread, write one lane's files."""
    flat = {"map": "ps_example", "agents": 4, "runs": 16, "steps": 150}
    env = PatrolVectorEnv(None, ["map=ps_example", "agents=4"], num_envs=16, threads=2)
    env.reset(seed=0)
    assert len(env.batch.lanes) == 2
    one = run.write_run(drive(flat, "numba"), tmp_path / "one", meta={})
    two = run.write_run(drive(flat, "numba", threads=2), tmp_path / "two", meta={})
    assert folder_bytes(one) == folder_bytes(two)


def test_pettingzoo_dicts_and_graph_observations():
    """Actions as PettingZoo's ``{agent: [B]}`` are the array's; ``observation="graph"``
    gives the graph features, with the map's edges."""
    over = ["map=ps_example", "agents=3"]
    a = PatrolVectorEnv(None, over, num_envs=2, max_steps=20, engine="numpy")
    b = PatrolVectorEnv(None, over, num_envs=2, max_steps=20, engine="numpy", observation="graph")
    _, ia = a.reset(seed=1)
    ob, _ = b.reset(seed=1)
    n = a.tables.targets.size
    assert ob.shape == (2, 3, n, len(features.NODE)) and b.edge_index.shape[0] == 2
    for _ in range(20):
        acts = ia["action_mask"].argmax(-1)
        oa, ra, _, _, ia = a.step(a.agent_dict(acts))
        ob, rb, _, _, _ = b.step(acts)
        assert (ra == rb).all()
        assert (a.graph()[0] == ob).all() or a.batch.t == 0  # (after autoreset: new runs)


def calls(fn) -> list[str]:
    """The phase calls of a function's body (``module.function`` of the compiled phase
    modules), in order."""
    phases = {"stations", "moves", "enter", "episodes", "fail", "observe", "pcg"}
    tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            base = node.func.value
            if isinstance(base, ast.Name) and base.id in phases:
                out.append((node.lineno, f"{base.id}.{node.func.attr}"))
    return [name for _, name in sorted(out)]


def test_the_kernel_calls_run_blocks_phases_in_its_order():
    """A phase added to (or moved in) the compiled loop's general step must be added to
    the env's kernel too: the kernel's calls are the loop's, from the first draw of a
    step to its measures (the kernel begins a step after finishing the last: its
    beginning comes last in the source, run_block's first)."""
    pytest.importorskip("numba")
    from qpatrol.engines import numba_core, vector

    # the calls of a step (a run's setup and stores around its steps left out)
    setup = {"pcg.double_inc", "episodes.deadline", "observe.sums_of", "observe.rows_of"}
    setup |= {"observe.store_sums", "pcg.store"}
    # a walk follower's turn on an edge (its plan read on waypoints): an env's policy
    # chooses at vertices only, as the numpy env's world.step without ``turns``
    block_only = {"moves.turn_round"}
    block = [c for c in calls(numba_core.run_block.py_func) if c not in setup | block_only]
    block = block[block.index("pcg.step_uniforms") :]
    kernel = [c for c in calls(vector.step_batch.py_func) if c not in setup]
    begin_at = kernel.index("pcg.step_uniforms")
    assert kernel[begin_at:] + kernel[:begin_at] == block


def test_masks_and_rewards_are_the_single_run_envs(tmp_path):
    """Run 0 of a batch on the numpy engine sees the masks and gets the rewards of the
    PettingZoo env on the same run, robot by robot, under random valid actions."""
    over = ["battery.enabled=on", "agents=4", "map=map_a"]
    vec = PatrolVectorEnv("paper", over, num_envs=2, max_steps=120, engine="numpy")
    one = PatrolParallelEnv("paper", over, max_steps=120)
    _, vi = vec.reset(seed=5)
    _, oi = one.reset(seed=5)
    rng = np.random.default_rng(1)
    for _ in range(119):
        mask = vi["action_mask"]
        for k, a in enumerate(one.possible_agents):
            assert (mask[0, k] == oi[a]["action_mask"]).all()
        acts = (rng.random(mask.shape) * mask).argmax(-1)
        _, rv, _, _, vi = vec.step(acts)
        _, ro, _, _, oi = one.step({a: int(acts[0, k]) for k, a in enumerate(one.agents)})
        assert [rv[0, k] for k in range(4)] == pytest.approx([ro[a] for a in one.agents])


@pytest.mark.parametrize("engine", ENGINES)
def test_autoreset_starts_the_next_runs_in_the_same_step(engine):
    kw = {"num_envs": 3, "max_steps": 25, "engine": engine}
    env = PatrolVectorEnv(None, ["map=ps_grid", "agents=2"], **kw)
    obs, infos = env.reset(seed=7)
    first = env.uniforms.copy()
    for i in range(25):
        mask = infos["action_mask"]
        obs, rew, term, trunc, infos = env.step(mask.argmax(-1))
        assert trunc.all() == (i == 24) and not term.any()
    assert set(infos["final_metrics"]) >= {"avg_idleness", "worst_idleness"}
    assert env.last_result.run_ids.tolist() == [0, 1, 2]
    assert env.batch.first_run == 3 and env.batch.t == 0
    fresh = PatrolVectorEnv(None, ["map=ps_grid", "agents=2"], **kw)
    again, _ = fresh.reset(seed=7, options={"run": 3})
    assert (obs == again).all() and (env.uniforms == fresh.uniforms).all()
    assert not (env.uniforms == first).all()


def test_gymnasium_vector_api():
    env = PatrolGymVectorEnv(None, ["map=ps_example", "agents=3"], runs=4, max_steps=10)
    obs, infos = env.reset(seed=0)
    assert env.num_envs == 12 and obs.shape == (12, *env.single_observation_space.shape)
    assert infos["action_mask"].shape == (12, 4)
    assert obs in env.observation_space
    for _ in range(10):
        obs, rew, term, trunc, infos = env.step(env.action_space.sample())
        assert rew.shape == term.shape == trunc.shape == (12,)
    assert trunc.all() and "final_obs" in infos


# --- features --------------------------------------------------------------------------
def square_world(tmp_path: Path, communication: bool = True):
    path = tmp_path / "square.txt"
    path.write_text(SQUARE)
    flat = {"map": str(path), "agents": 3, "team.communication": communication}
    cfg = from_flat({**flat, "battery.enabled": False})
    m = get_map(str(path))
    p = world.make_params(cfg, m)
    s = world.init_state(p, np.array([[0, 5, 1]]))
    s.t = 20
    g = 0 if communication else slice(None)
    s.last[0, g, :4] = [18, 5, 12, 0]  # idleness of vertices 0..3: 2, 15, 8, 20
    s.head[0] = [1, 0, 0]  # robot 1 on waypoint 5 came from vertex 2: bound for 3
    return m, p, s


def test_port_and_graph_features_by_hand(tmp_path):
    m, p, s = square_world(tmp_path)
    tab = features.Tables(m, p)
    obs = world.Observation(1, s, p, None, None, None)
    x = features.ports(obs, tab)[0, 0]  # robot 0 on vertex 0, came by port 1
    # port 0: the way of 2 moves to vertex 1 (idle 15 of at most 20, mean 11.25);
    # robot 2 stands there (bound for it, and 0 moves from it); beyond it vertex 3 (20)
    assert x[:, 0] == pytest.approx([1, 15 / 20, 2 / 3, 0, 1, 1, 20 / 20, 15 / 12.25])
    # port 1: the way back (1 move) to vertex 2 (idle 8); robot 1 is 1 move from it, not
    # fewer; beyond it vertex 3
    assert x[:, 1] == pytest.approx([1, 8 / 20, 1 / 3, 1, 0, 0, 20 / 20, 8 / 12.25])
    nodes = features.nodes(obs, tab)[0, 0]
    assert nodes.T == pytest.approx(
        np.array(
            [
                [2 / 20, 15 / 20, 8 / 20, 1],  # idleness
                [0, 2 / 3, 1 / 3, 1],  # moves from robot 0 / diameter 3
                [1, 0, 0, 0],  # robot 0 stands on vertex 0
                [0, 1, 0, 0],  # robot 2 on vertex 1 (robot 1 is on a waypoint)
                [0, 0, 0, 1],  # robot 1 bound for vertex 3
                [2 / 12.25, 15 / 12.25, 8 / 12.25, 20 / 12.25],
            ]
        )
    )
    index, attr = tab.graph_edges()
    moves = (attr[:, 0] * 3).round(6).tolist()
    pairs = sorted(zip(index[0].tolist(), index[1].tolist(), moves, strict=True))
    assert pairs == [
        (0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 3, 1), (2, 0, 1), (2, 3, 3), (3, 1, 1), (3, 2, 3),
    ]  # fmt: skip
    # a robot that failed is seen by no one: robot 2 no longer claims vertex 1
    s.mode[0, 2] = world.GONE
    x = features.ports(obs, tab)[0, 0]
    assert x[4, 0] == 0 and x[5, 0] == 0
    assert features.nodes(obs, tab)[0, 0, 1, 3] == 0


def test_without_communication_robots_see_their_own_maps_and_no_one(tmp_path):
    m, p, s = square_world(tmp_path, communication=False)
    s.last[0, 1, :4] = 20  # robot 1's own map: every vertex just visited
    obs = world.Observation(1, s, p, None, None, None)
    tab = features.Tables(m, p)
    x = features.ports(obs, tab)
    assert x[0, 0, :, 0] == pytest.approx([1, 15 / 20, 2 / 3, 0, 0, 0, 1, 15 / 12.25])
    assert (x[0, 1, 1] == 0).all()  # robot 1: idleness 0 everywhere
    assert (features.nodes(obs, tab)[..., 3:5] == 0).all()


@given(st.integers(0, 2**32 - 1), st.sampled_from(["ps_cumberland", "map_b"]), st.booleans())
def test_compiled_features_are_the_python_ones(seed, name, communication):
    """The features' loops give the same numbers compiled (numba) and as plain Python."""
    fill_ports = getattr(features._fill_ports, "py_func", None)
    if fill_ports is None:
        pytest.skip("numba not installed: only the Python loops run")
    cfg = from_flat({"map": name, "agents": 5, "team.communication": communication})
    m = get_map(name)
    p = world.make_params(cfg, m)
    rng = np.random.default_rng(seed)
    starts = np.stack([rng.choice(m.n_cells, 5, replace=False) for _ in range(2)])
    s = world.init_state(p, starts)
    s.t = int(rng.integers(1, 500))
    s.last[:] = rng.integers(0, s.t + 1, s.last.shape)
    s.head[:] = rng.integers(0, m.n_ports, s.head.shape)
    s.mode[:] = np.where(rng.random(s.mode.shape) < 0.2, world.GONE, 0)
    tab = features.Tables(m, p)
    obs = world.Observation(1, s, p, None, None, None)
    want = features.ports(obs, tab)
    got = np.empty_like(want)
    tab_i = (tab.far, tab.ahead, tab.targets)
    args = (s.t, s.pos, s.head, s.mode, s.last, tab.communication, tab_i)
    fill_ports(*args, tab.length, tab.max_len, tab.grid, tab.dist, got)
    assert (got == want).all()
    want_n = features.nodes(obs, tab)
    got_n = np.empty_like(want_n)
    nargs = (s.t, s.pos, s.head, s.mode, s.last, tab.communication, tab.ahead, tab.targets)
    features._fill_nodes.py_func(*nargs, tab.dist, tab.diameter, got_n)
    assert (got_n == want_n).all()
