"""Ablation of ``qlearning-idleness`` against ``cyclic`` and ``conscientious``.

The study's rules: battery off, collisions avoided, communication on, measures after
``record.warmup``. Prints one row per (map, K, variant): average and worst idleness,
each the mean over seeds, and the worst idleness over cyclic's. Not a unit test: the
full table takes several minutes on 2 cores::

    python benchmarks/variant_ablation.py                     # everything
    python benchmarks/variant_ablation.py --maps map_a --ks 1 4 --runs 5
    python benchmarks/variant_ablation.py --variants full no-known --jsonl out.jsonl
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from qpatrol.config import load_config
from qpatrol.run import simulate

#: variant -> (policy, overrides)
VARIANTS: dict[str, tuple[str, list[str]]] = {
    "cyclic": ("cyclic", []),
    "conscientious": ("conscientious", []),
    "shared-consc": ("shared-conscientious", []),
    "full": ("qlearning-idleness", []),
    # no learning: gamma 0 leaves Q at 0, the choice is the known idleness alone
    "gamma0": ("qlearning-idleness", ["qidle.gamma=0"]),
    # no idleness feature in the state
    "no-idle-state": ("qlearning-idleness", ["qidle.state=cell_heading"]),
    # plain Q-learning: the reward is only learned, not read before the move
    # (optimistic start, else the greedy robot never leaves the first moves it paid)
    "no-known": ("qlearning-idleness", ["qidle.known_reward=off", "qidle.q_init=10"]),
    # the paper's dot reward instead of idleness
    "dot-reward": ("qlearning-idleness", ["qidle.reward=dot"]),
    # epsilon-greedy exploration, 0.1 decaying to 0 over 5000 steps
    "explore": ("qlearning-idleness", ["qidle.epsilon=0.1"]),
    # one Q-table per robot instead of one for the team
    "no-share": ("qlearning-idleness", ["qidle.share=off"]),
}
MAPS = ["map_a", "map_b", "pacman", "facility"]
KS = [1, 2, 4, 8]


def measure(job: tuple[str, str, int, int, int, int]) -> dict[str, object]:
    """Mean avg/worst idleness over ``runs`` seeds of one (variant, map, K)."""
    variant, mp, k, steps, warmup, runs = job
    policy, extra = VARIANTS[variant]
    cfg = load_config(
        "configs/strategies.yaml",
        [
            f"policy={policy}",
            f"agents={k}",
            f"map={mp}",
            "battery.enabled=off",
            f"steps={steps}",
            f"record.warmup={warmup}",
            f"runs={runs}",
            *extra,
        ],
    )
    t0 = time.time()
    res = simulate(cfg)
    return {
        "variant": variant,
        "map": mp,
        "k": k,
        "avg": float(np.mean([r["avg_idleness"] for r in res.summary])),
        "worst": float(np.mean([r["worst_idleness"] for r in res.summary])),
        "seconds": time.time() - t0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maps", nargs="+", default=MAPS)
    ap.add_argument("--ks", nargs="+", type=int, default=KS)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--warmup", type=int, default=2000)
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--jsonl", help="also append each result as a JSON line to this file")
    a = ap.parse_args()
    variants = list(dict.fromkeys(["cyclic", *a.variants]))  # the reference first
    jobs = [(v, mp, k, a.steps, a.warmup, a.runs) for mp in a.maps for k in a.ks for v in variants]
    results = {}
    with ProcessPoolExecutor(a.jobs) as pool:
        for r in pool.map(measure, jobs):
            results[(r["variant"], r["map"], r["k"])] = r
            if a.jsonl:
                with open(a.jsonl, "a", encoding="utf-8") as f:
                    f.write(json.dumps(r) + "\n")
    print(f"steps {a.steps}, warm-up {a.warmup}, {a.runs} seeds; battery off, communication on")
    print(f"{'map':9s} {'K':>2s} {'variant':14s} {'avg':>8s} {'worst':>8s} {'worst/cyc':>9s}")
    for mp in a.maps:
        for k in a.ks:
            ref = results[("cyclic", mp, k)]["worst"]
            for v in variants:
                r = results[(v, mp, k)]
                ratio = r["worst"] / ref
                print(f"{mp:9s} {k:2d} {v:14s} {r['avg']:8.1f} {r['worst']:8.1f} {ratio:9.2f}")


if __name__ == "__main__":
    main()
