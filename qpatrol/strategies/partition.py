"""``partition``: the map cut into K connected regions, each robot cycling its own.

:func:`qpatrol.maps.walks.partition_regions` cuts the map into K connected regions of
balanced walk length, once per map; each region gets its own short closed walk through
its targets (on a patrol graph a region is vertices plus the waypoints of its edges). Robots
are matched to regions nearest first, walk to the nearest cell of their region's walk
and cycle it. Battery trips take a robot out of its region; it comes back where it
left. Two robots that meet head-on exchange regions (see
:mod:`qpatrol.strategies.follow`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.maps import walks
from qpatrol.strategies import follow

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.world import Params


class Strategy(follow.WalkFollower):
    """One walk per region; ``labels`` int ``[C]`` is each cell's region."""

    name = "partition"

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        self.labels = walks.partition_regions(m, p.n_agents)
        region_walks = walks.region_walks(m, self.labels)
        super().__init__(cfg, m, p, start_cells, region_walks)
        for r in range(self.n_runs):
            self.wid[r] = match_regions(self.dist, self.labels, start_cells[r])
            for k in range(self.n_agents):
                w = region_walks[self.wid[r, k]]
                self.target[r, k] = follow.nearest_index(self.dist, w, int(start_cells[r, k]))
        self.start_spacing()

    def describe(self) -> dict[str, object]:
        return {"region_walk_lengths": [int(x) for x in self.length[0]]}


def match_regions(dist: np.ndarray, labels: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """int ``[K]``: the region of each robot, nearest (robot, region) pairs matched first."""
    k = starts.size
    cost = np.stack([dist[starts][:, labels == g].min(axis=1) for g in range(k)], axis=1)
    out = np.full(k, -1, dtype=np.int64)
    taken = np.zeros(k, dtype=bool)
    for flat in np.argsort(cost, axis=None, kind="stable"):
        a, g = divmod(int(flat), k)
        if out[a] < 0 and not taken[g]:
            out[a] = g
            taken[g] = True
    return out
