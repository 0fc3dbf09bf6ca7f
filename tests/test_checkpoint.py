"""Checkpoints: the mechanics, and train killed (SIGKILL) or interrupted (SIGINT) halfway
then resumed gives byte-identical files (meta.json aside: it holds times)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from qpatrol import cli
from qpatrol.config import POLICIES, from_mapping
from qpatrol.run import checkpoint as ck
from qpatrol.run import simulate

#: on one worker under pytest-xdist: the module fixtures are built once
pytestmark = pytest.mark.xdist_group("checkpoint")

CONFIG = {
    "map": "map_b",
    "agents": 4,
    "runs": 2,
    "seed": 11,
    "steps": 2000,
    "battery": {"capacity": 120, "charge_steps": 5},
    "record": {"transitions": True, "watch": [34], "trajectory": 50, "warmup": 100},
}


def main(*args: object) -> int:
    try:
        cli.main([str(a) for a in args])
    except SystemExit as e:
        return int(e.code or 0)
    return 0


# --------------------------------------------------------------------- mechanics


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_save_load_and_when(tmp_path: Path):
    ck.save({"a": np.arange(3)}, tmp_path / "x.sha256")
    assert ck.load(tmp_path / "x.sha256")["a"].tolist() == [0, 1, 2]
    clock = Clock()
    cp = ck.Checkpointer(tmp_path / "cp", every=10, key={"config": "abc"}, clock=clock)
    cp.tick(1, "state-1")
    assert not cp.exists()  # not due yet
    clock.t = 10.5
    cp.tick(2, "state-2")
    assert cp.exists() and cp.saves == 1
    info = json.loads((tmp_path / "cp" / ck.INFO_FILE).read_text())
    assert info["position"] == 2
    cp.request_stop(signal.SIGTERM)
    with pytest.raises(ck.Interrupted) as e:
        cp.tick(3, "state-3")
    assert e.value.position == 3 and e.value.signum == signal.SIGTERM
    again = ck.Checkpointer(tmp_path / "cp", key={"config": "abc"})
    snap = again.load()
    assert (snap.position, snap.payload) == (3, "state-3") and again.position == 3
    with pytest.raises(ck.CheckpointError, match="differs in config"):
        ck.Checkpointer(tmp_path / "cp", key={"config": "xyz"}).load()
    with pytest.raises(ck.CheckpointError, match="no checkpoint"):
        ck.Checkpointer(tmp_path / "none").load()
    (tmp_path / "cp" / ck.STATE_FILE).write_bytes(b"garbage")
    with pytest.raises(ck.CheckpointError, match="unreadable"):
        again.load()
    again.discard()
    assert not (tmp_path / "cp").exists()


def test_save_load_keeps_values_layouts_sharing_and_random_states(tmp_path: Path):
    """Plain data, numpy numbers and arrays (any layout, size and kind), generators and
    seed sequences come back equal, to the bit and the layout; an object met twice is
    one object again, a list holding itself too; equal states give equal bytes."""
    shared = [1, 2]
    loop: list = ["me"]
    loop.append(loop)
    big = np.arange(3 * ck.SMALL_ARRAY // 8, dtype=np.float64).reshape(3, -1)
    gen = np.random.Generator(np.random.PCG64(np.random.SeedSequence(5, spawn_key=(1, 2))))
    gen.random(3)
    obj = {
        "plain": [None, True, 0, -(2**100), 1.5, -0.0, float("inf"), float("nan"), "é"],
        "tuple": (1, ("a", 2.5)),
        "keys": {3: "int", (1, 2): "tuple", None: "none"},
        "numbers": [np.int64(-3), np.float32(0.1), np.bool_(True), np.uint8(255)],
        "arrays": [
            np.asfortranarray(np.arange(12.0).reshape(3, 4)),
            np.arange(20)[::3],
            np.array(7, dtype=np.int32),
            np.zeros((0, 3), dtype=bool),
            np.array([1 + 2j, np.nan]),
            big,
            big.T,
        ],
        "shared": [shared, shared, big],
        "loop": loop,
        "gen": gen,
        "mt": np.random.MT19937(3),
        "seq": np.random.SeedSequence([1, 2**70]),
    }
    ck.save(obj, tmp_path / "a" / "x.sha256")
    ck.save(obj, tmp_path / "b" / "x.sha256")
    assert files(tmp_path / "a") == files(tmp_path / "b")
    back = ck.load(tmp_path / "a" / "x.sha256")
    same_tree(obj, back, {})
    assert back["shared"][0] is back["shared"][1] and back["shared"][2] is back["arrays"][5]
    assert back["loop"][1] is back["loop"]
    assert np.array_equal(back["gen"].random(5), gen.random(5))


def test_save_refuses_what_load_could_not_rebuild(tmp_path: Path):
    for bad in (object(), Path("x"), len, np.array([None]), {1, 2}, b"bytes", Clock()):
        with pytest.raises(TypeError, match="checkpoint"):
            ck.save({"x": [bad]}, tmp_path / "x.sha256")
    assert not tmp_path.joinpath("x.sha256").exists()


def test_a_save_cut_short_leaves_the_previous_checkpoint(tmp_path: Path, monkeypatch):
    """Parts are written under new names and the manifest replaced last: a save that
    dies before its manifest leaves the last checkpoint whole; the next save removes
    the parts it left."""
    from qpatrol.util import atomic

    path = tmp_path / ck.STATE_FILE
    ck.save({"step": 1, "a": np.arange(3)}, path)
    before = files(tmp_path)

    def killed(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic, "write_text", killed)
    with pytest.raises(KeyboardInterrupt):
        ck.save({"step": 2, "a": np.arange(4)}, path)
    assert len(files(tmp_path)) == len(before) + 2  # the new parts, not named
    assert ck.load(path)["step"] == 1
    monkeypatch.undo()
    ck.save({"step": 3, "a": np.arange(5)}, path)
    assert ck.load(path)["step"] == 3 and len(files(tmp_path)) == len(before)


def test_simulate_resumed_equals_uninterrupted(tmp_path: Path, stop_and_resume):
    cfg = from_mapping({**CONFIG, "steps": 700})
    whole = simulate(cfg)
    rest = stop_and_resume(cfg, tmp_path / "cp", 333)
    assert np.array_equal(rest.strategy.q, whole.strategy.q)
    assert np.array_equal(rest.strategy.n, whole.strategy.n)
    assert rest.summary == whole.summary
    assert rest.transitions.equals(whole.transitions) and rest.watch.equals(whole.watch)
    assert rest.episodes.equals(whole.episodes) and rest.trajectory.equals(whole.trajectory)


@pytest.mark.parametrize("agents", [1, 3])
def test_numpy_resumed_with_an_episode_quota_equals_uninterrupted(
    rooms_map, tmp_path, stop_and_resume, agents
):
    """On the numpy engine a run stopped at step 123 and resumed writes the files of an
    uninterrupted run, an episode quota ending runs on the way (the loop stops early
    once none is active)."""
    from qpatrol.run import write_run

    flat = {
        "map": str(rooms_map),
        "agents": agents,
        "runs": 3,
        "seed": 5,
        "steps": 300,
        "episodes": 4,
        "max_episode_steps": 60,
        "engine": "numpy",
        "battery": {"enabled": False},
        "reward": {"lambda": 0.3},
        "record": {"warmup": 30},
    }
    cfg = from_mapping(flat)
    meta = {"started": "-", "ended": "-"}
    a = write_run(stop_and_resume(cfg, tmp_path / "cp", 123), tmp_path / "resumed", meta=meta)
    b = write_run(simulate(cfg), tmp_path / "whole", meta=meta)
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


@pytest.mark.parametrize("agents", [1, 4])
def test_compiled_kernels_stop_at_any_step_and_resume_the_same(
    tmp_path, loop_specs, stop_and_resume, agents
):
    """The lone learner's and the team's loops keep a run's state in registers within
    a call and store it at its end: one step per call up to step 333, a stop there and
    a resume from the checkpoint give the tables and rows of one uninterrupted run."""
    from qpatrol.engines import numba_core

    flat = {
        **CONFIG,
        "steps": 700,
        "agents": agents,
        "engine": "numba",
        "battery": {"enabled": False},
        "record": {"trajectory": 50, "warmup": 100},
    }
    cfg = from_mapping(flat)
    whole = simulate(cfg)
    rest = stop_and_resume(cfg, tmp_path / "cp", 333)
    kernel = numba_core.SPEC_QLEARNING_SOLO if agents == 1 else numba_core.SPEC_QLEARNING_TEAM
    assert loop_specs == [kernel] * 3
    assert np.array_equal(rest.strategy.q, whole.strategy.q)
    assert np.array_equal(rest.strategy.n, whole.strategy.n)
    assert rest.summary == whole.summary
    assert rest.episodes.equals(whole.episodes) and rest.trajectory.equals(whole.trajectory)


def test_compiled_engine_ticks_after_blocks_and_resumes_the_same(tmp_path: Path):
    """On the compiled engine a stock checkpointer is ticked after each block of steps
    (not after every step, which cost ~30 us a step); a stop at the end of a block
    resumes to the uninterrupted run's files."""
    pytest.importorskip("numba")
    flat = {**CONFIG, "steps": 6000, "runs": 2, "agents": 2, "engine": "numba"}
    cfg = from_mapping(flat)
    whole = simulate(cfg)
    ticks = []

    class StopFirst(ck.Checkpointer):
        def tick(self, position, payload):
            ticks.append(position)
            if len(ticks) == 2:
                self.request_stop()
            super().tick(position, payload)

    with pytest.raises(ck.Interrupted):
        simulate(cfg, checkpoint=StopFirst(tmp_path / "cp", every=0))
    block = ticks[0]
    assert block > 1 and ticks == [block, 2 * block]  # blocks, not steps
    resumed = ck.Checkpointer(tmp_path / "cp", every=0)
    assert resumed.load().position == 2 * block
    rest = simulate(cfg, checkpoint=resumed)
    assert rest.engine == "numba"
    assert np.array_equal(rest.strategy.q, whole.strategy.q)
    assert np.array_equal(rest.strategy.n, whole.strategy.n)
    assert rest.summary == whole.summary
    assert rest.transitions.equals(whole.transitions) and rest.watch.equals(whole.watch)
    assert rest.episodes.equals(whole.episodes) and rest.trajectory.equals(whole.trajectory)


def folder(result, path: Path) -> dict[str, bytes]:
    """Every file of ``result``'s run folder (meta.json aside): name -> bytes."""
    from qpatrol.run import write_run

    out = write_run(result, path, meta={"started": "-", "ended": "-"})
    return {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.name != "meta.json"}


@pytest.mark.parametrize(
    "flat",
    [
        {"agents": 1, "runs": 130, "battery": {"enabled": False}},  # lone robot's loop
        {"agents": 3, "runs": 5, "battery": {"enabled": False}},  # team's loop
        {"agents": 2, "runs": 3},  # the general loop (battery)
        {"agents": 2, "runs": 3, "battery": {"enabled": False}, "record": {"watch": [34]}},
    ],
    ids=["solo", "team", "any", "updates"],
)
def test_compiled_block_sizes_do_not_change_results(tmp_path: Path, monkeypatch, flat):
    """The compiled loop's calls may have any number of team steps (the schedule sizes
    them by wall time): calls of 600, then 1, 7, 333, ... steps, cycling, write the
    files of the default schedule, byte for byte."""
    pytest.importorskip("numba")
    from qpatrol import run

    cfg = from_mapping({"map": "map_b", "seed": 5, "steps": 1500, "engine": "numba", **flat})
    whole = folder(simulate(cfg), tmp_path / "a")
    sizes = [1, 7, 333, 2, 600, 64]
    seen: list[int] = []
    schedule = run.compiled_schedule

    def first_600(*args, **kwargs):
        return min(schedule(*args, **kwargs), 600)

    def odd_blocks(block, taken, seconds, largest):
        seen.append(min(sizes[len(seen) % len(sizes)], largest))
        return seen[-1]

    monkeypatch.setattr(run, "compiled_schedule", first_600)
    monkeypatch.setattr(run, "_next_block", odd_blocks)
    assert folder(simulate(cfg), tmp_path / "b") == whole
    assert len(set(seen)) > 2  # the sizes did vary


def test_next_block_fits_calls_in_the_wall_time_bound(monkeypatch):
    """A call slower than COMPILED_CALL_SECONDS halves the block (down to
    COMPILED_MIN_STEPS); a fast one brings it back to the schedule's."""
    from qpatrol import run

    monkeypatch.setattr(run, "COMPILED_CALL_SECONDS", 1.0)
    assert run._next_block(4096, 4096, 0.3, 4096) == 4096  # fits
    assert run._next_block(4096, 4096, 3.0, 4096) == 1024  # 1,365 steps fit: 1,024
    assert run._next_block(4096, 4096, 100.0, 4096) == run.COMPILED_MIN_STEPS
    assert run._next_block(512, 512, 0.01, 4096) == 4096  # the compile is paid: back
    assert run._next_block(100, 100, 100.0, 100) == 100  # below the floor already
    assert run._next_block(8, 8, 1e-6, 8) == 8  # never beyond the schedule
    # the same schedule with or without a checkpointer; one step when it asks for that
    assert run.compiled_schedule(2048, 1, False) == 4096
    assert run.compiled_schedule(2, 2, False) == 16384
    assert run.compiled_schedule(2, 2, True) == 2048
    assert run.compiled_schedule(2048, 1, False, every_step=True) == 1


def test_slow_calls_are_shortened_and_ticked_after_each(tmp_path: Path, monkeypatch):
    """With calls slower than the bound (here: any call), a checkpointer is ticked after
    blocks of the smallest size, on the compiled engine, and a stop there resumes to the
    files of an uninterrupted run; with a loose bound it is ticked after the schedule's
    blocks (4,096 steps for 130 lone robots), as a run without checkpointer calls it."""
    pytest.importorskip("numba")
    from qpatrol import run

    flat = {"map": "map_b", "seed": 3, "steps": 9000, "runs": 130, "agents": 1}
    cfg = from_mapping({**flat, "engine": "numba", "battery": {"enabled": False}})
    whole = folder(simulate(cfg), tmp_path / "whole")
    ticks: list[int] = []

    class StopAt(ck.Checkpointer):
        def tick(self, position, payload):
            ticks.append(position)
            if len(ticks) == 3:
                self.request_stop()
            super().tick(position, payload)

    monkeypatch.setattr(run, "COMPILED_CALL_SECONDS", 0.0)
    with pytest.raises(ck.Interrupted):
        simulate(cfg, checkpoint=StopAt(tmp_path / "cp", every=0))
    small = run.COMPILED_MIN_STEPS
    assert ticks == [4096, 4096 + small, 4096 + 2 * small]
    resumed = ck.Checkpointer(tmp_path / "cp", every=0)
    assert resumed.load().position == ticks[-1]
    assert folder(simulate(cfg, checkpoint=resumed), tmp_path / "rest") == whole
    monkeypatch.setattr(run, "COMPILED_CALL_SECONDS", 1e9)
    ticks.clear()
    with pytest.raises(ck.Interrupted):
        simulate(cfg, checkpoint=StopAt(tmp_path / "cp2", every=0))
    assert ticks == [4096, 8192, 9000]


def test_periodic_checkpoints_come_on_time_on_the_compiled_engine(tmp_path: Path, monkeypatch):
    """A checkpointer due every 3.5 (fake) seconds, its clock a second ahead at each
    call of the compiled loop (blocks of 4,096 steps for 16 lone robots): it saves at
    the end of the first call after each 3.5 s."""
    pytest.importorskip("numba")
    from qpatrol import run

    monkeypatch.setattr(run, "COMPILED_CALL_SECONDS", 1e9)  # the schedule's blocks only
    flat = {"map": "map_b", "seed": 3, "steps": 60_000, "runs": 16, "agents": 1}
    cfg = from_mapping({**flat, "engine": "numba", "battery": {"enabled": False}})
    clock = Clock()
    saved = []

    class Ticking(ck.Checkpointer):
        def tick(self, position, payload):
            clock.t += 1.0  # each call of the loop "takes" a second
            super().tick(position, payload)

        def save(self, position, payload):
            saved.append((clock.t, position))
            super().save(position, payload)

    simulate(cfg, checkpoint=Ticking(tmp_path / "cp", every=3.5, clock=clock))
    assert saved == [(4.0, 4 * 4096), (8.0, 8 * 4096), (12.0, 12 * 4096)]


# --------------------------------------------------------------------- train, killed


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("ckpt")
    cfg = root / "ck.yaml"
    # the numpy engine, which checkpoints between any two steps (the compiled engine's
    # stops at the end of a call: test_sigint_on_the_compiled_engine_...)
    cfg.write_text(yaml.safe_dump({**CONFIG, "engine": "numpy"}))
    ref = root / "ref"
    assert main("train", cfg, "--out", ref, "-q") == 0
    return cfg, ref


def start_train(cfg: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "qpatrol.cli", "train", str(cfg), "--out", str(out), "-q"],
        env={**os.environ, "QPATROL_CHECKPOINT_EVERY": "0.2"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def wait_for_checkpoint(proc: subprocess.Popen, folder: Path, timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while not ((folder / ck.STATE_FILE).is_file() and (folder / ck.INFO_FILE).is_file()):
        if proc.poll() is not None:
            pytest.fail(f"train ended before a checkpoint: {proc.communicate()}")
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail("no checkpoint within the time limit")
        time.sleep(0.02)


def assert_same_files(a: Path, b: Path) -> None:
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    assert "meta.json" in names and "transitions.csv" in names
    for name in names:
        if name == "meta.json":
            continue  # times differ; the rest is compared below
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    ma, mb = (json.loads((d / "meta.json").read_text()) for d in (a, b))
    assert ma["map"] == mb["map"] and ma["overrides"] == mb["overrides"]


def position_of(folder: Path) -> int:
    return json.loads((folder / ck.INFO_FILE).read_text())["position"]


def test_sigkill_halfway_then_resume_is_byte_identical(setup, tmp_path: Path):
    cfg, ref = setup
    out = tmp_path / "run"
    folder = ck.location(out)
    proc = start_train(cfg, out)
    wait_for_checkpoint(proc, folder)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    assert not out.exists()
    at = position_of(folder)
    assert 0 < at < CONFIG["steps"]  # killed halfway: the test is not vacuous
    # without --resume the checkpoint is not silently thrown away
    assert main("train", cfg, "--out", out, "-q") == 2
    assert main("train", cfg, "--out", out, "-q", "--resume") == 0
    assert not folder.exists()
    assert_same_files(out, ref)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["resumed"]["from_step"] >= at


def test_sigint_saves_says_so_and_resumes_byte_identical(setup, tmp_path: Path):
    cfg, ref = setup
    out = tmp_path / "run"
    folder = ck.location(out)
    proc = start_train(cfg, out)
    wait_for_checkpoint(proc, folder)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert "interrupted at team step" in lines[0] and "--resume" in lines[0]
    assert str(folder) in lines[0]
    at = position_of(folder)
    assert 0 < at < CONFIG["steps"]
    assert f"{at:,} of {CONFIG['steps']:,}" in lines[0]
    # a resume with another config is refused, the checkpoint kept
    assert main("train", cfg, "--out", out, "--set", "seed=12", "--resume") == 2
    assert folder.exists()
    assert main("train", cfg, "--out", out, "-q", "--resume") == 0
    assert_same_files(out, ref)


def test_resume_without_checkpoint(setup, tmp_path: Path, capsys):
    cfg, _ = setup
    assert main("train", cfg, "--out", tmp_path / "x", "--resume") == 2
    assert "no checkpoint to resume from" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_sigint_on_the_compiled_engine_stops_soon_and_resumes_byte_identical(tmp_path: Path):
    """`qpatrol train` on the compiled engine, in the blocks the Python API uses (4,096
    team steps of 256 lone robots a call): a SIGINT is served at the end of the call it
    comes in, the checkpoint is at a call's end, and the resumed run writes the files of
    an uninterrupted one."""
    pytest.importorskip("numba")
    flat = {
        "map": "map_b",
        "agents": 1,
        "runs": 256,
        "seed": 4,
        "steps": 100_000,
        "engine": "numba",
        "threads": 1,
        "battery": {"enabled": False},
    }
    cfg = tmp_path / "big.yaml"
    cfg.write_text(yaml.safe_dump(flat))
    ref, out = tmp_path / "ref", tmp_path / "run"
    assert main("train", cfg, "--out", ref, "-q") == 0
    folder = ck.location(out)
    proc = start_train(cfg, out)
    wait_for_checkpoint(proc, folder)
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    latency = time.monotonic() - sent
    assert proc.returncode == 130, err
    assert "interrupted at team step" in err
    at = position_of(folder)
    assert 0 < at < flat["steps"] and at % 512 == 0  # at a call's end, halfway
    assert latency < 10  # a call lasts about a second at most (the process exits too)
    assert main("train", cfg, "--out", out, "-q", "--resume") == 0
    names = sorted(p.name for p in ref.iterdir())
    assert names == sorted(p.name for p in out.iterdir())
    for name in names:
        if name != "meta.json":
            assert (ref / name).read_bytes() == (out / name).read_bytes(), name


# --------------------------------------------------------------------- every strategy

#: A small batch on the rooms map: battery, every recorder, an episode limit.
SMALL = {
    "agents": 3,
    "runs": 2,
    "seed": 7,
    "steps": 60,
    "max_episode_steps": 20,
    "battery": {"capacity": 30, "charge_steps": 3},
    "record": {"transitions": True, "watch": [3], "trajectory": 9, "timeline": 7},
}


def same_tree(a, b, pairs: dict[int, object], where: str = "payload") -> None:
    """``b`` is a copy of ``a``: the same types, values, array dtypes, shapes and layout,
    random states, and the same objects shared (or not) between its branches."""
    assert type(a) is type(b), where
    if isinstance(a, bool | int | float | str | type(None) | np.generic):
        assert a == b or (a != a and b != b), where
        return
    if not isinstance(a, tuple):
        if id(a) in pairs:
            assert pairs[id(a)] is b, f"{where}: shared differently"
            return
        pairs[id(a)] = b
    if isinstance(a, np.ndarray):
        fortran = [x.flags.f_contiguous and not x.flags.c_contiguous for x in (a, b)]
        assert (a.dtype, a.shape, fortran[0]) == (b.dtype, b.shape, fortran[1]), where
        assert np.array_equal(a, b, equal_nan=a.dtype.kind in "fc") and b.flags.writeable, where
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            same_tree(a[k], b[k], pairs, f"{where}[{k!r}]")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            same_tree(x, y, pairs, f"{where}[{i}]")
    elif isinstance(a, np.random.Generator):
        same_tree(a.bit_generator, b.bit_generator, pairs, f"{where}.bit_generator")
    elif isinstance(a, np.random.BitGenerator):
        same_tree(a.state, b.state, {}, f"{where}.state")
        same_tree(a.seed_seq, b.seed_seq, pairs, f"{where}.seed_seq")
    elif isinstance(a, np.random.SeedSequence):
        for name in ("entropy", "spawn_key", "pool_size", "n_children_spawned"):
            assert getattr(a, name) == getattr(b, name), f"{where}.{name}"
        assert np.array_equal(a.generate_state(4), b.generate_state(4)), where
    else:  # an object of checkpoint.CLASSES
        assert ck.class_tag(type(a)) in ck.CLASSES, where
        state = type(a).__getstate__
        sa, sb = (state(x) if state is not object.__getstate__ else vars(x) for x in (a, b))
        same_tree(sa, sb, pairs, where)


def test_every_strategy_class_may_be_checkpointed():
    from qpatrol import strategies

    for name in strategies.NAMES:
        assert ck.class_tag(strategies.strategy_class(name)) in ck.CLASSES, name


def stop_at(cfg, folder: Path, at: int) -> tuple:
    """Run ``cfg`` to a checkpoint at step ``at`` (ticked every step); its payload."""
    seen = []

    class StopAt(ck.Checkpointer):
        every_step = True

        def tick(self, position, payload):
            if position == at:
                seen.append(payload)
                self.request_stop()
            super().tick(position, payload)

    with pytest.raises(ck.Interrupted):
        simulate(cfg, checkpoint=StopAt(folder, every=0))
    return seen[0]


@pytest.mark.parametrize("policy", POLICIES)
def test_every_strategy_resumes_to_the_same_files(rooms_map, tmp_path, monkeypatch, policy):
    """Each strategy stopped at step 29 and resumed writes the files of the
    uninterrupted run: saved on either engine and resumed on the other (on the numpy
    engine alone without numba); the state read back is the state saved, to the array
    layout and the objects shared; and no pickle is read on the way."""
    import pickle

    from qpatrol import engines

    flat = {**SMALL, "map": str(rooms_map), "policy": policy}
    cfg = {e: from_mapping({**flat, "engine": e}) for e in ("numpy", "numba")}
    whole = folder(simulate(cfg["numpy"]), tmp_path / "whole")

    def no_pickle(*args, **kwargs):
        raise AssertionError("a checkpoint was unpickled")

    pairs = [("numpy", "numpy")]  # (a save on an engine, the resume on an engine)
    if engines.numba_installed() and engines.compiled_gap(cfg["numba"]) is None:
        pairs = [("numpy", "numba"), ("numba", "numpy")]  # each engine saves and resumes
    for first, then in pairs:
        cp = tmp_path / f"cp-{first}-{then}"
        payload = stop_at(cfg[first], cp, 29)
        resumed = ck.Checkpointer(cp, every=0)
        with monkeypatch.context() as m:  # (numba's cache is read with pickle: not here)
            for name in ("load", "loads", "Unpickler"):
                m.setattr(pickle, name, no_pickle)
            same_tree(payload, ck.load(cp / ck.STATE_FILE)["payload"], {})
            assert resumed.load().position == 29
        rest = simulate(cfg[then], checkpoint=resumed)
        assert rest.engine == then
        assert folder(rest, tmp_path / f"rest-{first}-{then}") == whole, (first, then)


# --------------------------------------------------------------------- bad checkpoints


class Boom:
    """Unpickling it creates the file ``marker``: the code a crafted pickle could run."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (exec, (f"open({self.marker!r}, 'w').close()",))


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A config file of a short run, its uninterrupted run folder, and the checkpoint
    `train` would save of it at step 50 (to be copied, never changed)."""
    from qpatrol import config as config_mod
    from qpatrol import run

    root = tmp_path_factory.mktemp("small")
    path = root / "small.yaml"
    path.write_text(yaml.safe_dump({**CONFIG, "steps": 200, "engine": "numpy"}))
    assert main("train", path, "--out", root / "ref", "-q") == 0
    cfg = config_mod.load_config(path, [])
    prepared = run.prepare(cfg)
    cp = run.train_checkpointer(cfg, prepared[0], root / "pristine", every=0)
    tick = cp.tick

    def stop_at_50(position, payload):
        if position == 50:
            cp.request_stop()
        tick(position, payload)

    cp.tick = stop_at_50
    with pytest.raises(ck.Interrupted):
        simulate(cfg, prepared=prepared, checkpoint=cp)
    return path, root / "ref", root / "pristine"


def files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def refused(small, tmp_path: Path, capsys, edit) -> str:
    """Copy the pristine checkpoint beside a run folder, ``edit(checkpoint folder)``,
    then resume: exit 2, one line on stderr, no run folder, the checkpoint as it was.
    Returns the line."""
    import shutil

    cfg, _, pristine = small
    out = tmp_path / "run"
    folder = ck.location(out)
    shutil.copytree(pristine, folder)
    edit(folder)
    before, around = files(folder), sorted(tmp_path.iterdir())
    capsys.readouterr()
    assert main("train", cfg, "--out", out, "-q", "--resume") == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in lines[0], lines
    assert not out.exists() and sorted(tmp_path.iterdir()) == around
    assert files(folder) == before
    return lines[0]


def test_the_pristine_checkpoint_resumes_to_the_uninterrupted_files(small, tmp_path: Path):
    """(What the tests below damage is a good checkpoint.)"""
    import shutil

    cfg, ref, pristine = small
    out = tmp_path / "run"
    shutil.copytree(pristine, ck.location(out))
    assert main("train", cfg, "--out", out, "-q", "--resume") == 0
    assert_same_files(out, ref)


def test_a_pickle_left_as_checkpoint_pkl_is_never_unpickled(small, tmp_path: Path, capsys):
    """A checkpoint.pkl (the older format, or one crafted to run code) is not read:
    --resume says so in one line and exits 2, writing nothing; --force starts over."""
    import pickle

    marker = tmp_path / "elsewhere" / "marker"
    marker.parent.mkdir()
    blob = pickle.dumps({"format": "qpatrol-checkpoint/1", "payload": Boom(marker)})

    def pickle_only(folder: Path) -> None:
        for p in folder.iterdir():
            p.unlink()
        (folder / "checkpoint.pkl").write_bytes(blob)

    line = refused(small, tmp_path, capsys, pickle_only)
    assert not marker.exists()  # the pickle was not read
    assert "older format" in line and "--force" in line
    cfg, ref, _ = small
    assert main("train", cfg, "--out", tmp_path / "run", "-q", "--force") == 0
    assert not marker.exists() and not ck.location(tmp_path / "run").exists()


def rewrite(folder: Path, edit_doc=None, edit_members=None) -> None:
    """Rewrite the checkpoint in ``folder`` with its JSON and npz edited, and a manifest
    of their true sha256 (so that what refuses them is the reading, not the checksum)."""
    import hashlib
    import io
    import zipfile

    manifest = folder / ck.STATE_FILE
    names = [line.split("  ")[1] for line in manifest.read_text().splitlines()]
    doc = json.loads((folder / names[0]).read_text())
    with zipfile.ZipFile(folder / names[1]) as zf:
        members = {
            n[:-4]: np.lib.format.read_array(zf.open(n), allow_pickle=False) for n in zf.namelist()
        }
    for name in names:
        (folder / name).unlink()
    if edit_doc is not None:
        edit_doc(doc)
    if edit_members is not None:
        edit_members(members)
    buf = io.BytesIO()
    np.savez(buf, **members)  # allow_pickle: an object array goes in as a pickle
    lines = []
    for suffix, data in ((".json", json.dumps(doc).encode()), (".npz", buf.getvalue())):
        digest = hashlib.sha256(data).hexdigest()
        name = f"checkpoint-{digest[:16]}{suffix}"
        (folder / name).write_bytes(data)
        lines.append(f"{digest}  {name}\n")
    manifest.write_text("".join(lines))


def first(node, tag: str) -> dict:
    """The first JSON node of the tree tagged ``tag`` (depth first)."""
    if isinstance(node, dict):
        if tag in node:
            return node
        node = list(node.values())
    if isinstance(node, list):
        for x in node:
            found = first(x, tag)
            if found is not None:
                return found
    return None


def set_tag(tag: str, value):
    def edit(doc):
        first(doc["tree"], tag)[tag] = value

    return edit


def object_array(marker: Path):
    def edit(members):
        members["p0"] = np.array([Boom(marker)], dtype=object)

    return edit


def test_a_rewritten_checkpoint_resumes(small, tmp_path: Path):
    """(The rewriting below makes a good checkpoint when it edits nothing.)"""
    import shutil

    cfg, ref, pristine = small
    out = tmp_path / "run"
    shutil.copytree(pristine, ck.location(out))
    rewrite(ck.location(out))
    assert main("train", cfg, "--out", out, "-q", "--resume") == 0
    assert_same_files(out, ref)


@pytest.mark.parametrize(
    "edit_doc, edit_members, says",
    [
        (None, "object array", "refused checkpoint (array 'p0' has dtype object"),
        (set_tag("object", "os:system"), None, "class 'os:system', not one a checkpoint"),
        (set_tag("object", "builtins:eval"), None, "class 'builtins:eval', not one"),
        (set_tag("object", "collections:OrderedDict"), None, "not one a checkpoint may hold"),
        (set_tag("named_tuple", "builtins:tuple"), None, "not one a checkpoint may hold"),
        (set_tag("bit_generator", "RandomState"), None, "refused checkpoint (bit generator"),
        (set_tag("array", 10**6), None, "unreadable checkpoint (no array 1000000)"),
        (lambda doc: doc["arrays"][0].__setitem__(0, "nowhere"), None, "array 'nowhere'"),
        (lambda doc: doc.__setitem__("format", "qpatrol-checkpoint/9"), None, "format"),
        (lambda doc: doc.__setitem__("tree", {"exec": "print(1)"}), None, "unknown tag 'exec'"),
    ],
    ids=[
        "object-array",
        "os.system",
        "builtins.eval",
        "OrderedDict",
        "tuple",
        "bit-generator",
        "array-index",
        "array-member",
        "format",
        "tag",
    ],
)
def test_crafted_checkpoints_are_refused(small, tmp_path, capsys, edit_doc, edit_members, says):
    """A checkpoint whose sha256 match but whose content is not what qpatrol writes (an
    object array, a class or bit generator outside the allowlists, an array the npz
    does not hold, another format, an unknown node) is refused: exit 2, one line,
    nothing written, no code of the file run."""
    marker = tmp_path / "elsewhere" / "marker"
    marker.parent.mkdir()
    members = object_array(marker) if edit_members == "object array" else None
    line = refused(small, tmp_path, capsys, lambda f: rewrite(f, edit_doc, members))
    assert not marker.exists()  # no pickle in the npz was read
    assert says in line, line


def flip(path: Path, at: float, bit: int) -> None:
    """Flip bit ``bit`` of the byte at fraction ``at`` of the file."""
    data = bytearray(path.read_bytes())
    i = min(int(at * len(data)), len(data) - 1)
    data[i] ^= 1 << bit
    path.write_bytes(bytes(data))


def part(folder: Path, which: str) -> Path:
    if which == "manifest":
        return folder / ck.STATE_FILE
    (p,) = folder.glob(f"checkpoint-*.{which}")
    return p


#: Where the bits flip: the first and last byte, and a spread between.
FLIPS = [(0.0, 0), (0.03, 5), (0.11, 1), (0.25, 3), (0.5, 6), (0.62, 2), (0.8, 4), (1.0, 7)]


@pytest.mark.parametrize("which", ["manifest", "json", "npz"])
def test_one_flipped_bit_is_detected(small, tmp_path, capsys, which):
    """One bit flipped anywhere in a stored file: --resume exits 2 with one line and
    writes nothing (the damaged checkpoint stays as it is)."""
    for i, (at, bit) in enumerate(FLIPS):
        here = tmp_path / str(i)
        here.mkdir()
        line = refused(small, here, capsys, lambda f, at=at, bit=bit: flip(part(f, which), at, bit))
        assert "checkpoint" in line, line
        if which != "manifest":
            assert "damaged checkpoint" in line and "does not match its sha256" in line


@pytest.mark.parametrize(
    "damage, says",
    [
        (lambda f: part(f, "npz").unlink(), "incomplete checkpoint"),
        (lambda f: part(f, "json").unlink(), "incomplete checkpoint"),
        (lambda f: part(f, "npz").write_bytes(part(f, "npz").read_bytes()[:999]), "damaged"),
        (lambda f: part(f, "json").write_bytes(part(f, "json").read_bytes()[:99]), "damaged"),
        (lambda f: part(f, "manifest").write_bytes(b""), "unreadable checkpoint"),
    ],
    ids=["npz-missing", "json-missing", "npz-truncated", "json-truncated", "manifest-empty"],
)
def test_a_truncated_or_incomplete_checkpoint_is_refused(small, tmp_path, capsys, damage, says):
    assert says in refused(small, tmp_path, capsys, damage)
