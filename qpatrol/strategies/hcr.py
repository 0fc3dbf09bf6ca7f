"""``hcr`` (Almeida et al. 2004; patrolling_sim's Heuristic Conscientious Reactive): at each
target, the neighbouring target of greatest normalised idleness plus normalised nearness.

Among the candidate ports (:mod:`qpatrol.strategies.goals`), with ``I`` the idleness of
the far target on the robot's group map (the team's shared one with communication on)
and ``L`` the moves to it, the score is ``(L_max - L) / L_max + I / I_max`` (the idleness
term 0 when ``I_max`` is 0), maxima over the candidates: patrolling_sim's
``heuristic_conscientious_reactive``. On a grid every ``L`` is 1 and it is the
idlest neighbour.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.strategies import goals

if TYPE_CHECKING:
    from qpatrol.world import Observation


class Strategy(goals.GoalFollower):
    """Neighbour goals scored by normalised idleness and nearness."""

    name = "hcr"

    def scores(
        self, obs: Observation, k: int, rows: np.ndarray, c: np.ndarray, allowed: np.ndarray
    ) -> np.ndarray:
        far = np.maximum(self.tnbr[c], 0)
        idle = np.where(allowed, self.idleness(obs, k, rows, far), 0)
        cost = np.where(allowed, self.tcost[c], 0)
        i_max = idle.max(axis=1, keepdims=True)
        c_max = cost.max(axis=1, keepdims=True)
        near = (c_max - cost).astype(np.float64) / c_max.astype(np.float64)
        ratio = idle.astype(np.float64) / np.maximum(i_max, 1).astype(np.float64)
        return near + np.where(i_max == 0, 0.0, ratio)
