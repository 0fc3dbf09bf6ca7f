"""``qpatrol train`` against the Python API (``simulate`` then ``write_run``), same config.

    .venv/bin/python benchmarks/train_speed.py [--repeat 3] [--steps 100000] [--set KEY=V]

Each path runs in a fresh process (imports, numba's on-disk cache and the writing of the
run folder included, as a user pays them), the two alternating (api, train, api, train,
...) so that a machine whose speed drifts weighs on both alike; it prints each pass's
seconds, the medians and the ratio train / api of the medians. The default workload is
``configs/paper.yaml`` on the pacman map, 2,048 runs x 1 robot x 100,000 steps, battery
off, compiled engine, nothing watched.

Measured on a shared 2-core machine (whole process, medians of alternated passes, the
default workload): before train ran the compiled loop in the API's blocks (commit
c34d8ca) train took 107.9 s against the API's 15.4 s (7.0x; 42.6 s of user CPU against
5.3 s: 3,125 calls of 32 steps instead of 25 of 4,096); after, 16.2 s against 15.6 s
(1.06x), and 13.9 s against 13.3 s with this script (1.05x). At ``--steps 20000``:
26.0 s against 6.8 s (3.9x) before, 7.1 s against 6.9 s (1.08x) after.

``--loop`` times the loop alone in this process (no process start, no files): the API's
calls, one call per group of runs for all its steps (the floor the calls' cost is
measured against), and train's (checkpointer, signal handlers, progress), alternated.
Measured (default workload, 3 passes, medians): api 9.18 s, one-call 8.00 s, train
8.72 s (train / one-call 1.09; api and train run the same calls, their gap is noise).

``--path api`` or ``--path train`` runs one path once, in this process, and prints its
inner seconds as JSON (for an outside timer: ``/usr/bin/time -v python
benchmarks/train_speed.py --path train --steps 20000``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CONFIG = "paper"
#: The workload's overrides of CONFIG (steps comes from --steps).
WORKLOAD = [
    "map=pacman",
    "runs=2048",
    "agents=1",
    "battery.enabled=off",
    "engine=numba",
    "record.watch=[]",
]


def run_api(config: str, overrides: list[str], out: Path) -> float:
    """Seconds of ``simulate`` + ``write_run`` (config loading included)."""
    from qpatrol.config import load_config
    from qpatrol.run import simulate, write_run

    t = time.perf_counter()
    cfg = load_config(config, overrides)
    write_run(simulate(cfg), out)
    return time.perf_counter() - t


def run_train(config: str, overrides: list[str], out: Path) -> float:
    """Seconds of ``qpatrol train CONFIG --set ... --out OUT -q`` in this process."""
    from qpatrol import cli

    sets = [a for o in overrides for a in ("--set", o)]
    t = time.perf_counter()
    try:
        cli.main(["train", config, *sets, "--out", str(out), "-q"])
    except SystemExit as e:
        if e.code:
            raise
    return time.perf_counter() - t


def loop_costs(config: str, overrides: list[str], repeat: int) -> dict[str, list[float]]:
    """Seconds of the loop alone (no writing), in this process, alternated: ``api``
    (:func:`qpatrol.run.simulate` in its blocks), ``one-call`` (every run in one call
    of all its steps: the calls' floor) and ``train`` (with train's
    checkpointer under its signal handlers, and a progress callback)."""
    from qpatrol import run
    from qpatrol.config import load_config

    cfg = load_config(config, overrides)
    run.simulate(cfg.replace(steps=50, runs=2))  # load the compiled loop
    steps, seconds = run.COMPILED_RUN_STEPS, run.COMPILED_CALL_SECONDS
    times: dict[str, list[float]] = {"api": [], "one-call": [], "train": []}
    try:
        for _ in range(repeat):
            for kind, ts in times.items():
                one_call = kind == "one-call"
                run.COMPILED_RUN_STEPS = cfg["steps"] if one_call else steps
                run.COMPILED_CALL_SECONDS = float("inf") if one_call else seconds
                tmp = Path(tempfile.mkdtemp(prefix="train-speed-"))
                prepared = run.prepare(cfg)
                t = time.perf_counter()
                if kind == "train":
                    cp = run.train_checkpointer(cfg, prepared[0], tmp / "cp")
                    with cp.signals():
                        run.simulate(
                            cfg, prepared=prepared, checkpoint=cp, progress=lambda d, n: None
                        )
                else:
                    run.simulate(cfg, prepared=prepared)
                ts.append(time.perf_counter() - t)
                shutil.rmtree(tmp, ignore_errors=True)
    finally:
        run.COMPILED_RUN_STEPS, run.COMPILED_CALL_SECONDS = steps, seconds
    return times


def one(path: str, config: str, overrides: list[str]) -> float:
    """Run ``path`` once into a temporary folder; its inner seconds."""
    tmp = Path(tempfile.mkdtemp(prefix="train-speed-"))
    try:
        fn = run_api if path == "api" else run_train
        return fn(config, overrides, tmp / "run")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def timed(path: str, config: str, overrides: list[str]) -> tuple[float, float]:
    """``(whole-process seconds, inner seconds)`` of one path in a fresh process."""
    cmd = [sys.executable, __file__, "--path", path, "--config", config, "--no-workload"]
    cmd += [a for o in overrides for a in ("--set", o)]
    t = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t
    return wall, json.loads(done.stdout.strip().splitlines()[-1])["seconds"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=CONFIG)
    ap.add_argument("--steps", type=int, default=100_000)
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=V")
    ap.add_argument("--repeat", type=int, default=3, help="passes of each path")
    ap.add_argument("--path", choices=("api", "train"), help="run one path here, once")
    ap.add_argument("--no-workload", action="store_true", help="only CONFIG and --set")
    ap.add_argument("--loop", action="store_true", help="time the loop alone (loop_costs)")
    a = ap.parse_args()
    overrides = ([] if a.no_workload else [*WORKLOAD, f"steps={a.steps}"]) + a.sets
    if a.loop:
        times = loop_costs(a.config, overrides, a.repeat)
        for kind, ts in times.items():
            each = " ".join(f"{t:.2f}" for t in ts)
            print(f"{kind:8s} median {statistics.median(ts):8.2f} s  ({each})")
        base = statistics.median(times["one-call"])
        print(f"train / one-call {statistics.median(times['train']) / base:.3f}")
        return
    if a.path:
        print(json.dumps({"path": a.path, "seconds": one(a.path, a.config, overrides)}))
        return
    print(f"config {a.config} {' '.join(overrides)}")
    for path in ("api", "train"):  # compile or load the engine once, not counted
        timed(path, a.config, [*overrides, "steps=100", "runs=2"])
    walls: dict[str, list[float]] = {"api": [], "train": []}
    for i in range(a.repeat):
        for path in ("api", "train"):
            wall, inner = timed(path, a.config, overrides)
            walls[path].append(wall)
            print(f"pass {i + 1} {path:5s} {wall:8.2f} s whole process ({inner:.2f} s inside)")
    med = {k: statistics.median(v) for k, v in walls.items()}
    ratios = [t / p for t, p in zip(walls["train"], walls["api"], strict=True)]
    print(
        f"median api {med['api']:.2f} s, train {med['train']:.2f} s, "
        f"train/api {med['train'] / med['api']:.3f} (pairwise median "
        f"{statistics.median(ratios):.3f})"
    )


if __name__ == "__main__":
    main()
