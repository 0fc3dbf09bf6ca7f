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
from qpatrol.config import from_mapping
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
    ck.save({"a": np.arange(3)}, tmp_path / "x.pkl")
    assert ck.load(tmp_path / "x.pkl")["a"].tolist() == [0, 1, 2]
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
    cfg.write_text(yaml.safe_dump(CONFIG))
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
