"""A first result on a fresh install: ``qpatrol train`` with an empty numba cache.

    .venv/bin/python benchmarks/cold_start.py [--repeat 3] [--steps 5000 200000]
    .venv/bin/python benchmarks/cold_start.py --reproduce      # a cold `qpatrol reproduce`
    .venv/bin/python benchmarks/cold_start.py --rates          # the cost model's numbers
    .venv/bin/python benchmarks/cold_start.py --compile        # compile seconds per loop

Each cold run is a fresh process with an empty ``NUMBA_CACHE_DIR`` of its own (numba
otherwise caches in ``__pycache__`` next to the sources), timed as ``/usr/bin/time``
would (wall seconds, and CPU seconds of the process and its waited-for children: the
background process that compiles the loop for the next run is detached, and not
counted). The script then waits for that background compile to finish (its marker in
the cache folder, :mod:`qpatrol.engines.coldstart`), says how long it took, and times a
warm run on the same cache. Medians over ``--repeat`` rounds, each its own cache.

``--rates`` measures the numpy engine's CPU time per team step of each compiled loop's
batches (1 and 32 runs), ``--compile`` each loop's compile (fresh process, empty cache):
the numbers of :data:`qpatrol.engines.coldstart.NUMPY_US` and ``COMPILE_SECONDS``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def env_with(cache: str | None) -> dict[str, str]:
    """This checkout on the path, numba's cache in ``cache`` (None: as set)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = cache
    return env


def timed(argv: list[str], cache: str | None) -> tuple[float, float]:
    """``(wall seconds, CPU seconds)`` of ``python -m qpatrol.cli ARGV``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "qpatrol.cli", *argv],
        env=env_with(cache),
        check=True,
        stdout=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def wait_for_warm(cache: str, limit: float = 600.0) -> float | None:
    """Seconds until the background compile left a marker and no lock in ``cache``
    (None: not within ``limit``)."""
    t = time.perf_counter()
    while time.perf_counter() - t < limit:
        markers = list(Path(cache).rglob("qpatrol-loop-*.json"))
        locks = list(Path(cache).rglob("qpatrol-loop-*.lock"))
        if markers and not locks:
            return time.perf_counter() - t
        time.sleep(0.5)
    return None


def train_rounds(config: str, steps: list[int], repeat: int) -> None:
    for n in steps:
        rows = []
        for _ in range(repeat):
            with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
                argv = ["train", config, "--set", f"steps={n}", "-q"]
                cold = timed([*argv, "--out", f"{out}/cold"], cache)
                note = (Path(out) / "cold" / "meta.json").read_text()
                ran = json.loads(note)["engine"]["ran"]
                waited = wait_for_warm(cache)
                warm = timed([*argv, "--out", f"{out}/warm"], cache)
                rows.append((cold, ran, waited, warm))
                print(
                    f"  steps={n}: cold {cold[0]:.1f} s wall {cold[1]:.1f} s CPU ({ran}); "
                    f"background compile done {waited if waited is None else round(waited, 1)}"
                    f" s later; warm {warm[0]:.1f} s wall {warm[1]:.1f} s CPU",
                    flush=True,
                )
        med = [statistics.median(r[i][j] for r in rows) for i in (0, 3) for j in (0, 1)]
        print(
            f"qpatrol train {config} --set steps={n}: median of {repeat}: cold {med[0]:.1f} s "
            f"wall ({med[1]:.1f} s CPU), warm {med[2]:.1f} s wall ({med[3]:.1f} s CPU)",
            flush=True,
        )


def reproduce(jobs: int | None) -> None:
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
        argv = ["reproduce", "--out", out] + ([] if jobs is None else ["--jobs", str(jobs)])
        wall, cpu = timed(argv, cache)
        print(f"cold qpatrol reproduce: {wall:.1f} s wall, {cpu:.1f} s CPU", flush=True)


RATES = r"""
import time
from qpatrol.run import bench
from qpatrol.engines import coldstart
from qpatrol.run import simulate
CASES = [
    (1, {}),
    (4, {}),
    (1, {"record.watch": [13]}),
    (1, {"battery.enabled": True}),
    (4, {"battery.enabled": True}),
    (4, {"policy": "qlearning-idleness", "battery.enabled": True}),
]
for agents, extra in CASES:
    us = []
    for runs in (1, 32, 256):
        cfg = bench.workload(runs, agents, 1000, engine="numpy", extra=extra)
        t = time.process_time()
        simulate(cfg)
        us.append((time.process_time() - t) / 1000 * 1e6)
    per = (us[2] - us[0]) / (255 * agents)
    fixed = us[0] - per * agents
    model = [coldstart.numpy_seconds(cfg, r) / 1000 * 1e6 for r in (1, 32, 256)]
    print(f"{agents} agents {extra}: us/step at 1, 32, "
          f"256 runs {us[0]:.0f} {us[1]:.0f} {us[2]:.0f} (fixed {fixed:.0f} + {per:.2f} per "
          f"agent-step); NUMPY_US gives {model[0]:.0f} {model[1]:.0f} {model[2]:.0f}",
          flush=True)
"""

COMPILE = r"""
import sys, time
from qpatrol import engines
from qpatrol.run import bench
from qpatrol.run import simulate
loop = sys.argv[1]
agents, extra = {
    "any": (4, {"battery.enabled": True}),
    "qlearning": (4, {"record.watch": [13]}),
    "qlearning-solo": (1, {}),
    "qlearning-team": (4, {}),
}[loop]
cfg = bench.workload(1, agents, 8, engine="numba", extra=extra)
assert engines.compiled_loop(cfg) == loop
import qpatrol.engines.numba_core
t = time.process_time()
simulate(cfg)
print(f"{loop}: compiled in {time.process_time() - t:.1f} s CPU", flush=True)
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="paper")
    ap.add_argument("--steps", type=int, nargs="+", default=[5000, 200_000])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--reproduce", action="store_true", help="time a cold qpatrol reproduce")
    ap.add_argument("--jobs", type=int, default=None, help="--jobs of qpatrol reproduce")
    ap.add_argument("--rates", action="store_true", help="numpy CPU per team step")
    ap.add_argument("--compile", action="store_true", help="compile CPU per loop")
    a = ap.parse_args()
    if a.rates:
        subprocess.run([sys.executable, "-c", RATES], env=env_with(None), check=True)
    elif a.compile:
        for loop in ("any", "qlearning", "qlearning-solo", "qlearning-team"):
            with tempfile.TemporaryDirectory() as cache:
                cmd = [sys.executable, "-c", COMPILE, loop]
                subprocess.run(cmd, env=env_with(cache), check=True)
    elif a.reproduce:
        reproduce(a.jobs)
    else:
        train_rounds(a.config, a.steps, a.repeat)


if __name__ == "__main__":
    main()
