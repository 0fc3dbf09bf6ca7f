"""``PatrolParallelEnv``: the patrol world as a PettingZoo ``ParallelEnv`` (one run)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from qpatrol.config import Config
from qpatrol.envs import observe, render
from qpatrol.envs.sim import Sim, WorldView, make_config

RENDER_MODES = render.RENDER_MODES


class PatrolParallelEnv(WorldView, ParallelEnv):
    """A team of patrol robots, one PettingZoo agent each (``agent_0`` .. ``agent_{K-1}``).

    The world is qpatrol's own (:mod:`qpatrol.world`): the same maps, rewards, battery,
    collision and communication rules as ``qpatrol train``, for one run (``runs`` in
    the config is ignored).

    Args:
        config: a YAML path or shipped config name (``"paper"``), a
            :class:`~qpatrol.config.Config`, or None for the defaults.
        overrides: ``KEY=VALUE`` strings, as ``qpatrol train --set``.
        map: shortcut for the override ``map=...`` (a map name or file).
        agents: shortcut for ``agents=...``.
        max_steps: team steps after which every agent is truncated (default: the
            config's ``steps``).
        idleness_map: append the idleness of every cell to each observation.
        render_mode: None, ``"rgb_array"`` (uint8 ``[rows x 8, cols x 8, 3]``) or
            ``"ansi"`` (text).

    Observation: float32 ``[14]`` (``[14 + C]`` with ``idleness_map``), layout in
    :mod:`qpatrol.envs.observe`: the robot's cell, row, col, heading, battery and mode,
    then dot and idleness of its N, E, S, W neighbours (-1 for a wall).

    Action: ``Discrete(4)``, 0..3 = N, E, S, W (``Discrete(D)``, the cell's ports, on a
    patrol graph). ``infos[agent]["action_mask"]`` (int8 ``[4]``, ``[D]``) marks the
    moves qpatrol's strategies choose from: the open moves (not into a wall, a cell
    another robot stands in, or a station pocket another robot holds), or every non-wall
    move when none is open. A move outside the mask is still applied by the world's
    rules (into a wall: the robot stays; into a robot: it waits, or the robot with right
    of way pushes). When the world moves the robot itself (homing, queued or charging:
    ``infos[agent]["choosing"]`` False) the mask is all zero and the action is ignored;
    an agent missing from the action dict, or given None, asks for
    no move.

    Reward: the world's reward for the cell the robot entered in the step (dot, idleness
    and lambda terms, ``docs/model.md``), 0 if it did not move.

    Episodes: patrolling does not end when the dots are eaten: the world starts the next
    dot episode at once (``infos[agent]["episode_ended"]``). Every agent is *truncated*
    after ``max_steps`` team steps, and *terminated* when the run's episode quota
    (``episodes`` in the config) is met; then ``agents`` is empty until ``reset``.

    Seeding: ``reset(seed=s, options={"run": r})`` starts run ``r`` (default 0) of root
    seed ``s``, the stream ``SeedSequence(s, spawn_key=(0, r))`` that run ``r`` of
    ``qpatrol train`` with ``seed: s`` uses. ``reset()`` without a seed starts the next
    run of the last seed (first: the config's ``seed``, run 0). :attr:`uniforms` are
    the uniforms of the step about to be taken, as ``train`` gives them to its strategy.
    """

    metadata = {
        "name": "qpatrol_patrol_v0",
        "render_modes": list(RENDER_MODES),
        "render_fps": 10,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        config: str | Path | Config | None = None,
        overrides: Iterable[str] = (),
        *,
        map: str | None = None,
        agents: int | None = None,
        max_steps: int | None = None,
        idleness_map: bool = False,
        render_mode: str | None = None,
    ):
        self.render_mode = render.check_mode(render_mode)
        self.config = make_config(config, overrides, map, agents)
        self.sim = Sim(self.config, max_steps)
        self.idleness_map = bool(idleness_map)
        k = self.sim.n_agents
        self.possible_agents = [f"agent_{i}" for i in range(k)]
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self.observation_spaces = {
            a: observe.space(self.sim, self.idleness_map) for a in self.possible_agents
        }
        self.action_spaces = {
            a: spaces.Discrete(self.sim.map.n_ports) for a in self.possible_agents
        }

    def observation_space(self, agent: str) -> spaces.Box:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Discrete:
        return self.action_spaces[agent]

    # --- the PettingZoo API -------------------------------------------------------------
    def reset(
        self, seed: int | None = None, options: Mapping[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        """Start a run; ``options={"run": r}`` picks the run index (other keys ignored)."""
        run_index = None if options is None else options.get("run")
        self.sim.reset(seed, run_index)
        self.agents = list(self.possible_agents)
        return self._observations(), self._infos()

    def step(self, actions: Mapping[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if not self.sim.started:
            raise RuntimeError("call reset() before step()")
        if not self.agents:
            return {}, {}, {}, {}, {}
        choice = np.full(self.sim.n_agents, -1, dtype=np.int64)
        for agent, action in actions.items():
            if agent not in self._index:
                raise ValueError(f"actions: unknown agent {agent!r}; allowed: {self.agents}")
            if action is not None:
                choice[self._index[agent]] = _direction(action, agent, self.sim.map.n_ports)
        out = self.sim.step(choice)
        live = self.agents
        obs = self._observations()
        rewards = {a: float(out.reward[0, self._index[a]]) for a in live}
        term, trunc = self.sim.terminated, self.sim.truncated
        terminations = dict.fromkeys(live, term)
        truncations = dict.fromkeys(live, trunc)
        infos = self._infos()
        if term or trunc:
            self.agents = []
        return obs, rewards, terminations, truncations, infos

    def _observations(self) -> dict[str, np.ndarray]:
        vec = observe.observe(
            self.sim.state, self.sim.params, self.sim.map.coords, self.idleness_map
        )
        return {a: vec[self._index[a]] for a in self.agents}

    def _infos(self) -> dict[str, dict]:
        per = observe.infos(self.sim)
        return {a: per[self._index[a]] for a in self.agents}

    def render(self) -> np.ndarray | str | None:
        """The current picture in ``render_mode`` (None without one)."""
        if self.render_mode is None or not self.sim.started:
            return None
        return render.picture(self.sim.map, self.sim.params, self.sim.state, self.render_mode)

    def close(self) -> None:
        """Nothing to release."""


def _direction(action: Any, who: str, n_ports: int = 4) -> int:
    """An action as a direction 0..3 (a port 0..n_ports-1 on a patrol graph);
    ValueError for anything else."""
    allowed = "0..3 (N, E, S, W)" if n_ports == 4 else f"0..{n_ports - 1} (the cell's ports)"
    try:
        a = int(action)
    except (TypeError, ValueError):
        raise ValueError(f"action of {who}: got {action!r}; allowed: {allowed}") from None
    if a != action or not 0 <= a < n_ports:
        raise ValueError(f"action of {who}: got {action!r}; allowed: {allowed}")
    return a
