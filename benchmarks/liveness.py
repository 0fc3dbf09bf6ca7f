"""Every strategy under ``exclusive`` on every shipped map, K = 2 to 16, battery on and off.

For each (map, strategy, K, battery) the runs of ``qpatrol train`` with the shipped
defaults but these keys; counts the runs that are not ``live`` (a stretch without
progress above ``stall_bound``, or a target unvisited for the whole window) and those
that leave a target unvisited, and, for those, whether the same run (config and seed)
under ``none``, robots ignoring each other, leaves a target unvisited too: then the
strategy leaves it so, not the rules. Writes every run's summary row to a CSV
(``coverage_none``: that run's coverage under ``none``, empty where not run). Teams the
config refuses (the density and room rules) are listed as refused.

One run against the same run under ``none`` says little for a strategy whose runs part
ways at the robots' first meeting (a learner: its later choices follow from other
updates), so ``--rates N`` then runs, for every point with a target unvisited, N runs
under each model and compares how many leave a target unvisited: the rules cost
coverage there only if ``exclusive``'s count is above ``none``'s by more than chance
(Fisher's exact test, one-sided, p below 0.01).

    python benchmarks/liveness.py --out /tmp/liveness.csv [--runs 2 --steps 6000]
    python benchmarks/liveness.py --out /tmp/ql.csv --maps facility --policies qlearning \
        --runs 2 --rates 256
"""

from __future__ import annotations

import argparse
import math
import time

import pandas as pd

from qpatrol import strategies
from qpatrol.config import ConfigError, from_flat
from qpatrol.maps import available_maps
from qpatrol.run import simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument("--warmup", type=int, default=1000)
    ap.add_argument("--agents", default="2,4,8,16")
    ap.add_argument("--maps", default=",".join(available_maps()))
    ap.add_argument("--policies", default=",".join(strategies.NAMES))
    ap.add_argument("--rates", type=int, default=0, help="runs per model at each point "
                    "with a target unvisited (0: no comparison of rates)")  # fmt: skip
    a = ap.parse_args()
    rows, refused = [], []
    t0 = time.perf_counter()
    for mp in a.maps.split(","):
        for pol in a.policies.split(","):
            for k in (int(x) for x in a.agents.split(",")):
                for bat in (False, True):
                    flat = point(a, mp, pol, k, bat, a.runs, "exclusive")
                    try:
                        res = simulate(from_flat(flat))
                    except ConfigError as e:
                        refused.append((mp, pol, k, bat, str(e)))
                        continue
                    # a target unvisited: the same runs with robots that ignore each
                    # other say whether the strategy leaves it so without the rules
                    alone = [None] * len(res.summary)
                    if any(r["coverage"] < 1.0 for r in res.summary):
                        flat["team.interaction"] = "none"
                        alone = [r["coverage"] for r in simulate(from_flat(flat)).summary]
                    for r, cov in zip(res.summary, alone, strict=True):
                        rows.append(
                            {"map": mp, "policy": pol, "agents": k, "battery": bat, **r,
                             "coverage_none": cov}
                        )  # fmt: skip
            done = pd.DataFrame(rows)
            bad = done[~done["live"].astype(bool)] if len(done) else done
            print(
                f"{mp} {pol}: {len(done)} runs so far, {len(bad)} not live, "
                f"{time.perf_counter() - t0:.0f} s",
                flush=True,
            )
    df = pd.DataFrame(rows)
    df.to_csv(a.out, index=False)
    not_live = df[~df["live"].astype(bool)]
    unvisited = df[df["coverage"] < 1.0]
    print(f"{len(df)} runs, {len(refused)} teams refused; not live: {len(not_live)}")
    print(f"a target unvisited for the whole window: {len(unvisited)}")
    alone = unvisited["coverage_none"] < 1.0
    print(
        f"  of which the same run under `none` leaves a target unvisited too: "
        f"{int(alone.sum())} (" + ", ".join(
            f"{p} {n}" for p, n in unvisited[alone].groupby("policy").size().items()
        ) + f"); only under `exclusive`: {int((~alone).sum())}"
    )  # fmt: skip
    cols = [
        "map", "policy", "agents", "battery", "run", "coverage", "coverage_none", "max_stall",
        "stall_bound",
    ]  # fmt: skip
    if len(not_live):
        print(not_live[cols].to_string(index=False))
    if len(unvisited):
        print(unvisited.groupby("policy").size().to_string())
    for r in refused:
        print("refused:", *r[:4])
    if a.rates and len(unvisited):
        points = unvisited[["map", "policy", "agents", "battery"]].drop_duplicates()
        print(f"runs leaving a target unvisited, of {a.rates} per model (seed 0):")
        for mp, pol, k, bat in points.itertuples(index=False):
            counts = []
            for inter in ("exclusive", "none"):
                flat = point(a, mp, pol, int(k), bool(bat), a.rates, inter)
                summary = simulate(from_flat(flat)).summary
                counts.append(sum(r["coverage"] < 1.0 for r in summary))
            p = fisher_greater(counts[0], counts[1], a.rates)
            verdict = "the rules cost coverage" if p < 0.01 else "chance"
            print(
                f"  {mp} {pol} K={k} battery={'on' if bat else 'off'}: exclusive "
                f"{counts[0]}, none {counts[1]}, p = {p:.3g} ({verdict})",
                flush=True,
            )


def point(
    a: argparse.Namespace, mp: str, pol: str, k: int, bat: bool, runs: int, inter: str
) -> dict:
    """The flat config of ``runs`` runs of one point under interaction model ``inter``."""
    return {
        "map": mp, "policy": pol, "agents": k, "runs": runs, "steps": a.steps,
        "record.warmup": a.warmup, "seed": 0, "battery.enabled": bat,
        "team.interaction": inter, "engine": "numba",
    }  # fmt: skip


def fisher_greater(a: int, c: int, n: int) -> float:
    """Fisher's exact test, one-sided: the chance that, of ``a + c`` runs with a target
    unvisited among two groups of ``n`` runs, the first group holds ``a`` or more, if
    the model made no difference (the hypergeometric tail)."""
    total = a + c
    norm = math.comb(2 * n, total)
    tail = range(a, min(n, total) + 1)
    return sum(math.comb(n, x) * math.comb(n, total - x) for x in tail) / norm


if __name__ == "__main__":
    main()
