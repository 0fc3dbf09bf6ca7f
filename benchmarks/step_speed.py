"""How fast the batched simulator advances, and what batching runs buys.

    .venv/bin/python benchmarks/step_speed.py [--steps 3000]

Prints, for a team of 4 on map A, the wall time per team step and per run-step for
batches of 1, 8 and 32 independent runs, measured on this machine (best of 3).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

from qpatrol.config import from_flat
from qpatrol.run import prepare, simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--map", default="map_a")
    ap.add_argument("--agents", type=int, default=4)
    args = ap.parse_args()
    print(
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"python {platform.python_version()}; map {args.map}, {args.agents} agents, "
        f"{args.steps} team steps, best of 3"
    )
    print(f"{'runs':>5} {'seconds':>9} {'ms/team step':>13} {'us/run-step':>12}")
    for runs in (1, 8, 32):
        cfg = from_flat({"map": args.map, "agents": args.agents, "runs": runs, "steps": args.steps})
        prepared = prepare(cfg)
        best = min(_timed(cfg, prepared) for _ in range(3))
        print(
            f"{runs:5d} {best:9.2f} {1e3 * best / args.steps:13.3f} "
            f"{1e6 * best / (args.steps * runs):12.1f}"
        )


def _timed(cfg, prepared) -> float:
    t = time.perf_counter()
    simulate(cfg, prepared=prepared)
    return time.perf_counter() - t


if __name__ == "__main__":
    main()
