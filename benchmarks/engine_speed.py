"""Agent-steps per second of both engines and the plain-Python loop vs batch size.

    .venv/bin/python benchmarks/engine_speed.py [--out docs/performance] [--repeat N]

Runs ``qpatrol bench --json`` for each (engine, runs, agents, threads) point, each in a
fresh process (so peak memory is per point), ``--repeat`` passes over all points (3 by
default: this machine's speed drifts, so a point is measured at three moments), and
writes ``<out>.json`` (every bench result, with its ``pass``) and ``<out>.png``
(agent-steps/s against runs, log-log, the median of the passes, both engines, the
compiled engine in one thread and on every core, and the reference loop measured next
to each point).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

#: (engine, agents, runs, steps, threads): about the same work per point, a few seconds
#: each; the compiled engine in one thread (``--threads 1``) and on every core (0), the
#: numpy engine in one thread whatever it is told. 2,048 runs also at 20,000 steps, where
#: setting up the runs (streams, tables) weighs less than at 3,000.
POINTS = [
    ("numpy", 1, 1, 4000, 1),
    ("numpy", 1, 16, 3000, 1),
    ("numpy", 1, 256, 1500, 1),
    ("numpy", 1, 2048, 400, 1),
    ("numpy", 4, 16, 800, 1),
    ("numpy", 4, 256, 300, 1),
    ("numba", 1, 1, 2_000_000, 1),
    ("numba", 1, 16, 200_000, 1),
    ("numba", 1, 256, 20_000, 1),
    ("numba", 1, 2048, 3_000, 1),
    ("numba", 1, 2048, 20_000, 1),
    ("numba", 4, 1, 500_000, 1),
    ("numba", 4, 16, 50_000, 1),
    ("numba", 4, 256, 5_000, 1),
    ("numba", 1, 16, 200_000, 0),
    ("numba", 1, 256, 20_000, 0),
    ("numba", 1, 2048, 3_000, 0),
    ("numba", 1, 2048, 20_000, 0),
    ("numba", 4, 16, 50_000, 0),
    ("numba", 4, 256, 5_000, 0),
]


def run_point(engine: str, agents: int, runs: int, steps: int, threads: int) -> dict:
    cmd = [
        sys.executable,
        "-m",
        "qpatrol.cli",
        "bench",
        "--engine",
        engine,
        "--agents",
        str(agents),
        "--runs",
        str(runs),
        "--steps",
        str(steps),
        "--threads",
        str(threads),
        "--json",
    ]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    b = json.loads(out)
    b["command"] = (
        f"qpatrol bench --engine {engine} --agents {agents} --runs {runs} --steps {steps} "
        f"--threads {threads} --json"
    )
    return b


def _median_rate(results: list[dict], b: dict) -> float:
    """The median agent-steps/s over the passes of ``b``'s point."""
    import numpy as np

    same = [x["agent_steps_per_s"] for x in results if x["command"] == b["command"]]
    return float(np.median(same))


def plot(results: list[dict], path: Path) -> None:
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5.2))
    cores = max((b.get("threads", 1) for b in results), default=1)
    styles = {
        ("numpy", False): ("tab:blue", "o", "numpy"),
        ("numba", False): ("tab:red", "s", "numba, 1 thread"),
        ("numba", True): ("tab:purple", "^", f"numba, {cores} threads"),
    }
    team = {1: "1 agent", 4: "teams of 4"}
    for (engine, many), (color, marker, name) in styles.items():
        for agents, line in ((1, "-"), (4, "--")):
            # one point per batch size: the longest run of it (2,048 runs: 20,000 steps);
            # a batch of one run has one thread whatever it asks, and is in both lines
            best: dict[int, dict] = {}
            for b in results:
                threaded = b.get("threads", 1) > 1 or (b["runs"] == 1 and many)
                if b["engine"] == engine and b["agents"] == agents and threaded == many:
                    if b["runs"] not in best or b["steps"] > best[b["runs"]]["steps"]:
                        best[b["runs"]] = b
            pts = sorted((r, _median_rate(results, b)) for r, b in best.items())
            if pts:
                xs, ys = zip(*pts, strict=True)
                ax.plot(xs, ys, line, color=color, marker=marker, label=f"{name}, {team[agents]}")
    gc = "; gc off" if all(b.get("gc_during_timings") is False for b in results) else ""
    for agents, line in ((1, ":"), (4, "-.")):
        refs = [b["reference_agent_steps_per_s"] for b in results if b["agents"] == agents]
        if refs:
            ax.axhline(
                float(np.median(refs)),
                linestyle=line,
                color="0.35",
                label=f"plain-Python loop, {team[agents]} (median of {len(refs)}{gc})",
            )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("runs in the batch")
    ax.set_ylabel("agent-steps per second")
    passes = 1 + max((b.get("pass", 0) for b in results), default=0)
    ax.set_title(
        f"qpatrol bench: Q-learning, battery off, map_a (2 cores, noisy; median of {passes} "
        f"pass{'es' if passes > 1 else ''})"
    )
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7.5, loc="lower right", ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/performance")
    ap.add_argument("--replot", action="store_true", help="only redraw from <out>.json")
    ap.add_argument("--repeat", type=int, default=3, help="passes over all points")
    args = ap.parse_args()
    out = Path(args.out)
    if args.replot:
        results = json.loads(out.with_suffix(".json").read_text())
    else:
        results = []
        for n, point in ((n, point) for n in range(args.repeat) for point in POINTS):
            b = run_point(*point)
            b["pass"] = n
            results.append(b)
            print(
                f"pass {n} {b['engine']:6} K={b['agents']} runs={b['runs']:5d} "
                f"threads={b['threads']} "
                f"{b['agent_steps_per_s'] / 1e6:9.3f} M/s  ref "
                f"{b['reference_agent_steps_per_s'] / 1e6:6.3f} M/s "
                f"({b['reference_drift']:+.0%})  ratio {b['ratio']:8.2f}  "
                f"{b['bytes_per_run']:,} B/run",
                flush=True,
            )
        out.with_suffix(".json").write_text(json.dumps(results, indent=1) + "\n")
    plot(results, out.with_suffix(".png"))


if __name__ == "__main__":
    main()
