"""The numpy engine's fast steps write the general step's files to the bit.

Every config runs twice on the numpy engine, with the fast steps
(:mod:`qpatrol.engines.numpy_solo`, :mod:`qpatrol.engines.numpy_team`) and without
(:data:`qpatrol.engines.numpy_loop.FAST` off: :func:`qpatrol.run.advance` on every
step), and every file of the run folder is compared byte for byte. The configs are
chosen so that the fast steps run (checked) and also hand steps to the general step
(episode quotas, robots that cannot move, collisions).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from qpatrol.config import from_flat
from qpatrol.engines import numpy_loop
from qpatrol.run import simulate, write_run

META = {"started": "-", "ended": "-"}


def same_folders(a: Path, b: Path, context: object) -> None:
    """Every file of run folders ``a`` (fast steps) and ``b`` (general step only) is the
    same byte for byte; in ``meta.json`` but the step that ran (``engine.loop``)."""
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for name in names:
        if name == "meta.json":
            ma, mb = (json.loads((f / name).read_text()) for f in (a, b))
            assert ma["engine"]["loop"] in ("fast-solo", "fast-team"), ma["engine"]
            assert mb["engine"]["loop"] == "general"
            ma["engine"].pop("loop"), mb["engine"].pop("loop")
            assert ma == mb, context
        else:
            assert (a / name).read_bytes() == (b / name).read_bytes(), (context, name)


def both_ways(
    flat: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, decline: int = 0
) -> tuple[str, int]:
    """Run ``flat`` with and without the fast steps and compare every file; ``(kind,
    steps)``: the fast step's class and how many team steps it took (of all runs).
    ``decline``: the fast step also declines every ``decline``-th step it is offered,
    which the general step then takes (0: only those it does not cover)."""
    cfg = from_flat({"engine": "numpy", **flat})
    made = []
    real = numpy_loop.fast_step

    def spy(*args, **kwargs):
        fast = real(*args, **kwargs)
        made.append(fast)
        if fast is not None and decline:
            offered = [0]
            step = fast.step

            def sometimes(*a):
                offered[0] += 1
                return offered[0] % decline != 0 and step(*a)

            fast.step = sometimes
        return fast

    monkeypatch.setattr(numpy_loop, "fast_step", spy)
    folders = {}
    for fast in (True, False):
        monkeypatch.setattr(numpy_loop, "FAST", fast)
        folders[fast] = write_run(simulate(cfg), tmp_path / str(fast), replace=True, meta=META)
    same_folders(folders[True], folders[False], flat)
    assert made[-1] is None  # the second run had no fast step
    return type(made[0]).__name__, made[0].taken


BASE = {
    "runs": 3,
    "seed": 5,
    "steps": 300,
    "max_episode_steps": 60,
    "battery.enabled": False,
    "reward.lambda": 0.3,
}


@pytest.mark.parametrize(
    "extra",
    [
        {},
        {"record.trajectory": 7, "record.warmup": 40},
        {"learning.epsilon": 0.3, "learning.state_space": "cell"},
        {"team.avoid_collisions": False, "episodes": 3, "max_episode_steps": None},
        {"learning.gamma": 0.9, "learning.multiplier": 100.0, "reward.lambda": 0.3},
    ],
)
def test_solo(rooms_map, tmp_path, monkeypatch, extra):
    flat = {**BASE, "map": str(rooms_map), "agents": 1, **extra}
    kind, taken = both_ways(flat, tmp_path, monkeypatch)
    assert kind == "Solo" and taken > 100


def test_solo_episodes_of_different_lengths(ring_map, tmp_path, monkeypatch):
    """Runs whose episodes end at different steps (the ring's dots all eaten, or 12
    steps up), so their episodes start at different steps: the fast step checks the
    step limit against the earliest start of all runs, kept between steps."""
    flat = {**BASE, "map": str(ring_map), "agents": 1, "runs": 6, "max_episode_steps": 12}
    kind, taken = both_ways(flat, tmp_path, monkeypatch)
    assert kind == "Solo" and taken > 250


def test_solo_leaves_a_map_without_moves_to_the_general_step(tmp_path, monkeypatch):
    """A one-cell map (collision avoidance off, else it is refused): its robot has no
    move, which the lone fast step (walls at -inf, no check) must not take; the team
    step, which checks, is offered it and declines every step."""
    one = tmp_path / "one.txt"
    one.write_text("; name: one\n#0#\n")
    flat = {**BASE, "map": str(one), "agents": 1, "team.avoid_collisions": False}
    assert both_ways(flat, tmp_path, monkeypatch) == ("Team", 0)


@pytest.mark.parametrize("agents", [1, 2, 4, 8])
@pytest.mark.parametrize("communication", [True, False])
@pytest.mark.parametrize("avoid", [True, False])
def test_team(rooms_map, tmp_path, monkeypatch, agents, communication, avoid):
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": agents,
        "team.communication": communication,
        "team.avoid_collisions": avoid,
        "record.trajectory": 5,
    }
    kind, taken = both_ways(flat, tmp_path, monkeypatch)
    print(kind, taken)
    assert kind == ("Solo" if agents == 1 else "Team") and taken > 100


@pytest.mark.parametrize("agents", [2, 3, 4, 8])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_team_moves_match_traffic(rooms_map, agents, seed):
    """Crowded random states: the team step's moves and token passing are
    traffic.resolve's and traffic.pass_token's (robots pushed, cells several robots ask
    for, chains and cycles of robots in the way)."""
    from qpatrol import traffic, world
    from qpatrol.engines.numpy_team import Team
    from qpatrol.measures import Measures
    from qpatrol.run import prepare
    from qpatrol.strategies import make

    cfg = from_flat({**BASE, "map": str(rooms_map), "agents": agents, "runs": 300})
    m, p = prepare(cfg)
    rng = np.random.default_rng(seed)
    starts = np.stack([rng.permutation(p.n_cells)[:agents] for _ in range(cfg["runs"])])
    states = [world.init_state(p, starts) for _ in range(2)]
    for s in states:
        s.t = 7
        s.wait = rng.integers(0, 3, starts.shape) if s is states[0] else states[0].wait.copy()
        s.token = rng.integers(-1, agents, cfg["runs"]) if s is states[0] else states[0].token
        s.token_held = rng.integers(0, 3, cfg["runs"]) if s is states[0] else states[0].token_held
    nb = p.neighbors[starts]  # [R, K, 4]
    pick = rng.random(nb.shape)
    pick[nb < 0] = -1
    want = np.take_along_axis(nb, pick.argmax(axis=2)[..., None], axis=2)[..., 0]
    a, b = states
    res_a = traffic.resolve(a, p, want)
    team = Team(p, b, make("qlearning", cfg, m, p, starts), Measures(300, agents, p.n_cells, 0))
    res_b = team._resolve(want)
    for name in ("moved", "as_asked", "push_failed"):
        assert np.array_equal(getattr(res_a, name), getattr(res_b, name)), name
    assert np.array_equal(a.pos, b.pos) and np.array_equal(a.occ, b.occ)
    assert res_a.moved.any() and not res_a.moved.all()
    for s, res in ((a, res_a), (b, res_b)):
        s.wait = np.where(res.as_asked, 0, s.wait + 1)
    blocked_by = np.where(~res_a.as_asked, a.occ[np.arange(300)[:, None], want], -1)
    traffic.pass_token(a, p, want, res_a, blocked_by)
    team._pass_token(res_b, blocked_by)
    assert np.array_equal(a.token, b.token) and np.array_equal(a.token_held, b.token_held)


@pytest.mark.parametrize("agents", [1, 3])
@pytest.mark.parametrize("decline", [2, 7])
def test_fast_and_general_steps_alternate(rooms_map, tmp_path, monkeypatch, agents, decline):
    """The fast step hands every few steps to the general step and takes over again: the
    deferred arrays are brought up to date, the kept Q rows dropped (warm-up, episodes,
    recorders and the timeline across the hand-overs)."""
    flat = {
        **BASE,
        "map": str(rooms_map),
        "agents": agents,
        "record.warmup": 25,
        "record.trajectory": 4,
        "record.timeline": 40 if agents > 1 else 0,
        "learning.epsilon": 0.1,
    }
    kind, taken = both_ways(flat, tmp_path, monkeypatch, decline)
    assert 0 < taken < BASE["steps"]


@pytest.mark.parametrize(
    "record",
    [
        {"record.transitions": True, "record.watch": [5, 9], "record.timeline": 30},
        {"record.watch": [3, 4, 17], "learning.state_space": "cell", "record.warmup": 50},
    ],
)
@pytest.mark.parametrize("agents", [1, 4])
def test_team_recorders(rooms_map, tmp_path, monkeypatch, record, agents):
    """Transitions, watched states and the timeline: the team step records them (also for
    a lone robot, which the lone-learner step leaves to it)."""
    flat = {**BASE, "map": str(rooms_map), "agents": agents, **record}
    kind, taken = both_ways(flat, tmp_path, monkeypatch)
    assert kind == "Team" and taken == BASE["steps"]


@pytest.mark.parametrize("agents", [1, 3])
def test_checkpoint_resume_with_fast_steps(rooms_map, tmp_path, monkeypatch, agents):
    """With a checkpointer the fast step defers its writes too, and the checkpointer
    brings them up to date before it saves (``before_save``): a run stopped at a
    checkpoint and resumed (a new fast step, no kept rows) writes the files of a run on
    the general step only; an episode quota ends runs on the way (the general step
    takes over)."""
    from qpatrol import checkpoint as ck

    flat = {**BASE, "map": str(rooms_map), "agents": agents, "episodes": 4, "record.warmup": 30}
    cfg = from_flat({"engine": "numpy", **flat})

    class StopAt(ck.Checkpointer):
        every_step = True  # stops at an exact step

        def tick(self, position, payload):
            if position == 123:
                self.request_stop()
            super().tick(position, payload)

    with pytest.raises(ck.Interrupted):
        simulate(cfg, checkpoint=StopAt(tmp_path / "cp", every=0))
    resumed = ck.Checkpointer(tmp_path / "cp", every=0)
    assert resumed.load().position == 123
    a = write_run(simulate(cfg, checkpoint=resumed), tmp_path / "resumed", meta=META)
    monkeypatch.setattr(numpy_loop, "FAST", False)
    b = write_run(simulate(cfg), tmp_path / "general", meta=META)
    same_folders(a, b, flat)


def test_flat_blocks_match_learner():
    """The fast steps' 4-column max and tie-break give learner's results to the bit:
    signed zeros and -inf in the max, every candidate mask, uniforms up to 1 - 2**-53."""
    import itertools

    from qpatrol import learner
    from qpatrol.engines import flat

    rows = np.array(list(itertools.product([-0.0, 0.0, -np.inf, 1.0, -1.0], repeat=4)))
    got, want = flat.max4(rows), rows.max(axis=1)
    assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))
    cand = np.array(list(itertools.product([False, True], repeat=4)) * 7)
    u = np.concatenate([np.linspace(0.0, 1.0, cand.shape[0], endpoint=False)])
    u[-16:] = np.nextafter(1.0, 0.0)
    action, count = flat.pick(np.ascontiguousarray(cand), u)
    expected, has = learner.pick(cand, u)
    assert np.array_equal(action, expected) and np.array_equal(count > 0, has)
    some = has  # pick_among: rows with a candidate only (the lone step's)
    got = flat.pick_among(np.ascontiguousarray(cand[some]), u[some])
    assert np.array_equal(got, expected[some])


@pytest.mark.parametrize("agents", [2, 3, 4, 8])
def test_team_token_passing_matches_traffic(rooms_map, agents):
    """Random outcomes of a step (failed pushes, blocked robots, waits): the team step
    passes the token as traffic.pass_token does."""
    from qpatrol import traffic, world
    from qpatrol.engines.numpy_team import Team
    from qpatrol.measures import Measures
    from qpatrol.run import prepare
    from qpatrol.strategies import make

    runs = 2000
    cfg = from_flat({**BASE, "map": str(rooms_map), "agents": agents, "runs": runs})
    m, p = prepare(cfg)
    rng = np.random.default_rng(agents)
    starts = np.stack([rng.permutation(p.n_cells)[:agents] for _ in range(runs)])
    a, b = (world.init_state(p, starts) for _ in range(2))
    token = rng.integers(-1, agents, runs)
    held = rng.integers(0, p.diameter + 2, runs)
    wait = rng.integers(0, 3, starts.shape)
    for s in (a, b):
        s.t, s.token, s.token_held, s.wait = 11, token.copy(), held.copy(), wait.copy()
    as_asked = rng.random(starts.shape) < 0.6
    res = traffic.Resolution(
        ~as_asked | as_asked, as_asked, (token >= 0) & (rng.random(runs) < 0.5)
    )
    blocked_by = np.where(as_asked, -1, rng.integers(-1, agents, starts.shape))
    want = rng.integers(0, p.n_cells, starts.shape)
    traffic.pass_token(a, p, want, res, blocked_by)
    team = Team(p, b, make("qlearning", cfg, m, p, starts), Measures(runs, agents, p.n_cells, 0))
    team._pass_token(res, blocked_by)
    assert np.array_equal(a.token, b.token) and np.array_equal(a.token_held, b.token_held)
