"""``PatrolEnv``: one patrol robot as a Gymnasium ``Env``, alone or in a qpatrol team."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from qpatrol import strategies
from qpatrol.config import Config
from qpatrol.envs import observe, render
from qpatrol.envs.parallel import RENDER_MODES, _direction
from qpatrol.envs.sim import Sim, WorldView, make_config


class PatrolEnv(WorldView, gymnasium.Env):
    """Robot ``agent`` of a patrol team; the others, if any, run a qpatrol strategy.

    Args:
        config, overrides, map, max_steps, idleness_map, render_mode: as
            :class:`~qpatrol.envs.PatrolParallelEnv`.
        agents: robots in the team (shortcut for ``agents=...``); with ``teammates``
            None it must be None or 1.
        teammates: None (the robot patrols alone: ``agents`` is set to 1), or a policy
            name of :data:`qpatrol.strategies.NAMES` (``"conscientious"``,
            ``"qlearning"``, ...) that drives the other robots. The strategy is made
            afresh at each reset and acts on the same uniforms as in ``train``; it is
            asked for every robot and its choice for ``agent`` is replaced by the
            action (a learning strategy learns from every robot's outcome).
        agent: which robot is controlled (0..K-1).

    Observation, action, action mask (``info["action_mask"]``), reward, termination,
    truncation and seeding are those of the controlled robot in
    :class:`~qpatrol.envs.PatrolParallelEnv`.
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 10}

    def __init__(
        self,
        config: str | Path | Config | None = None,
        overrides: Iterable[str] = (),
        *,
        map: str | None = None,
        agents: int | None = None,
        teammates: str | None = None,
        agent: int = 0,
        max_steps: int | None = None,
        idleness_map: bool = False,
        render_mode: str | None = None,
    ):
        self.render_mode = render.check_mode(render_mode)
        if teammates is None:
            if agents is not None and agents != 1:
                raise ValueError(
                    f"agents: got {agents!r} with teammates=None; allowed: 1 (a robot alone), "
                    f"or name a teammates strategy ({', '.join(strategies.NAMES)})"
                )
            agents = 1
        elif teammates not in strategies.NAMES:
            raise ValueError(
                f"teammates: got {teammates!r}; allowed: None or one of "
                f"{', '.join(strategies.NAMES)}"
            )
        self.config = make_config(config, overrides, map, agents)
        self.sim = Sim(self.config, max_steps)
        k = self.sim.n_agents
        if isinstance(agent, bool) or not isinstance(agent, int | np.integer):
            raise TypeError(f"agent: expected an int, got {agent!r}")
        if not 0 <= agent < k:
            raise ValueError(f"agent: got {agent}; allowed: 0..{k - 1} (the team has {k})")
        self.agent = int(agent)
        self.teammates = teammates
        self.team: strategies.base.Strategy | None = None
        self.idleness_map = bool(idleness_map)
        self.observation_space = observe.space(self.sim, self.idleness_map)
        self.action_space = spaces.Discrete(self.sim.map.n_ports)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict]:
        """Start a run; ``options={"run": r}`` picks the run index (other keys ignored)."""
        super().reset(seed=seed)
        self.sim.reset(seed, None if options is None else options.get("run"))
        if self.teammates is not None:
            sim = self.sim
            self.team = strategies.make(
                self.teammates, self.config, sim.map, sim.params, sim.starts
            )
        return self._observation(), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        sim = self.sim
        if not sim.started:
            raise RuntimeError("call reset() before step()")
        if self.team is not None:
            choice = self.team.act(sim.obs, sim.uniforms[None])[0].copy()
        else:
            choice = np.full(sim.n_agents, -1, dtype=np.int64)
        choice[self.agent] = _direction(action, f"agent {self.agent}", sim.map.n_ports)
        out = sim.step(choice)
        if self.team is not None:
            self.team.learn(out)
        reward = float(out.reward[0, self.agent])
        return self._observation(), reward, sim.terminated, sim.truncated, self._info()

    def _observation(self) -> np.ndarray:
        sim = self.sim
        return observe.observe(sim.state, sim.params, sim.map.coords, self.idleness_map)[self.agent]

    def _info(self) -> dict:
        return observe.infos(self.sim)[self.agent]

    def render(self) -> np.ndarray | str | None:
        """The current picture in ``render_mode`` (None without one)."""
        if self.render_mode is None or not self.sim.started:
            return None
        return render.picture(self.sim.map, self.sim.params, self.sim.state, self.render_mode)
