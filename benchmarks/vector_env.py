"""Agent-steps per second of the batched env, side by side with the single-run env and
``train`` on the same workload (docs/envs.md, "Speed").

Workload: B runs of K robots on MAP (default 256 x 6 on ps_cumberland, battery off,
the field's default interaction), each step every robot's action a uniformly random
valid one (its action mask), drawn by a Python policy through the public API:

* ``vector``: :class:`qpatrol.envs.PatrolVectorEnv` (engine numba), observations
  (per-port features) and masks written each step, random valid actions from the
  masks (numpy, one call for the batch);
* ``vector-numpy``: the same on the numpy engine (``--numpy``);
* ``pettingzoo``: :class:`qpatrol.envs.PatrolParallelEnv`, one run, the same robots
  and map, ``action_space(a).sample(mask)`` per agent (steps per second of one run,
  times K robots);
* ``train``: :func:`qpatrol.run.simulate` of ``policy=random`` (the classic strategy
  that also picks a random open move) on the same B x K x T, compiled engine.

Each workload is measured ``--repeat`` times, in turn (A, B, C, A, B, C, ...), after
one warm-up each (the compile or the cache load); the medians and the ratios of the
medians are printed, with the load average. ``--json`` prints them as one object.

    python benchmarks/vector_env.py [--runs 256] [--agents 6] [--map ps_cumberland]
        [--steps 1000] [--repeat 5] [--threads 1] [--numpy] [--only vector,train]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np


def random_valid(mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """int ``[..., ]``: a uniformly random port among the mask's ones (0 where none)."""
    u = rng.random(mask.shape, dtype=np.float32) * mask
    return u.argmax(axis=-1)


def vector(args, engine: str) -> float:
    from qpatrol.envs import PatrolVectorEnv

    env = PatrolVectorEnv(
        None,
        [f"battery.enabled={args.battery}"],
        map=args.map,
        agents=args.agents,
        num_envs=args.runs,
        max_steps=args.steps + 1,
        engine=engine,
        threads=args.threads,
    )
    rng = np.random.default_rng(0)
    obs, infos = env.reset(seed=0)
    began = time.perf_counter()
    for _ in range(args.steps):
        actions = random_valid(infos["action_mask"], rng)
        obs, rewards, term, trunc, infos = env.step(actions)
    seconds = time.perf_counter() - began
    return args.runs * args.agents * args.steps / seconds


def pettingzoo(args) -> float:
    from qpatrol.envs import PatrolParallelEnv

    steps = max(200, args.steps // 4)
    env = PatrolParallelEnv(
        None,
        [f"battery.enabled={args.battery}"],
        map=args.map,
        agents=args.agents,
        max_steps=steps + 1,
    )
    obs, infos = env.reset(seed=0)
    began = time.perf_counter()
    for _ in range(steps):
        actions = {a: env.action_space(a).sample(infos[a]["action_mask"]) for a in env.agents}
        obs, rewards, term, trunc, infos = env.step(actions)
    seconds = time.perf_counter() - began
    return args.agents * steps / seconds


def train(args) -> float:
    from qpatrol import run
    from qpatrol.config import from_flat

    cfg = from_flat({}).with_overrides(
        [
            f"map={args.map}",
            f"agents={args.agents}",
            f"runs={args.runs}",
            f"steps={args.steps}",
            "policy=random",
            "engine=numba",
            f"threads={args.threads}",
            f"battery.enabled={args.battery}",
        ]
    )
    began = time.perf_counter()
    run.simulate(cfg)
    seconds = time.perf_counter() - began
    return args.runs * args.agents * args.steps / seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=256)
    ap.add_argument("--agents", type=int, default=6)
    ap.add_argument("--map", default="ps_cumberland")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--battery", default="off")
    ap.add_argument("--numpy", action="store_true", help="also the vector env on numpy")
    ap.add_argument("--only", default="", help="comma-separated workloads")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    work = {
        "vector": lambda: vector(args, "numba"),
        "pettingzoo": lambda: pettingzoo(args),
        "train": lambda: train(args),
    }
    if args.numpy:
        work["vector-numpy"] = lambda: vector(args, "numpy")
    if args.only:
        work = {k: v for k, v in work.items() if k in args.only.split(",")}
    load_before = os.getloadavg()
    for f in work.values():  # warm-up: the compile, or the load from numba's cache
        f()
    rates: dict[str, list[float]] = {k: [] for k in work}
    for _ in range(args.repeat):
        for k, f in work.items():
            rates[k].append(f())
    med = {k: statistics.median(v) for k, v in rates.items()}
    out = {
        "workload": f"{args.runs} runs x {args.agents} robots on {args.map}, {args.steps} steps",
        "threads": args.threads,
        "load_before": [round(x, 2) for x in load_before],
        "load_after": [round(x, 2) for x in os.getloadavg()],
        "agent_steps_per_s": {k: {"median": v, "all": rates[k]} for k, v in med.items()},
    }
    if "vector" in med:
        out["vector_over"] = {k: med["vector"] / v for k, v in med.items() if k != "vector"}
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(out["workload"], f"threads {args.threads}")
    print(f"load average before {out['load_before']}, after {out['load_after']}")
    for k, v in med.items():
        lo, hi = min(rates[k]), max(rates[k])
        print(f"{k:13s} {v / 1e6:8.3f} M agent-steps/s (range {lo / 1e6:.3f} to {hi / 1e6:.3f})")
    for k, v in out.get("vector_over", {}).items():
        print(f"vector / {k}: {v:.2f}x")


if __name__ == "__main__":
    main()
