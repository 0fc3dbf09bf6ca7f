"""Floors of 10^3, 10^4 and 10^5 cells with 8, 64 and 512 robots: setup, speed, memory.

    .venv/bin/python benchmarks/scale.py [--cells 1000 10000 100000] [--agents 8 64 512]
        [--policies cyclic qlearning conscientious] [--steps 10000] [--battery]
        [--out docs/scale.md]
    .venv/bin/python benchmarks/scale.py --walks [--cells 1000 3000 10000 100000]

Each floor is ``random_maze(n, n, 7, 0.25, 4, False)`` of ``tests/mazes.py`` (the n whose
floor has about the cells asked). Each row is two ``qpatrol train paper`` commands in
fresh processes (``runs=1``, ``engine=numba``, a warm numba cache: one untimed run of a
small floor first), each timed from outside with ``/usr/bin/time`` (wall seconds and peak
resident memory): one of 1 step (the setup: map, walks, placement, strategy, compiled
loop loaded, files written) and one of ``--steps`` steps; the loop's team steps per second
is ``(steps - 1) / (wall - setup wall)``, printed only where that difference is above a
second (below, two processes' noise hides it).
A config the command refuses (too many robots for the floor, the battery's room rule)
is listed with the first words of its refusal. Prints a markdown table, and writes it to
``--out`` if given.

With ``--walks``, only the closed walk through every cell of each floor (``cyclic``'s,
``walks.closed_walk``) and its lower bound (``walks.closed_walk_lower_bound``), in this
process: their lengths, the ratio, which way the walk was made (``search``: at most
``walks.SEARCH_TARGETS`` targets, the tour search; ``large``: the table-free walk) and
the wall seconds of each.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))

from mazes import random_maze  # noqa: E402


def floor(cells: int, folder: Path) -> tuple[Path, int]:
    """The maze file of about ``cells`` free cells, and its exact count."""
    from qpatrol.maps import parse_map

    n = max(2, round((cells / 2.2) ** 0.5))
    text = random_maze(n, n, 7, 0.25, 4, False)
    path = folder / f"floor{cells}.txt"
    path.write_text(text)
    return path, parse_map(text).n_cells


def train(path: Path, agents: int, policy: str, steps: int, battery: bool, out: Path):
    """(wall seconds, peak MiB, error line or '') of one ``qpatrol train``."""
    cmd = [
        "/usr/bin/time", "-f", "TIME %e %M",
        sys.executable, "-c", "from qpatrol.cli import main; main()",
        "train", "paper", "--out", str(out), "--force",
        "--set", f"map={path}", "--set", f"agents={agents}", "--set", "runs=1",
        "--set", f"steps={steps}", "--set", f"policy={policy}", "--set", "engine=numba",
        "--set", f"battery.enabled={'true' if battery else 'false'}",
    ]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO)
    line = [x for x in res.stderr.splitlines() if x.startswith("TIME ")][-1].split()
    error = ""
    if res.returncode != 0:
        bad = [x for x in res.stderr.splitlines() if "error" in x]
        error = (bad[-1] if bad else res.stderr.strip()[-200:])[:160]
    return float(line[1]), int(line[2]) / 1024, error


def walk_rows(cells: list[int], folder: Path) -> list[str]:
    """Markdown rows: each floor's closed walk against its bound (``--walks``)."""
    from qpatrol.maps import load_map, walks

    rows = [
        "| cells | walk | bound | walk / bound | way | walk s | bound s |",
        "|---|---|---|---|---|---|---|",
    ]
    for n in cells:
        path, c = floor(n, folder)
        m = load_map(path)
        t0 = time.perf_counter()
        walk = walks.closed_walk(m)
        t1 = time.perf_counter()
        bound = walks.closed_walk_lower_bound(m)
        t2 = time.perf_counter()
        way = "search" if m.n_targets <= walks.SEARCH_TARGETS else "large"
        rows.append(
            f"| {c:,} | {walk.size:,} | {bound:,} | {walk.size / bound:.3f} | {way} | "
            f"{t1 - t0:.1f} | {t2 - t1:.1f} |"
        )
        print(rows[-1], flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, nargs="+", default=[1000, 10000, 100000])
    ap.add_argument("--agents", type=int, nargs="+", default=[8, 64, 512])
    ap.add_argument("--policies", nargs="+", default=["cyclic", "qlearning", "conscientious"])
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--battery", action="store_true", help="battery on (default off)")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--walks", action="store_true", help="closed walks and bounds only")
    a = ap.parse_args()
    if a.walks:
        with tempfile.TemporaryDirectory() as tmp:
            table = "\n".join(walk_rows(a.cells, Path(tmp))) + "\n"
        print(table)
        if a.out:
            a.out.write_text(table)
        return
    rows = [
        "| cells | robots | policy | setup s | total s | team steps/s | peak MiB |",
        "|---|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        small, _ = floor(300, tmp)
        for policy in a.policies:  # warm numba's cache
            train(small, 2, policy, 600, a.battery, tmp / "warm")
        for cells in a.cells:
            path, c = floor(cells, tmp)
            for k in a.agents:
                for policy in a.policies:
                    s_wall, _, err = train(path, k, policy, 1, a.battery, tmp / "o1")
                    if err:
                        rows.append(f"| {c:,} | {k} | {policy} | refused: {err} ||||")
                        print(rows[-1], flush=True)
                        continue
                    wall, mib, err = train(path, k, policy, a.steps, a.battery, tmp / "o2")
                    rate = f"{(a.steps - 1) / (wall - s_wall):,.0f}" if wall - s_wall > 1 else "-"
                    rows.append(
                        f"| {c:,} | {k} | {policy} | {s_wall:.1f} | {wall:.1f} | {rate} | "
                        f"{mib:,.0f} |"
                    )
                    print(rows[-1], flush=True)
    table = "\n".join(rows) + "\n"
    print(table)
    if a.out:
        a.out.write_text(table)


if __name__ == "__main__":
    main()
