"""One run of the patrol world, stepped from outside: the engine under both envs.

:class:`Sim` is the loop of :func:`qpatrol.run.simulate` for a single run (``R = 1``),
turned inside out so that a caller gives the moves: ``reset`` places the robots and
asks the world what the first step looks like, ``step`` applies the caller's moves
and asks again. Everything is qpatrol's own code (:mod:`qpatrol.world`,
:mod:`qpatrol.measures`, :mod:`qpatrol.world.rng`), called in the same order as ``train``,
so with the same config, seed and run index and the same moves the trajectory is the
one ``train`` would produce.

Random numbers: run ``r`` of seed ``s`` draws from ``SeedSequence(s, spawn_key=(0,
r))``, exactly as run ``r`` of ``qpatrol train`` with ``seed: s``. The world uses the
stream only to place robots beyond the map's start digits; every step then takes
``2 x agents`` uniforms from it (:class:`qpatrol.world.rng.Streams`). The uniforms of the
step about to be taken are :attr:`Sim.uniforms`: a strategy fed with them chooses as
it would inside ``train``. Pettingzoo/gymnasium are not imported here.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from qpatrol import measures, run, world
from qpatrol.config import Config, ConfigError, from_flat, load_config
from qpatrol.maps import Map
from qpatrol.measures.records import Recorder
from qpatrol.world.rng import Streams, run_seeds


def make_config(
    config: str | Path | Config | None = None,
    overrides: Iterable[str] = (),
    map: str | None = None,
    agents: int | None = None,
) -> Config:
    """The config of an env: a YAML path or shipped name, a Config, or None (defaults).

    ``overrides`` are ``KEY=VALUE`` strings as for ``qpatrol train --set``; ``map`` and
    ``agents`` are shortcuts for ``map=...`` and ``agents=...``, applied last. Raises
    :class:`~qpatrol.config.ConfigError` (a ``ValueError``) on a bad key or value and
    ``TypeError`` on an argument of the wrong type.
    """
    if isinstance(overrides, str):
        raise TypeError(f"overrides: expected a list of 'KEY=VALUE' strings, got {overrides!r}")
    extra = list(overrides)
    for item in extra:
        if not isinstance(item, str):
            raise TypeError(f"overrides: expected 'KEY=VALUE' strings, got {item!r}")
    if map is not None:
        if not isinstance(map, str | Path):
            raise TypeError(f"map: expected a map name or path, got {map!r}")
        extra.append(f"map={map}")
    if agents is not None:
        if isinstance(agents, bool) or not isinstance(agents, int | np.integer):
            raise TypeError(f"agents: expected an int, got {agents!r}")
        extra.append(f"agents={int(agents)}")
    if config is None:
        return from_flat({}).with_overrides(extra)
    if isinstance(config, Config):
        return config.with_overrides(extra)
    if isinstance(config, str | Path):
        return load_config(config, extra)
    raise TypeError(
        f"config: expected a YAML path, a shipped config name or a qpatrol Config, got "
        f"{type(config).__name__}"
    )


class Sim:
    """One run of the world, stepped by a caller.

    Args:
        cfg: the config (``runs`` is ignored: a Sim is one run).
        max_steps: team steps after which the run is truncated (default ``cfg['steps']``).

    Attributes (valid after :meth:`reset`):
        state: the world, ``R = 1``.
        obs: the :class:`~qpatrol.world.Observation` of the step about to be taken.
        uniforms: float ``[K, 2]``, that step's uniforms (what ``train`` gives a strategy).
        outcome: the :class:`~qpatrol.world.Outcome` of the last step (None before one).
        measures: qpatrol's measure accumulators over this run.
        seed, run: the root seed and run index the stream came from.
    """

    def __init__(self, cfg: Config, max_steps: int | None = None):
        if max_steps is None:
            max_steps = int(cfg["steps"])
        if isinstance(max_steps, bool) or not isinstance(max_steps, int | np.integer):
            raise TypeError(f"max_steps: expected an int >= 1, got {max_steps!r}")
        if max_steps < 1:
            raise ValueError(f"max_steps: got {max_steps}; allowed: an int >= 1")
        if cfg["failures.robots"]:
            raise ConfigError(
                f"failures.robots: got {cfg['failures.robots']}; allowed here: 0 (the "
                "environments keep every robot; robot failures are for train and sweeps)"
            )
        self.cfg = cfg
        self.max_steps = int(max_steps)
        self.map, self.params = run.prepare(cfg)
        self.n_agents = self.params.n_agents
        self.seed: int = int(cfg["seed"])
        self.run: int = -1
        self.state: world.State | None = None
        self.outcome: world.Outcome | None = None

    def reset(self, seed: int | None = None, run_index: int | None = None) -> None:
        """Start run ``run_index`` of root ``seed``.

        ``seed`` None keeps the last seed (first: the config's ``seed``); ``run_index``
        None is 0 after a new seed, else the run after the last one, so successive
        ``reset()`` calls go through runs 0, 1, 2, ... of ``qpatrol train``.
        """
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
                raise ValueError(f"seed: got {seed!r}; allowed: an int >= 0 or None")
            self.seed = int(seed)
        if run_index is None:
            run_index = 0 if seed is not None else self.run + 1
        if isinstance(run_index, bool) or not isinstance(run_index, int | np.integer):
            raise ValueError(f"run: got {run_index!r}; allowed: an int >= 0")
        if run_index < 0:
            raise ValueError(f"run: got {run_index}; allowed: an int >= 0")
        self.run = int(run_index)
        p = self.params
        self.streams = Streams(run_seeds(self.seed, range(self.run, self.run + 1)), p.n_agents)
        starts = world.place_agents(p, self.map, self.streams.generators[0])[None, :]
        self.starts = starts
        self.state = world.init_state(p, starts)
        self.measures = measures.Measures(
            1,
            p.n_agents,
            p.n_cells,
            int(self.cfg["record.warmup"]),
            p.target,
            measures.attack_steps(self.cfg["security.attack_steps"], p.n_targets),
            self.max_steps,
            self.state.pos,
        )
        self.recorder = Recorder(np.array([self.run]))
        self.outcome = None
        self._begin()

    def _begin(self) -> None:
        self.obs = world.begin_step(self.state, self.params)
        self.uniforms = self.streams.next()[0].copy()

    @property
    def started(self) -> bool:
        return self.state is not None

    @property
    def terminated(self) -> bool:
        """The run's episode quota (``episodes`` in the config) has been met."""
        return not bool(self.state.active[0])

    @property
    def truncated(self) -> bool:
        """``max_steps`` team steps have been taken (and the quota is not met)."""
        return self.state.t >= self.max_steps and not self.terminated

    @property
    def done(self) -> bool:
        return self.terminated or self.state.t >= self.max_steps

    def step(self, choice: np.ndarray) -> world.Outcome:
        """One team step with ``choice`` int ``[K]`` (0..3, -1 none; used for choosing robots).

        After the step, the measures take it in, then (unless the run is over) the world
        is asked about the next step and its uniforms are drawn.
        """
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        if self.done:
            raise RuntimeError("the run is over (terminated or truncated); call reset()")
        out = world.step(self.state, self.params, self.obs, np.asarray(choice)[None, :])
        self.recorder.episodes(out.t, out.episodes)
        p = self.params
        s = self.state
        stall = measures.stalls(s, out.t)
        self.measures.observe(out, s.wait, s.charge if p.battery else None, None, stall)
        self.outcome = out
        if not self.done:
            self._begin()
        return out

    def open_moves(self) -> np.ndarray:
        """bool ``[K, D]``: the moves a choosing robot may take (all zero if not choosing).

        The open moves (:attr:`~qpatrol.world.Observation.open`), or every legal move
        where none is open, as qpatrol's strategies choose from
        (:func:`qpatrol.strategies.base.prefer_open`).
        """
        o = self.obs
        moves = np.where(o.open.any(axis=-1, keepdims=True), o.open, o.legal)[0]
        return moves & o.choosing[0][:, None]

    def metrics(self) -> dict[str, Any]:
        """The run's patrol measures so far, as ``summary.json`` of ``train`` gives them.

        :func:`qpatrol.measures.summarize` over this run's accumulators: ``avg_idleness``,
        ``worst_idleness``, ``mean_interval``, ``max_interval``, ``coverage``,
        ``division_of_labour``, waits, episodes and the rest.
        """
        if self.state is None:
            raise RuntimeError("call reset() before metrics()")
        episodes = self.recorder.episode_table()
        bound = measures.stall_bound(self.params)
        steps = self.state.steps_done
        return measures.summarize(self.measures, episodes, self.recorder.run_ids, steps, bound)[0]


class WorldView:
    """What both envs expose of their :class:`Sim` (``self.sim``), for qpatrol code."""

    sim: Sim

    @property
    def map(self) -> Map:
        """The :class:`~qpatrol.maps.Map`."""
        return self.sim.map

    @property
    def params(self) -> world.Params:
        """The world's parameters."""
        return self.sim.params

    @property
    def world_state(self) -> world.State:
        """The world (``R = 1``); read only."""
        return self.sim.state

    @property
    def world_observation(self) -> world.Observation:
        """What a qpatrol strategy sees before the step about to be taken."""
        return self.sim.obs

    @property
    def uniforms(self) -> np.ndarray:
        """float ``[K, 2]``: the uniforms ``train`` would give its strategy this step."""
        return self.sim.uniforms

    @property
    def last_outcome(self) -> world.Outcome | None:
        """The :class:`~qpatrol.world.Outcome` of the last step (what strategies learn from)."""
        return self.sim.outcome

    def metrics(self) -> dict[str, Any]:
        """Patrol measures of the run so far, computed by :mod:`qpatrol.measures` exactly
        as ``train`` does (``avg_idleness``, ``worst_idleness``, ``mean_interval``,
        ``max_interval``, ``coverage``, ...): :meth:`Sim.metrics`."""
        return self.sim.metrics()
