"""Batched environments: B runs of one config on the compiled world, arrays ``[B, K, ...]``.

* :class:`PatrolVectorEnv`: the team of every run, PettingZoo's parallel API batched:
  agents ``agent_0 .. agent_{K-1}`` (``possible_agents``, ``observation_space(agent)``,
  ``action_space(agent)`` as in PettingZoo), with each per-agent dict replaced by an
  agent axis: observations ``[B, K, F]``, actions ``[B, K]``, rewards, terminations,
  truncations ``[B, K]``, infos a dict of arrays (``action_mask`` ``[B, K, D]``).
  :meth:`PatrolVectorEnv.agent_dict` gives any of them as PettingZoo's ``{agent:
  array [B, ...]}`` (views, no copy).
* :class:`PatrolGymVectorEnv`: ``gymnasium.vector.VectorEnv`` with one robot per
  sub-environment: ``num_envs = B x K`` (``B`` with ``agents=1``: one robot per run),
  the form single-agent libraries and parameter-shared learners take.

Both step :class:`~qpatrol.envs.batch.Batch` (the world's rules, interaction models,
batteries and failures exactly as ``train``) and write their arrays in place: the
arrays returned are the env's own buffers, valid until the next call (copy to keep).
See ``docs/envs.md``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode

from qpatrol.config import Config
from qpatrol.envs.batch import Batch
from qpatrol.envs.sim import make_config
from qpatrol.strategies import features

OBSERVATIONS = ("ports", "graph")


class PatrolVectorEnv:
    """``num_envs`` runs of a patrol team, stepped together.

    Args:
        config, overrides, map, agents: as :class:`~qpatrol.envs.PatrolParallelEnv`.
        num_envs: runs in the batch (B).
        max_steps: team steps of each run (default: the config's ``steps``).
        engine: ``"numba"`` (the compiled world), ``"numpy"`` or ``"auto"``.
        threads: threads stepping lanes of runs on the compiled engine (1: one).
        observation: ``"ports"`` (per-port features, float32 ``[B, K, D x P]``,
            :func:`qpatrol.strategies.features.ports`) or ``"graph"`` (node features
            ``[B, K, N, F]``, :func:`~qpatrol.strategies.features.nodes`, with
            :attr:`edge_index` and :attr:`edge_attr`).
        autoreset: when every run is over (``max_steps`` taken, or every episode quota
            met), the next batch of runs starts in the same step (gymnasium's
            ``SAME_STEP``): the observations returned are the new runs' first, the
            finished batch's measures are in ``infos["final_metrics"]`` and its
            :class:`~qpatrol.run.RunResult` is :attr:`last_result`. False: the batch
            waits for :meth:`reset`.

    Runs share the team step (their world's clock), so a batch starts and ends
    together: a run that meets its episode quota first sits out (terminated, its masks
    0, its rewards 0), as in ``train``, until the batch is over.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "name": "qpatrol_patrol_vector_v0"}

    def __init__(
        self,
        config: str | Path | Config | None = None,
        overrides: Iterable[str] = (),
        *,
        map: str | None = None,
        agents: int | None = None,
        num_envs: int = 16,
        max_steps: int | None = None,
        engine: str = "auto",
        threads: int = 1,
        observation: str = "ports",
        autoreset: bool = True,
    ):
        extra = list(overrides) if not isinstance(overrides, str) else overrides
        if max_steps is not None:
            if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1:
                raise ValueError(f"max_steps: got {max_steps!r}; allowed: an int >= 1")
            extra = [*extra, f"steps={max_steps}"]
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation: got {observation!r}; allowed: {OBSERVATIONS}")
        self.config = make_config(config, extra, map, agents)
        self.batch = Batch(self.config, num_envs, engine, threads)
        self.num_envs = self.batch.n_envs
        self.n_agents = k = self.batch.n_agents
        self.max_steps = self.batch.max_steps
        self.observation = observation
        self.autoreset = bool(autoreset)
        self.tables = features.Tables(self.batch.map, self.batch.params)
        self.edge_index, self.edge_attr = self.tables.graph_edges()
        b, d = self.num_envs, self.batch.n_ports
        n = self.tables.targets.size
        if observation == "ports":
            self._feat = np.zeros((b, k, len(features.PORT), d), dtype=np.float32)
            self._obs = self._feat.reshape(b, k, d * len(features.PORT))
            single = spaces.Box(0.0, np.inf, (d * len(features.PORT),), np.float32)
        else:
            self._feat = np.zeros((b, k, n, len(features.NODE)), dtype=np.float32)
            self._obs = self._feat
            single = spaces.Box(0.0, np.inf, (n, len(features.NODE)), np.float32)
        self.single_observation_space = single
        self.single_action_space = spaces.Discrete(d)
        self.possible_agents = [f"agent_{i}" for i in range(k)]
        self.agents = list(self.possible_agents)
        self._rewards = np.zeros((b, k), dtype=np.float32)
        self._term = np.zeros((b, k), dtype=bool)
        self._trunc = np.zeros((b, k), dtype=bool)
        self.last_result = None

    # --- PettingZoo's per-agent accessors --------------------------------------------------
    def observation_space(self, agent: str) -> spaces.Box:
        """One robot's observation space (every robot's is the same)."""
        return self.single_observation_space

    def action_space(self, agent: str) -> spaces.Discrete:
        """One robot's action space: ``Discrete(D)``, the ports (N, E, S, W on a grid)."""
        return self.single_action_space

    def agent_dict(self, arr: np.ndarray) -> dict[str, np.ndarray]:
        """``{agent: arr[:, k]}`` (views) of an array ``[B, K, ...]``: PettingZoo's dicts."""
        return {a: arr[:, i] for i, a in enumerate(self.possible_agents)}

    # --- the API --------------------------------------------------------------------------
    def reset(
        self, seed: int | None = None, options: Mapping[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start runs ``r .. r + B - 1`` of root ``seed`` (``options={"run": r}``,
        default 0 after a new seed; without a seed, the runs after the last batch's):
        run ``r`` draws from ``SeedSequence(seed, spawn_key=(0, r))`` as run ``r`` of
        ``qpatrol train`` does. Returns ``(observations, infos)``."""
        first = None if options is None else options.get("run")
        self.batch.reset(seed, first)
        self._term[:] = False
        self._trunc[:] = False
        return self._observe(), self._infos()

    def step(
        self, actions: np.ndarray | Mapping[str, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One team step of every run. ``actions``: int ``[B, K]`` (or PettingZoo's
        ``{agent: int [B]}``), the port each robot asks for; read only where
        ``infos["action_mask"]`` has a move (a robot that chooses). Returns
        ``(observations, rewards, terminations, truncations, infos)``."""
        b = self.batch
        if isinstance(actions, Mapping):
            arr = np.full((self.num_envs, self.n_agents), -1, dtype=np.int64)
            for i, a in enumerate(self.possible_agents):
                if a in actions and actions[a] is not None:
                    arr[:, i] = actions[a]
            actions = arr
        was_active = b.state.active.copy()
        b.step(actions)
        np.copyto(self._rewards, b.reward)
        self._term[:] = (~b.state.active & was_active)[:, None]
        self._trunc[:] = b.truncated[:, None]
        infos: dict[str, Any] = {}
        if b.done_all and self.autoreset:
            result = b.result()
            self.last_result = result
            infos["final_metrics"] = _columns(result.summary)
            infos["final_obs"] = self._observe().copy()
            b.reset()
        obs = self._observe()
        infos.update(self._infos())
        return obs, self._rewards, self._term, self._trunc, infos

    def _observe(self) -> np.ndarray:
        if self.observation == "ports":
            features.ports(self.batch.observation, self.tables, self._feat)
        else:
            features.nodes(self.batch.observation, self.tables, self._feat)
        return self._obs

    def _infos(self) -> dict[str, Any]:
        b = self.batch
        return {"action_mask": b.mask, "moved": getattr(b, "moved", None), "t": b.t}

    # --- qpatrol's view -----------------------------------------------------------------------
    @property
    def world_observation(self):
        """The :class:`~qpatrol.world.Observation` a qpatrol strategy sees this step."""
        return self.batch.observation

    @property
    def uniforms(self) -> np.ndarray:
        """float ``[B, K, 2]``: the uniforms ``train`` gives a strategy this step."""
        return self.batch.uniforms

    @property
    def last_outcome(self):
        """The :class:`~qpatrol.world.Outcome` of the last step (what strategies learn from)."""
        return self.batch.outcome

    def result(self, strategy=None):
        """The batch's :class:`~qpatrol.run.RunResult` so far (:meth:`Batch.result`):
        :func:`qpatrol.run.write_run` writes ``train``'s files from it."""
        return self.batch.result(strategy)

    def metrics(self) -> dict[str, np.ndarray]:
        """Each run's measures so far, as columns ``{name: [B]}``."""
        return _columns(self.batch.metrics())

    def graph(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(nodes float32 [B, K, N, F], edge_index int64 [2, E], edge_attr float32
        [E, 1])``: the graph observations of this step, whatever ``observation`` is."""
        nodes = features.nodes(self.batch.observation, self.tables)
        return nodes, self.edge_index, self.edge_attr

    def close(self) -> None:
        """Nothing to release."""


def _columns(rows: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Summaries (one dict per run) as numeric columns ``{name: [B]}``."""
    keys = [k for k, v in rows[0].items() if isinstance(v, int | float) and not isinstance(v, bool)]
    return {k: np.array([r.get(k, np.nan) for r in rows], dtype=np.float64) for k in keys}


class PatrolGymVectorEnv(gymnasium.vector.VectorEnv):
    """Every robot of ``B`` runs as a sub-environment of ``gymnasium.vector.VectorEnv``
    (``num_envs = B x K``, robot ``k`` of run ``b`` at index ``b x K + k``).

    Arguments as :class:`PatrolVectorEnv` (``num_envs`` there is ``runs`` here).
    Observations ``[B x K, F]``, actions ``[B x K]`` (``MultiDiscrete``), rewards,
    terminations, truncations ``[B x K]``, ``infos["action_mask"]`` ``[B x K, D]``;
    autoreset ``SAME_STEP`` (``metadata["autoreset_mode"]``).
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, config=None, overrides=(), *, runs: int = 16, **kwargs: Any):
        self.env = PatrolVectorEnv(config, overrides, num_envs=runs, **kwargs)
        e = self.env
        self.num_envs = e.num_envs * e.n_agents
        self.single_observation_space = e.single_observation_space
        self.single_action_space = e.single_action_space
        self.observation_space = gymnasium.vector.utils.batch_space(
            self.single_observation_space, self.num_envs
        )
        self.action_space = gymnasium.vector.utils.batch_space(
            self.single_action_space, self.num_envs
        )
        self.render_mode = None

    def _flat(self, infos: dict[str, Any]) -> dict[str, Any]:
        n = self.num_envs
        out = dict(infos)
        out["action_mask"] = infos["action_mask"].reshape(n, -1)
        if infos.get("moved") is not None:
            out["moved"] = infos["moved"].reshape(n)
        if "final_obs" in infos:
            out["final_obs"] = infos["final_obs"].reshape(n, *self.single_observation_space.shape)
        return out

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, infos = self.env.reset(seed, options)
        return obs.reshape(self.num_envs, *self.single_observation_space.shape), self._flat(infos)

    def step(self, actions):
        a = np.asarray(actions).reshape(self.env.num_envs, self.env.n_agents)
        obs, rew, term, trunc, infos = self.env.step(a)
        n = self.num_envs
        shape = (n, *self.single_observation_space.shape)
        flat = (rew.reshape(n), term.reshape(n), trunc.reshape(n))
        return obs.reshape(shape), *flat, self._flat(infos)

    def close_extras(self, **kwargs: Any) -> None:
        """Nothing to release."""
