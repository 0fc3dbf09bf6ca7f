"""``evap``: ant-like patrol by pheromone evaporation (Chu, Glad, Simonin et al. 2007).

Each robot drops one unit of pheromone on every cell it enters; all pheromone loses
the share ``evap.evaporation`` every team step; a robot moves to the open neighbour
with the least pheromone, ties broken by the run's stream. On a patrol graph only
vertices are marked and read: at a vertex a robot takes the open port whose far vertex
(the other end of the edge) has the least pheromone. With communication on the
team shares one pheromone map, with it off each robot has its own.

Evaporation is applied lazily, exactly: a cell stores its amount and the step it was
last updated, and is read as ``amount x (1 - evaporation) ** (t - step)``, so no step
touches the whole map.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.strategies import base

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.measures.records import Recorder
    from qpatrol.world import Observation, Outcome, Params


class Strategy(base.Strategy):
    """``amount``, ``since``: ``[R, G, C]``, pheromone and the step it was last updated."""

    name = "evap"

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.keep = 1.0 - float(cfg["evap.evaporation"])
        shape = (self.n_runs, p.n_groups, p.n_cells)
        self.amount = np.zeros(shape)
        self.since = np.zeros(shape, dtype=np.int64)

    def pheromone(self, t: int) -> np.ndarray:
        """float ``[R, G, C]``: the pheromone at step ``t``."""
        return self.amount * self.keep ** (t - self.since)

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        t = obs.t - 1  # pheromone as the step starts
        amount = base.neighbour_values(self.amount, obs, per_group=True)
        since = base.neighbour_values(self.since, obs, per_group=True)
        level = amount * self.keep ** (t - since)
        return base.choose_min(level, base.prefer_open(obs), u[..., 1])

    def learn(self, out: Outcome, rec: Recorder | None = None) -> None:
        for k in range(self.n_agents):
            # only decision points are marked: every grid cell, a graph's vertices
            rows = np.flatnonzero(out.moved[:, k] & self.params.target[out.pos[:, k]])
            if rows.size == 0:
                continue
            g = 0 if self.params.communication else k
            c = out.pos[rows, k]
            now = self.amount[rows, g, c] * self.keep ** (out.t - self.since[rows, g, c])
            self.amount[rows, g, c] = now + 1.0
            self.since[rows, g, c] = out.t
