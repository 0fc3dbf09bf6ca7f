"""``shared-conscientious``: go to the neighbour the *team* visited longest ago.

The same rule as ``conscientious``, over the team's shared last-visit map (with
``team.communication: off`` each robot only has its own map, and the two coincide). On
a patrol graph: at a vertex, the port whose far vertex the map says was visited
longest ago.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.strategies import base

if TYPE_CHECKING:
    from qpatrol.world import Observation


class Strategy(base.Strategy):
    """Reads the world's last-visit map of the robot's group; no state of its own."""

    name = "shared-conscientious"

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        seen = base.neighbour_values(obs.state.last, obs, per_group=True)
        return base.choose_min(seen.astype(np.float64), base.prefer_open(obs), u[..., 1])
