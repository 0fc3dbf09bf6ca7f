"""How fast can any numpy step of lone Q-learners be here? A floor, next to the engine.

    .venv/bin/python benchmarks/numpy_floor.py [--runs 2048] [--steps 2000] [--repeat 3]

The issue asks the numpy engine for 8 M agent-steps/s at 2,048 runs x 1 robot, that is
one team step of all 2,048 runs in 256 us. This script times, in one process and in
alternation (this machine's speed drifts):

* **engine**: the numpy engine's steady step (:mod:`qpatrol.engines.numpy_solo`), from
  two :func:`qpatrol.run.simulate` of ``qpatrol bench``'s workload (map_a, 1 robot,
  battery off), one of ``--steps`` and one of 10 steps: the difference divided by the
  difference of steps, so the setup of the runs and their summaries drop out;
* **floor**: a model step with the fewest memory touches a lone learner's step needs,
  on map_a's own moves, from the learner's own optimistic start (so its robots spread
  over the map as the engine's do: ``tests/test_benchmarks.py`` checks it). Not
  qpatrol's arithmetic to the bit, and no episodes: a cost model. It reads the uniforms
  of a step from one contiguous row, keeps the moves into walls at -inf in the Q table
  (no masking), reads a run's record of the cell entered (last visit, visit count, dot
  and seen flags: 32 bytes, one cache line) and writes it back, reads Q(s', .) (the
  next state's row) and N(s, a), and keeps Q(s, .) from the step before: about 55
  numpy operations (ufuncs, takes and index assignments), where the engine's step has
  about 60;
* **floor, tables shared**: the same operations on the same number of values, but
  every run indexes the tables of run 0 (results meaningless), so the tables sit in
  the caches: what the operations cost without the misses;
* **floor, Q and N in a line**: the floor with N(s, .) beside Q(s, .) in one 64-byte
  row, so N(s, a) comes with the row read a step before (one cache miss less per step,
  a few operations more).

Prints one line per measure (the best of ``--repeat``, in us per team step and M
agent-steps/s); ``--json`` prints them as one object.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from qpatrol import bench
from qpatrol.engines.flat import CODE_MOD, COUNT_OF_CODE, NTH_OF_CODE
from qpatrol.run import prepare, simulate


def engine_step_us(runs: int, steps: int) -> tuple[float, float]:
    """``(us, cells)``: us per team step of the numpy engine's steady loop (setup and
    summary excluded), and the mean number of cells a run's robot visited."""
    short = 10
    times = {}
    for n in (short, steps):
        cfg = bench.workload(runs, 1, n, "numpy", threads=1)
        prepared = prepare(cfg)
        t = time.perf_counter()
        result = simulate(cfg, prepared=prepared)
        times[n] = time.perf_counter() - t
    cells = float((result.measures.visits.sum(axis=1) > 0).sum(axis=1).mean())
    return (times[steps] - times[short]) / (steps - short) * 1e6, cells


def floor_step_us(
    runs: int, steps: int, shared: bool, one_line: bool = False, seed: int = 0
) -> tuple[float, float]:
    """``(us, cells)``: us per team step of the model step (see the module's docstring),
    and the mean number of cells a run's robot visited (its tables shared: run 0's).
    ``one_line``: N(s, .) beside Q(s, .) in one 64-byte row, so that N(s, a) is read
    with Q(s, .) a step before."""
    m, p = prepare(bench.workload(runs, 1, steps, "numpy"))
    c = p.n_cells
    rng = np.random.default_rng(seed)
    nbrs = p.neighbors.reshape(-1)  # int [C 4]: next cell, -1 for a wall
    legal = p.wall_legal
    size = 1 if shared else runs
    cfg = bench.workload(runs, 1, steps, "numpy")
    q_init = np.array([cfg[f"learning.q_init.{d}"] for d in ("north", "east", "south", "west")])
    q_init *= cfg["learning.multiplier"]  # the learner's optimistic start: it explores
    gamma = cfg["learning.gamma"]
    q = np.where(legal, q_init, -np.inf)[None, :, None, :].repeat(size, 0).repeat(4, 2)
    q = q.reshape(-1, 4)  # float [R C 4, 4]: Q(s, .), walls -inf
    if one_line:  # float [R C 4, 8]: Q(s, .) then N(s, .)
        q = np.concatenate([q, np.zeros_like(q)], axis=1)
        ar8 = np.arange(runs) * 8
    q1 = q.reshape(-1)
    n = np.zeros(size * c * 16, dtype=np.int32)  # int32 [R C 4 4]: N(s, a)
    record = np.zeros((size * c, 4), dtype=np.int64)  # last, visits, flags, (unused)
    first_row = np.arange(runs) * (c * 4) * (not shared)  # int [R]
    first_cell = np.arange(runs) * c * (not shared)
    count = COUNT_OF_CODE.astype(np.float64)
    dot_value = p.dot_value
    pos = rng.integers(0, c, runs)
    head = np.zeros(runs, dtype=np.int64)
    row = first_row + pos * 4 + head
    block = q.take(row, axis=0)
    masked = block[:, :4]
    best = np.maximum(
        np.maximum(masked[:, 0], masked[:, 1]), np.maximum(masked[:, 2], masked[:, 3])
    )
    ep_dots = np.zeros(runs, dtype=np.int64)
    ep_visits = np.zeros(runs, dtype=np.int64)
    last_sum = np.zeros(runs, dtype=np.int64)
    gap_sum = np.zeros(runs, dtype=np.int64)
    worst = np.zeros(runs, dtype=np.int64)
    idle_total = np.zeros(runs, dtype=np.int64)
    u = rng.random((steps, runs))  # the uniforms of a step: one contiguous row
    start = time.perf_counter()
    for t in range(1, steps + 1):
        # choose: the best moves (walls are -inf), one of them by the step's uniform
        key = (masked == best[:, None]).view(np.uint32)[:, 0] % CODE_MOD
        j = (u[t - 1] * count.take(key)).astype(np.uint32)
        key *= 4
        key += j
        a = NTH_OF_CODE.take(key)
        ca = pos * 4
        ca += a
        c1 = nbrs.take(ca)
        gi = first_cell + c1
        # enter: one record of the cell entered, read and written back
        rec = record.take(gi, axis=0)
        idle = t - rec[:, 0]
        ate = (rec[:, 2] & 1) == 0
        rec[:, 0] = t
        rec[:, 1] += 1
        rec[:, 2] |= 3
        record[gi] = rec
        ep_dots += ate
        ep_visits += 1
        reward = ate * dot_value.take(c1)
        r = idle / p.idle_horizon
        np.minimum(r, 1.0, out=r)
        r *= p.incremental_value
        reward += r
        r = p.lambda_weight * ep_dots
        r /= ep_visits
        reward += r
        # learn: Q(s', .) read, Q(s, .) kept from the step before, N(s, a)
        row1 = first_row + c1 * 4 + a
        block1 = q.take(row1, axis=0)
        masked1 = block1[:, :4]
        best1 = np.maximum(
            np.maximum(masked1[:, 0], masked1[:, 1]), np.maximum(masked1[:, 2], masked1[:, 3])
        )
        target = gamma * best1
        target += reward
        if one_line:  # Q(s, a) and N(s, a) from the row read a step before
            k = ar8 + a
            flat = block.reshape(-1)
            q_sa = flat.take(k)
            k += 4
            n_sa = flat.take(k)
            n_sa += 1.0
            target -= q_sa
            target /= n_sa
            target += q_sa
            idx = row * 8
            idx += a
            q1[idx] = target
            idx += 4
            q1[idx] = n_sa
        else:
            idx = row * 4
            idx += a
            q_sa = q1.take(idx)
            n_sa = n.take(idx)
            n_sa += 1
            target -= q_sa
            target /= n_sa
            target += q_sa
            q1[idx] = target
            n[idx] = n_sa
        # measures: sums and maxima per run
        last_sum += idle
        gap_sum += idle
        np.maximum(worst, idle, out=worst)
        idle_total += c * t - last_sum
        pos, row, block, masked, best = c1, row1, block1, masked1, best1
    seconds = time.perf_counter() - start
    cells = float((record[:, 1].reshape(size, c) > 0).sum(axis=1).mean())
    return seconds / steps * 1e6, cells


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=2048)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=3, help="rounds; the best is printed")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    measures = {
        "engine": lambda: engine_step_us(args.runs, args.steps),
        "floor": lambda: floor_step_us(args.runs, args.steps, shared=False),
        "floor, tables shared": lambda: floor_step_us(args.runs, args.steps, shared=True),
        "floor, Q and N in a line": lambda: floor_step_us(
            args.runs, args.steps, shared=False, one_line=True
        ),
    }
    best = dict.fromkeys(measures, (float("inf"), 0.0))
    for _ in range(args.repeat):  # alternate the measures, round after round
        for name, f in measures.items():
            best[name] = min(best[name], f())
    out = {
        name: {"us_per_step": us, "agent_steps_per_s": args.runs / us * 1e6, "cells": cells}
        for name, (us, cells) in best.items()
    }
    if args.json:
        print(json.dumps({"runs": args.runs, "steps": args.steps, **out}))
        return
    print(
        f"{args.runs} runs x 1 robot, {args.steps} steps; 8 M agent-steps/s is "
        f"{args.runs / 8:.0f} us per step"
    )
    for name, v in out.items():
        print(
            f"  {name:26s} {v['us_per_step']:7.1f} us per step  "
            f"{v['agent_steps_per_s'] / 1e6:6.2f} M agent-steps/s  "
            f"(cells visited per run: {v['cells']:.0f})"
        )


if __name__ == "__main__":
    main()
