"""SimplePatrol's protocol on SimPatrol's map A, in qpatrol's definitions and the field's.

Protocol (SimplePatrol's): 150,000 team steps measured after a warm-up of 50,000, 3 runs,
1, 5, 10 and 15 robots, robots ignoring each other (``team.avoid_collisions: off``),
strategies ``conscientious`` and ``shared-conscientious`` (SimplePatrol's
conscientious-reactive and its shared-memory variant). Each row prints qpatrol's quadratic
mean interval, average and worst idleness (docs/model.md, "Patrolling measures") and
SimPatrol MetricsReport's recount of the same run (``qpatrol.measures.field``), from every
robot's cells over the measured window (``record.trajectory``).

The map: SimPatrol's map A (50 nodes, 106 edges) is ``SimPatrol Clients/res/maps/
map_a.xml`` in the public repository github.com/mothguib/simpatrol, which carries no
licence file, so it is not shipped here: give your copy with ``--xml map_a.xml`` and it is
imported with ``qpatrol maps import --unit-edges`` (every edge one move, the parallel
edges v37-v39 merged). Without ``--xml`` the example runs on the shipped patrol graph
``ps_example`` (patrolling_sim's example.graph), the closest shipped graph.

Published numbers: none are printed beside ours. Almeida, Ramalho, Santana, Tedesco,
Menezes, Corruble and Chevaleyre, "Recent Advances on Multi-Agent Patrolling", SBIA 2004,
LNAI 3171, pp. 526-535, tabulate map A and map B, but with SimPatrol's edge lengths
(not unit edges) and their own protocol, so they do not compare with this table; no
publication of SimplePatrol's numbers under this protocol was found to cite. The
closeness to SimplePatrol's own agents (QMI within 1% for conscientious, 2% for
shared-conscientious) comes from a referee's runs, not from a publication.

Run time: the full protocol on a 30-vertex graph takes about 20 s with a warm numba
cache on 2 cores and peaks near 1.2 GB (the trajectory of 150,001 steps x 15 robots x
3 runs); ``--quick`` takes a few seconds on the numpy engine.

    python examples/simplepatrol_map_a.py [--xml map_a.xml] [--quick]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from qpatrol.config import load_config
from qpatrol.maps import get_map
from qpatrol.measures.field import simpatrol_measures, trajectory_visits
from qpatrol.run import simulate

STRATEGIES = ("conscientious", "shared-conscientious")
TEAMS = (1, 5, 10, 15)
FULL = {"steps": 200_000, "warmup": 50_000, "runs": 3}
QUICK = {"steps": 600, "warmup": 200, "runs": 2}


def import_xml(xml: Path, out: Path) -> str:
    """The qpatrol map file of SimPatrol graph ``xml``, every edge one move."""
    cmd = [sys.executable, "-m", "qpatrol.cli", "maps", "import", str(xml), "--unit-edges"]
    cmd += ["--agents", str(max(TEAMS)), "--out", str(out), "--force"]
    subprocess.run(cmd, check=True)
    return str(out)


def field_row(result, warmup: int, steps: int) -> list[dict[str, float]]:
    """SimPatrol's measures of each run, from its trajectory over ``[warmup, steps]``
    (one step before the window, to see who entered at its first step)."""
    m = result.map
    out = []
    for _, run in result.trajectory.groupby("run"):
        k = int(run["agent"].max()) + 1
        cells = run["cell"].to_numpy().reshape(-1, k)  # [S + 1, K], steps warmup..steps
        times = trajectory_visits(cells, m.target, warmup + 1)
        out.append(simpatrol_measures(times, warmup + 1, steps))
    return out


def main(argv: list[str] | None = None) -> list[dict[str, object]]:
    """Run the protocol, print the table, return its rows."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--xml", type=Path, help="SimPatrol's map_a.xml (default: ps_example)")
    ap.add_argument("--quick", action="store_true", help="a short run (seconds)")
    ap.add_argument("--engine", default="auto", help="numpy, numba or auto")
    args = ap.parse_args(argv)
    proto = QUICK if args.quick else FULL
    with tempfile.TemporaryDirectory() as tmp:
        mp = import_xml(args.xml, Path(tmp) / "map_a.txt") if args.xml else "ps_example"
        get_map(mp)  # refuses a broken map before any run
        rows = []
        for strategy in STRATEGIES:
            for k in TEAMS:
                t0 = time.perf_counter()
                cfg = load_config(
                    "field",
                    [
                        f"map={mp}",
                        f"agents={k}",
                        f"policy={strategy}",
                        "team.avoid_collisions=off",
                        f"steps={proto['steps']}",
                        f"record.warmup={proto['warmup']}",
                        f"runs={proto['runs']}",
                        f"record.trajectory={proto['steps'] - proto['warmup'] + 1}",
                        f"engine={args.engine}",
                    ],
                )
                res = simulate(cfg)
                field = field_row(res, proto["warmup"], proto["steps"])
                ours = res.summary
                rows.append(
                    {
                        "strategy": strategy,
                        "robots": k,
                        "qmi": float(np.mean([s["qmi"] for s in ours])),
                        "avg_idleness": float(np.mean([s["avg_idleness"] for s in ours])),
                        "worst_idleness": float(np.mean([s["worst_idleness"] for s in ours])),
                        "field_qmi": float(np.mean([f["qmi"] for f in field])),
                        "field_avg_idleness": float(np.mean([f["avg_idleness"] for f in field])),
                        "field_max_interval": float(np.mean([f["max_interval"] for f in field])),
                        "seconds": time.perf_counter() - t0,
                    }
                )
    head = list(rows[0])
    print(" ".join(f"{h:>20}" for h in head))
    for r in rows:
        print(" ".join(f"{v:>20.3f}" if isinstance(v, float) else f"{v!s:>20}" for v in r.values()))
    return rows


if __name__ == "__main__":
    main()
