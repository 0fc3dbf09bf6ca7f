"""A/B of two checkouts on the `qpatrol bench` workloads, alternated in the same minutes.

    python benchmarks/ab_bench.py --a /path/to/checkout-A --b /path/to/checkout-B [--pairs 3]

Each row runs ``qpatrol bench --engine numba --runs B --agents K --threads N --json`` in a
fresh process with ``PYTHONPATH`` set to A's, then B's checkout (each with its own numba
cache folder, warmed first), ``--pairs`` times in turn, and prints the median
agent-steps/s of each and the median of the pairwise ratios B/A (above 1: B is faster).
The workloads are those of docs/performance.md: lone robots at 1 and 2,048 runs, teams
of four at 1, 16 and 256 runs, one thread and two.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

#: (runs, agents, threads, steps): the bench workloads compared.
WORKLOADS = [
    (1, 1, 1, 2_000_000),
    (2048, 1, 1, 3_000),
    (1, 4, 1, 500_000),
    (16, 4, 1, 50_000),
    (256, 4, 1, 5_000),
    (2048, 1, 2, 3_000),
    (16, 4, 2, 50_000),
    (256, 4, 2, 5_000),
]


def bench(tree: str, cache: str, runs: int, agents: int, threads: int, steps: int) -> float:
    """agent-steps/s of one `qpatrol bench` of the workload, on checkout ``tree``."""
    env = dict(os.environ, PYTHONPATH=tree, NUMBA_CACHE_DIR=cache)
    argv = [sys.executable, "-m", "qpatrol.cli", "bench", "--engine", "numba"]
    argv += ["--runs", str(runs), "--agents", str(agents), "--threads", str(threads)]
    argv += ["--steps", str(steps), "--json"]
    out = subprocess.run(argv, env=env, cwd=tree, capture_output=True, text=True, check=True)
    return float(json.loads(out.stdout)["agent_steps_per_s"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--a", required=True, help="checkout A (the baseline)")
    ap.add_argument("--b", required=True, help="checkout B")
    ap.add_argument("--pairs", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as ca, tempfile.TemporaryDirectory() as cb:
        for tree, cache in ((args.a, ca), (args.b, cb)):  # compile every loop once
            for runs, agents, threads, _ in WORKLOADS[:5]:
                bench(tree, cache, runs, agents, threads, 200)
        print("runs agents threads | A M/s | B M/s | B/A (median of pairs, range)")
        for runs, agents, threads, steps in WORKLOADS:
            a, b = [], []
            for _ in range(args.pairs):
                a.append(bench(args.a, ca, runs, agents, threads, steps))
                b.append(bench(args.b, cb, runs, agents, threads, steps))
            ratios = [y / x for x, y in zip(a, b, strict=True)]
            print(
                f"{runs:5d} {agents:3d} {threads:3d} | {statistics.median(a) / 1e6:6.2f} | "
                f"{statistics.median(b) / 1e6:6.2f} | {statistics.median(ratios):.3f} "
                f"({min(ratios):.3f} to {max(ratios):.3f})",
                flush=True,
            )


if __name__ == "__main__":
    main()
