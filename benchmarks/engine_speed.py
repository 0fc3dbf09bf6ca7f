"""Agent-steps per second of both engines and the plain-Python loop vs batch size.

    .venv/bin/python benchmarks/engine_speed.py [--out docs/performance] [--quick]

Runs ``qpatrol bench --json`` once per (engine, runs, agents) point, each in a fresh
process (so peak memory is per point), and writes ``<out>.json`` (every bench result)
and ``<out>.png`` (agent-steps/s against runs, log-log, both engines and the
reference loop measured next to each point).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

#: (engine, agents, runs, steps): about the same work per point, a few seconds each.
POINTS = [
    ("numpy", 1, 1, 4000),
    ("numpy", 1, 16, 3000),
    ("numpy", 1, 256, 1500),
    ("numpy", 1, 2048, 400),
    ("numpy", 4, 16, 800),
    ("numpy", 4, 256, 300),
    ("numba", 1, 1, 2_000_000),
    ("numba", 1, 16, 200_000),
    ("numba", 1, 256, 20_000),
    ("numba", 1, 2048, 3_000),
    ("numba", 4, 1, 500_000),
    ("numba", 4, 16, 50_000),
    ("numba", 4, 256, 5_000),
]


def run_point(engine: str, agents: int, runs: int, steps: int) -> dict:
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
        "--json",
    ]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    b = json.loads(out)
    b["command"] = (
        f"qpatrol bench --engine {engine} --agents {agents} --runs {runs} --steps {steps} --json"
    )
    return b


def plot(results: list[dict], path: Path) -> None:
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    styles = {"numpy": ("tab:blue", "o"), "numba": ("tab:red", "s")}
    team = {1: "1 agent", 4: "teams of 4"}
    for engine, (color, marker) in styles.items():
        for agents, line in ((1, "-"), (4, "--")):
            pts = sorted(
                (b["runs"], b["agent_steps_per_s"])
                for b in results
                if b["engine"] == engine and b["agents"] == agents
            )
            if pts:
                xs, ys = zip(*pts, strict=True)
                ax.plot(xs, ys, line, color=color, marker=marker, label=f"{engine}, {team[agents]}")
    for agents, line in ((1, ":"), (4, "-.")):
        refs = [b["reference_agent_steps_per_s"] for b in results if b["agents"] == agents]
        if refs:
            ax.axhline(
                float(np.median(refs)),
                linestyle=line,
                color="0.35",
                label=f"plain-Python loop, {team[agents]} (median of {len(refs)})",
            )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("runs in the batch")
    ax.set_ylabel("agent-steps per second")
    ax.set_title("qpatrol bench: Q-learning, battery off, map_a (2 cores, noisy)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/performance")
    ap.add_argument("--replot", action="store_true", help="only redraw from <out>.json")
    args = ap.parse_args()
    out = Path(args.out)
    if args.replot:
        results = json.loads(out.with_suffix(".json").read_text())
    else:
        results = []
        for point in POINTS:
            b = run_point(*point)
            results.append(b)
            print(
                f"{b['engine']:6} K={b['agents']} runs={b['runs']:5d} "
                f"{b['agent_steps_per_s'] / 1e6:9.3f} M/s  ref "
                f"{b['reference_agent_steps_per_s'] / 1e6:6.3f} M/s  ratio {b['ratio']:8.2f}  "
                f"{b['bytes_per_run']:,} B/run",
                flush=True,
            )
        out.with_suffix(".json").write_text(json.dumps(results, indent=1) + "\n")
    plot(results, out.with_suffix(".png"))


if __name__ == "__main__":
    main()
