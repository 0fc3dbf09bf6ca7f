"""``sebs`` (Portugal and Rocha 2013, State Exchange Bayesian Strategy): ``gbs`` with the
robots' intentions.

Each robot's goal is its announced intention. A candidate target that ``n > 0`` other
robots of the team have as their goal has its posterior multiplied by
``2^(K - n) / (2^K - 1)`` (patrolling_sim's ``state_exchange_bayesian_strategy``, K the
team's size). Robots decide in robot order, so a robot sees the goals chosen before it
in the same step. With ``team.communication: off`` no intention is exchanged and the
rule is ``gbs``'s.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from qpatrol.strategies import gbs

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.world import Observation, Params


def state_factors(n_agents: int) -> np.ndarray:
    """float64 ``[K + 1]``: the posterior's factor for n other robots intending a target
    (1 for none)."""
    f = [1.0] + [
        math.ldexp(1.0, n_agents - n) / (math.ldexp(1.0, n_agents) - 1.0)
        for n in range(1, n_agents + 1)
    ]
    return np.array(f, dtype=np.float64)


class Strategy(gbs.Strategy):
    """``gbs`` scores times the intention factor; ``factor`` ``[K + 1]``."""

    name = "sebs"

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.factor = state_factors(self.n_agents)

    def scores(
        self, obs: Observation, k: int, rows: np.ndarray, c: np.ndarray, allowed: np.ndarray
    ) -> np.ndarray:
        pp = super().scores(obs, k, rows, c, allowed)
        if not obs.params.communication:
            return pp
        others = np.delete(self.goal[rows], k, axis=1)  # [B, K - 1]
        far = self.tnbr[c]  # [B, D]
        count = ((far[:, :, None] == others[:, None, :]) & (far[:, :, None] >= 0)).sum(axis=2)
        return pp * self.factor[count]
