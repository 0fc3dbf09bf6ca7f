"""PettingZoo and Gymnasium environments over qpatrol's world (``pip install -e ".[envs]"``).

* :class:`PatrolParallelEnv`: the whole team, one PettingZoo agent per robot.
* :class:`PatrolEnv`: one robot as a Gymnasium env, alone or with teammates driven by a
  qpatrol strategy; registered as ``"qpatrol/Patrol-v0"`` for ``gymnasium.make``.
* :class:`PatrolVectorEnv`: B runs stepped together on the compiled world, arrays
  ``[B, K, ...]`` (PettingZoo's parallel API batched); :class:`PatrolGymVectorEnv`:
  the same as a ``gymnasium.vector.VectorEnv`` of ``B x K`` robots.

Both run one run of :mod:`qpatrol.world` under the rules of ``qpatrol train`` and give
``env.unwrapped.metrics()`` from :mod:`qpatrol.measures`. See ``docs/envs.md``. The
core of qpatrol never imports this package, so the base install works without
pettingzoo and gymnasium.
"""

from __future__ import annotations

import gymnasium

from qpatrol.envs.observe import FEATURES
from qpatrol.envs.parallel import PatrolParallelEnv
from qpatrol.envs.single import PatrolEnv
from qpatrol.envs.vector import PatrolGymVectorEnv, PatrolVectorEnv

__all__ = ["FEATURES", "PatrolEnv", "PatrolGymVectorEnv", "PatrolParallelEnv", "PatrolVectorEnv"]

GYM_ID = "qpatrol/Patrol-v0"
if GYM_ID not in gymnasium.registry:
    gymnasium.register(id=GYM_ID, entry_point="qpatrol.envs.single:PatrolEnv")
