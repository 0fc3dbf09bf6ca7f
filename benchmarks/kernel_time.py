"""Nanoseconds per agent-step of the compiled engine's loop, in this process, one thread.

    .venv/bin/python benchmarks/kernel_time.py RUNS AGENTS STEPS [--repeat N] [--set KEY=VALUE]

Times :func:`qpatrol.run.simulate` of ``qpatrol bench``'s workload (qlearning, battery
off, map_a) on the compiled engine in one thread, after a warm-up that compiles or
loads the loop, and prints the best of ``--repeat`` timings in ns per agent-step. For an
A/B of two trees of the code (a ``git worktree`` of the committed one and the changed
one), alternate them, one process each, with ``PYTHONPATH`` set to the tree::

    for i in 1 2 3 4 5; do
        PYTHONPATH=/tmp/base .venv/bin/python benchmarks/kernel_time.py 1 4 1000000
        PYTHONPATH=. .venv/bin/python benchmarks/kernel_time.py 1 4 1000000
    done

(this machine's speed drifts: compare the pairs, not one number with another of an
earlier minute).
"""

from __future__ import annotations

import argparse
import time

from qpatrol.config import parse_assignment
from qpatrol.run import bench, prepare, simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=int)
    ap.add_argument("agents", type=int)
    ap.add_argument("steps", type=int)
    ap.add_argument("--repeat", type=int, default=3, help="timings; the best is printed")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    extra = dict(parse_assignment(a) for a in args.set)
    cfg = bench.workload(args.runs, args.agents, args.steps, "numba", extra=extra, threads=1)
    prepared = prepare(cfg)
    warm = cfg.replace(runs=1, steps=min(args.steps, 50))
    simulate(warm, prepared=prepare(warm))
    best = float("inf")
    for _ in range(args.repeat):
        t = time.perf_counter()
        simulate(cfg, prepared=prepared)
        best = min(best, time.perf_counter() - t)
    per = best * 1e9 / (args.runs * args.agents * args.steps)
    print(f"{args.runs} x {args.agents} x {args.steps}: {per:.1f} ns per agent-step")


if __name__ == "__main__":
    main()
