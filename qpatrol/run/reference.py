"""The paper's Q-learning in plain Python: dicts and lists, one run, K agents, no battery.

The yardstick of ``qpatrol bench``: what a straightforward implementation of §3 does
per agent-step, with no numpy in the loop. It follows the core's arithmetic to the bit
(greedy over open moves with ties and epsilon drawn from the run's uniforms, reward
``dot + incremental_value x min(1, idle / idle_horizon) + lambda x dots / visits``,
``Q <- Q + (1/N) (r + gamma max Q(s') - Q)``), so with the same uniforms and one agent
(or ``team.interaction: none``) it gives the core's Q-table. With more agents and
collisions avoided it moves robots in index order into cells empty at that moment (no
right of way), which is the same work per agent-step but not the core's traffic rules.
On a patrol graph with waypoints an agent chooses at vertices only, travels each edge
to its end, and learns each transition from its decision to the next vertex.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qpatrol.world import Params


@dataclass
class ReferenceResult:
    """What the loop leaves: ``q``/``n`` as dicts ``(agent, cell, heading) -> [D]`` (D
    ports: 4 on a grid)."""

    q: dict[tuple[int, int, int], list[float]]
    n: dict[tuple[int, int, int], list[int]]
    pos: list[int]
    steps: int

    def arrays(self, n_cells: int, n_agents: int, q_init: list[float]) -> tuple[np.ndarray, ...]:
        """``(q, n)`` as the core's ``[K, C, D, D]`` arrays (unvisited states at q_init,
        one value per port)."""
        d = len(q_init)
        q = np.broadcast_to(np.array(q_init, dtype=np.float64), (n_agents, n_cells, d, d)).copy()
        n = np.zeros((n_agents, n_cells, d, d), dtype=np.int64)
        for key, row in self.q.items():
            q[key] = row
        for key, row in self.n.items():
            n[key] = row
        return q, n


def run(
    p: Params,
    starts: list[int],
    u: np.ndarray,
    q_init: list[float],
    gamma: float,
    epsilon: float = 0.0,
    use_heading: bool = True,
) -> ReferenceResult:
    """Run one team for ``u.shape[0]`` steps.

    Args:
        p: the world's parameters (``p.battery`` is ignored: no battery here).
        starts: the K start cells.
        u: float ``[T, K, 2]``, the run's uniforms (``u[..., 0]`` explore, ``u[..., 1]``
            ties), as :class:`qpatrol.world.rng.Streams` draws them.
        q_init: the initial Q of each port (N, E, S, W on a grid; multiplier applied).
        gamma, epsilon: discount and exploration probability.
        use_heading: state ``(cell, heading)``; False: ``(cell, 0)``.
    """
    nbrs = p.neighbors.tolist()
    entry = p.entry.tolist()  # the heading after a move (Map.entry: the move on a grid)
    legal_dirs = [[d for d in range(len(row)) if row[d] >= 0] for row in nbrs]
    dot_value = p.dot_value.tolist()
    has_dot = p.has_dot.tolist()
    n_dots = sum(has_dot)
    k_agents = len(starts)
    groups = 1 if p.communication else k_agents
    inc, horizon, lam = p.incremental_value, p.idle_horizon, p.lambda_weight
    max_ep = p.max_episode_steps
    if p.interaction == "interference":
        raise ValueError("the plain-Python reference has no interference stops")
    avoid = p.avoid_collisions
    uu = u.tolist()
    pos = list(starts)
    head = [p.initial_heading] * k_agents
    occupied = {c: 1 for c in pos}
    dots = [list(has_dot) for _ in range(groups)]
    last = [[0] * p.n_cells for _ in range(groups)]
    dots_left = [n_dots] * groups
    ep_dots = [0] * groups
    ep_visits = [0] * groups
    ep_start = [0] * groups
    q: dict[tuple[int, int, int], list[float]] = {}
    n: dict[tuple[int, int, int], list[int]] = {}
    # a graph's waypoints: the port that continues the edge by heading (world.Params)
    onward = p.onward.tolist() if p.onward is not None else None
    vertex = p.target.tolist()
    pending: list[tuple[tuple[int, int, int], int] | None] = [None] * k_agents
    travelling = [False] * k_agents
    steps = len(uu)
    for t in range(1, steps + 1):
        ut = uu[t - 1]
        # choose: greedy over open moves (every legal one if none is open)
        want = [-1] * k_agents
        for k in range(k_agents):
            c = pos[k]
            travelling[k] = onward is not None and onward[c][head[k]] >= 0
            if travelling[k]:  # on an edge: on to its end, no choice
                want[k] = onward[c][head[k]]
                continue
            pending[k] = None  # (a decision not made good is dropped)
            s = (k, c, head[k] if use_heading else 0)
            row = q.get(s) or q_init
            legal = legal_dirs[c]
            if avoid:
                free = [d for d in legal if nbrs[c][d] not in occupied]
                if len(free) < len(legal) and free:
                    legal = free
            if not legal:
                continue
            if epsilon > 0.0 and ut[k][0] < epsilon:
                cand = legal
            else:
                best = max([row[d] for d in legal])
                cand = [d for d in legal if row[d] == best]
            j = min(int(ut[k][1] * len(cand)), len(cand) - 1)
            want[k] = cand[j]
        # move, reward, learn
        for k in range(k_agents):
            a = want[k]
            if a < 0:
                continue
            c0 = pos[k]
            c1 = nbrs[c0][a]
            if avoid:
                if c1 in occupied:
                    continue
                del occupied[c0]
                occupied[c1] = 1
            g = 0 if p.communication else k
            ate = dots[g][c1]
            if ate:
                dots[g][c1] = False
                dots_left[g] -= 1
                ep_dots[g] += 1
            ep_visits[g] += 1
            idle = t - last[g][c1]
            last[g][c1] = t
            reward = (
                (dot_value[c1] if ate else 0.0)
                + inc * min(1.0, idle / horizon)
                + lam * ep_dots[g] / ep_visits[g]
            )
            pos[k] = c1
            s = (k, c0, head[k] if use_heading else 0)
            head[k] = h = entry[c0][a]
            if not travelling[k]:
                pending[k] = (s, a)
            if not vertex[c1] or pending[k] is None:
                continue  # a waypoint is no state: the transition goes on
            (s, a), pending[k] = pending[k], None
            nxt = q.get((k, c1, h if use_heading else 0)) or q_init
            bootstrap = gamma * max([nxt[d] for d in legal_dirs[c1]])
            target = reward + bootstrap
            qs = q.get(s)
            if qs is None:
                qs = q[s] = list(q_init)
                n[s] = [0] * len(q_init)
            ns = n[s]
            ns[a] += 1
            alpha = 1.0 / ns[a]
            qs[a] = qs[a] + alpha * (target - qs[a])
        # episodes: all dots eaten, or too long
        for g in range(groups):
            if dots_left[g] == 0 or (max_ep and t - ep_start[g] >= max_ep):
                dots[g] = list(has_dot)
                dots_left[g] = n_dots
                ep_dots[g] = ep_visits[g] = 0
                ep_start[g] = t
    return ReferenceResult(q=q, n=n, pos=pos, steps=steps)
