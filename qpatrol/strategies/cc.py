"""``cc`` (Almeida et al. 2004, Conscientious Cognitive): a goal anywhere on the map, the
target this robot visited longest ago, reached by a shortest path.

Each robot keeps its own record of when it last entered each cell (never: step 0), as
``conscientious`` does, a goal it handed on to the robot in its way counting as entered
then (:func:`qpatrol.world.traffic.hand_on`: the other robot serves it), and on its
goal (or without one) chooses the target of oldest record other than its own cell, ties
by the run's stream (the j-th tied target in cell order); see
:mod:`qpatrol.strategies.goals` for travel and held pockets.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.strategies import goals

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.measures.records import Recorder
    from qpatrol.world import Observation, Outcome, Params


class Strategy(goals.GoalFollower):
    """``memory``: int ``[R, K, C]``, the step at which robot k last entered cell c."""

    name = "cc"
    neighbour_goals = False

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.memory = np.zeros((self.n_runs, self.n_agents, p.n_cells), dtype=np.int64)

    def choose(
        self,
        obs: Observation,
        k: int,
        rows: np.ndarray,
        mask: np.ndarray,
        closed: np.ndarray,
        u: np.ndarray,
    ) -> np.ndarray:
        c, cells, cand = self.any_target(obs, k, rows)
        seen = np.where(cand, self.memory[rows, k], np.iinfo(np.int64).max)
        best = cand & (seen == seen.min(axis=1, keepdims=True))
        has = cand.any(axis=1)
        best[~has, 0] = True  # (no candidate: a placeholder, replaced by -1 below)
        return np.where(has, goals.pick_nth(best, u), -1)

    def learn(self, out: Outcome, rec: Recorder | None = None) -> None:
        goals.remember(self.memory, self.goal, out)
