"""``conscientious`` (Machado et al. 2002): go to the neighbour *I* visited longest ago.

Each robot keeps its own memory of when it last entered each cell (never: step 0) and
moves to the open neighbour with the oldest entry, ties broken by the run's stream. It
remembers every cell it enters, on patrol, pushed aside or on its way home. On a
patrol graph it chooses at vertices only, among its ports by its memory of the vertex
at each port's far end.
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
    """``memory``: int ``[R, K, C]``, the step at which robot k last entered cell c."""

    name = "conscientious"

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.memory = np.zeros((self.n_runs, self.n_agents, p.n_cells), dtype=np.int64)

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        seen = base.neighbour_values(self.memory, obs, per_group=False)
        return base.choose_min(seen.astype(np.float64), base.prefer_open(obs), u[..., 1])

    def learn(self, out: Outcome, rec: Recorder | None = None) -> None:
        rr, kk = np.nonzero(out.moved)
        self.memory[rr, kk, out.pos[rr, kk]] = out.t
