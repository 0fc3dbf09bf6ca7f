"""``random``: each step a uniformly random move among the open ones (a lower baseline).

Open moves are those not into a wall nor into a cell another robot stands in; a robot
hemmed in picks among all its non-wall moves, so that the world can make room for it.
On a patrol graph it picks among a vertex's ports and travels the edge to its end.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.strategies import base

if TYPE_CHECKING:
    from qpatrol.world import Observation


class Strategy(base.Strategy):
    """Uniform over the open moves; no state."""

    name = "random"

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        return base.choose_min(np.zeros(obs.legal.shape), base.prefer_open(obs), u[..., 1])
