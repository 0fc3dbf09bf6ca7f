"""Tabular Q-learning through the PettingZoo API on map A, then the patrol measures.

Each robot learns its own table ``Q[cell, heading, action]`` from nothing but what the
PettingZoo API gives it: the observation (cell and heading are its first features,
walls show as -1 among the neighbour features), ``infos[agent]["action_mask"]`` and
the reward. It acts greedily inside the mask (ties broken at random, a few random
moves with probability ``epsilon``) and, like the paper's learner, updates only after
a move it chose and made (``info["as_asked"]``), with ``alpha = 1/N(s, a)``.

Run: ``python examples/pettingzoo_qlearning.py [steps]`` (needs ``pip install -e ".[envs]"``).
It prints the idleness measured by ``env.unwrapped.metrics()`` (qpatrol's own
measures) next to ``qpatrol train``'s Q-learning on the same config and seed.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from qpatrol.envs import PatrolParallelEnv

CONFIG = "paper"  # map_a, 4 robots, battery on, communication on
GAMMA = 0.1
Q_INIT = np.array([3.0, 2.0, 1.0, 2.0]) * 100  # N, E, S, W, as the paper's learner


def main(steps: int = 5000, seed: int = 2012, epsilon: float = 0.02) -> dict:
    """Train for ``steps`` team steps; return ``metrics()`` (avg_idleness, ...)."""
    env = PatrolParallelEnv(CONFIG, ["runs=1"], max_steps=steps)
    obs, infos = env.reset(seed=seed)
    n_cells = env.unwrapped.params.n_cells
    rng = np.random.default_rng(seed)
    q = {a: np.broadcast_to(Q_INIT, (n_cells, 4, 4)).copy() for a in env.possible_agents}
    n = {a: np.zeros((n_cells, 4, 4), dtype=np.int64) for a in env.possible_agents}
    while env.agents:
        actions, before = {}, {}
        for a in env.agents:
            mask = infos[a]["action_mask"].astype(bool)
            if not mask.any():  # the world is moving this robot (battery): no choice
                continue
            cell, heading = int(obs[a][0]), int(obs[a][3])
            if rng.random() < epsilon:
                best = np.flatnonzero(mask)
            else:
                row = np.where(mask, q[a][cell, heading], -np.inf)
                best = np.flatnonzero(row == row.max())
            actions[a] = int(rng.choice(best))
            before[a] = (cell, heading)
        obs, rewards, _, _, infos = env.step(actions)
        for a, (cell, heading) in before.items():
            if not infos[a]["as_asked"]:
                continue  # blocked or pushed aside: no update, as in the paper
            act = actions[a]
            nxt, nxt_head = int(obs[a][0]), int(obs[a][3])
            legal = obs[a][6:14:2] >= 0  # a neighbour's dot feature is -1 behind a wall
            target = rewards[a] + GAMMA * q[a][nxt, nxt_head][legal].max()
            n[a][cell, heading, act] += 1
            q[a][cell, heading, act] += (target - q[a][cell, heading, act]) / n[a][
                cell, heading, act
            ]
    return env.unwrapped.metrics()


def reference(steps: int, seed: int) -> dict:
    """``qpatrol train``'s own Q-learning on the same config and seed (run 0)."""
    from qpatrol.config import load_config
    from qpatrol.run import simulate

    cfg = load_config(CONFIG, ["runs=1", f"steps={steps}", f"seed={seed}"])
    return simulate(cfg).summary[0]


if __name__ == "__main__":
    steps = int(sys.argv[1]) if len(sys.argv) > 1 else 5000
    t0 = time.perf_counter()
    m = main(steps)
    dt = time.perf_counter() - t0
    print(f"PettingZoo Q-learner, map_a, 4 robots, {steps} steps ({steps / dt:,.0f} steps/s)")
    print(
        f"  avg idleness {m['avg_idleness']:.1f}  worst {m['worst_idleness']}  "
        f"mean interval {m['mean_interval']:.1f}  coverage {m['coverage']:.2f}"
    )
    r = reference(steps, 2012)
    print(
        f"qpatrol train (same config and seed): avg idleness {r['avg_idleness']:.1f}  "
        f"worst {r['worst_idleness']}  coverage {r['coverage']:.2f}"
    )
