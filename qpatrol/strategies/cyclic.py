"""``cyclic`` (Chevaleyre 2004): the whole team on one short closed walk, evenly spaced.

One closed walk through every target (every free cell of a grid, every vertex of a patrol
graph), as short as :func:`qpatrol.maps.walks.closed_walk` can make it, is computed once
per map. Robot slots are spaced ``L / K`` apart along it
(moved forward to the next distinct target that is not a station, if needed), robots are
matched to slots nearest first, walk to them and wait there until the whole team has
gathered (or ``3 x diameter`` steps have passed); then every robot advances one cell
per step. With K robots and no disturbance every target is visited every ``L / K`` steps,
the bound reported beside the results. Battery trips and yielding shift robots; each
rejoins the walk where it left it, and each robot keeps its slot's distance behind the
next robot ahead by waiting, so that the spacing comes back (see
:mod:`qpatrol.strategies.follow`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.maps import search, walks
from qpatrol.strategies import follow
from qpatrol.world.battery import GONE

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.world import Observation, Params


class Strategy(follow.WalkFollower):
    """One walk for all; ``hold`` until the team has gathered on its slots."""

    name = "cyclic"

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        walk = walks.closed_walk(m)
        super().__init__(cfg, m, p, start_cells, [walk])
        self.bound = walks.closed_walk_lower_bound(m)
        self.methods = walks.closed_walk_methods(m)
        # slots on targets that are not stations (robots wait only on targets)
        slots = slot_indices(walk, p.n_agents, (p.station_of >= 0) | ~p.target)
        for r in range(self.n_runs):
            self.target[r] = match_slots(self.dist, walk, slots, start_cells[r], m.neighbors)
        self.hold[:] = True
        self.start_spacing()
        self.gather_until = 3 * p.diameter

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        if self.hold.any():
            # the team: the robots that have not failed (qpatrol.world.failures)
            here = (obs.state.pos == self.goal_cells()) | (obs.state.mode == GONE)
            gathered = here.all(axis=1)
            if obs.t > self.gather_until:
                gathered[:] = True
            self.hold[gathered] = False
        return super().act(obs, u)

    def describe(self) -> dict[str, object]:
        L = int(self.length[0, 0])
        return {
            "walk_length": L,
            "walk_lower_bound": int(self.bound),
            **getattr(self, "methods", {}),
            "walk_per_robot": L / self.n_agents,
        }


def slot_indices(walk: np.ndarray, k: int, is_station: np.ndarray) -> np.ndarray:
    """int ``[k]``: walk indices ``i L / k``, each moved forward to a distinct cell that
    ``is_station`` (bool ``[C]``: the cells no slot may take) does not mark."""
    L = walk.size
    used: set[int] = set()
    out = []
    for i in range(k):
        idx = (i * L) // k
        for _ in range(L):
            c = int(walk[idx])
            if c not in used and not is_station[c]:
                break
            idx = (idx + 1) % L
        used.add(int(walk[idx]))
        out.append(idx)
    return np.array(out, dtype=np.int64)


def match_slots(
    dist: np.ndarray | None,
    walk: np.ndarray,
    slots: np.ndarray,
    starts: np.ndarray,
    neighbors: np.ndarray | None = None,
) -> np.ndarray:
    """int ``[K]``: the slot (walk index) of each robot, nearest pairs matched first
    (without a table, ``dist`` None, by a search from each robot over ``neighbors``)."""
    if dist is None:
        cost = np.stack([search.bfs(neighbors, int(c))[walk[slots]] for c in starts])
    else:
        cost = dist[starts][:, walk[slots]]  # [K robots, K slots]
    out = np.full(starts.size, -1, dtype=np.int64)
    taken = np.zeros(slots.size, dtype=bool)
    for flat in np.argsort(cost, axis=None, kind="stable"):
        k, i = divmod(int(flat), slots.size)
        if out[k] < 0 and not taken[i]:
            out[k] = slots[i]
            taken[i] = True
    return out
