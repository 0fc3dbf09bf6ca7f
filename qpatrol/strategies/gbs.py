"""``gbs`` (Portugal and Rocha 2013, Greedy Bayesian Strategy): at each target, the
neighbouring target of greatest posterior probability of a gain.

For a candidate port with far target of idleness ``I`` (the robot's group map, the
team's shared one with communication on) and ``L`` moves away, the gain is
``g = I / max(L, bayes.edge_min)`` and the posterior
``P = bayes.g1 x exp(ln(1 / bayes.g1) / bayes.g2 x g)`` for ``g < bayes.g2``, else 1
(patrolling_sim's ``greedy_bayesian_strategy``, its constants G1 = 0.1, G2 = 100,
edge_min = 1 the defaults). ``exp`` is the C library's (``math.exp``), the one the
compiled engine calls, so that both engines compare the same numbers.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from qpatrol.strategies import goals

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.world import Observation, Params

#: ``math.exp`` element by element (numpy's own ``exp`` may round differently).
_EXP = np.frompyfunc(math.exp, 1, 1)


def posterior(gain: np.ndarray, g1: float, coef: float, g2: float) -> np.ndarray:
    """float64, the shape of ``gain``: ``g1 exp(coef x gain)`` below ``g2``, else 1
    (``coef = ln(1 / g1) / g2``)."""
    below = gain < g2
    e = _EXP(np.where(below, coef * gain, 0.0)).astype(np.float64)
    return np.where(below, g1 * e, 1.0)


class Strategy(goals.GoalFollower):
    """Neighbour goals of greatest posterior; ``g1``, ``g2``, ``edge_min``: the keys."""

    name = "gbs"

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.g1 = float(cfg["bayes.g1"])
        self.g2 = float(cfg["bayes.g2"])
        self.edge_min = float(cfg["bayes.edge_min"])
        self.coef = math.log(1.0 / self.g1) / self.g2

    def scores(
        self, obs: Observation, k: int, rows: np.ndarray, c: np.ndarray, allowed: np.ndarray
    ) -> np.ndarray:
        far = np.maximum(self.tnbr[c], 0)
        idle = self.idleness(obs, k, rows, far).astype(np.float64)
        weight = np.maximum(self.tcost[c].astype(np.float64), self.edge_min)
        return posterior(idle / weight, self.g1, self.coef, self.g2)
