"""B runs of one config stepped from outside together: the engine under
:class:`~qpatrol.envs.PatrolVectorEnv`.

:class:`Batch` is the time loop of :func:`qpatrol.run.simulate` for a batch of runs,
turned inside out: ``reset`` builds the batch exactly as ``train`` does
(:func:`qpatrol.run.new_batch`: the runs' streams, placements, failing robots,
measures and recorders) and begins the first step; ``step`` takes the caller's moves
``[B, K]`` and begins the next. On the numpy engine a step is
:func:`qpatrol.world.step` and :func:`qpatrol.engines.numpy_loop.measure`, as in the
numpy engine's loop; on the compiled engine it is
:func:`qpatrol.engines.vector.step_batch`, run_block's phases cut where a strategy
chooses, on the very arrays of the numpy objects. Either way :meth:`Batch.result`
gives the :class:`~qpatrol.run.RunResult` that ``train`` writes, so a batch driven with
a strategy's choices writes ``train``'s files to the bit. No gymnasium here.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from qpatrol import engines, run, strategies, world
from qpatrol.config import Config, ConfigError
from qpatrol.engines import numpy_loop
from qpatrol.engines import threads as engine_threads
from qpatrol.world.rng import run_keys

ENGINES = ("auto", "numpy", "numba")


class Batch:
    """``n_envs`` runs of ``cfg`` in lockstep, moved by a caller.

    Args:
        cfg: the config (its ``runs`` is replaced by ``n_envs``, its ``steps`` by
            ``max_steps`` when given).
        n_envs: runs in the batch (B).
        engine: ``numba`` (the compiled world; needs numba), ``numpy``, or
            ``auto`` (numba when installed).
        threads: lanes of runs stepped by threads of their own on the compiled engine
            (0: the config's ``threads`` rule; 1: one thread).

    After :meth:`reset`: :attr:`state` (the world, ``R = B``), :attr:`mask` int8 ``[B, K,
    D]`` (the moves each robot may choose this step; all 0 for a robot the world moves
    or that does not decide here), :attr:`uniforms` float ``[B, K, 2]`` (the step's
    uniforms, as ``train`` gives them to a strategy), :attr:`observation` (the
    :class:`~qpatrol.world.Observation` a strategy sees); after :meth:`step`:
    :attr:`reward` float ``[B, K]``, :attr:`moved` bool ``[B, K]`` and
    :attr:`outcome` (the :class:`~qpatrol.world.Outcome` a strategy learns from).
    """

    def __init__(self, cfg: Config, n_envs: int, engine: str = "auto", threads: int = 1):
        if isinstance(n_envs, bool) or not isinstance(n_envs, int | np.integer) or n_envs < 1:
            raise ValueError(f"num_envs: got {n_envs!r}; allowed: an int >= 1")
        if engine not in ENGINES:
            raise ValueError(f"engine: got {engine!r}; allowed: {', '.join(ENGINES)}")
        if engine == "auto":
            engine = "numba" if engines.numba_installed() else "numpy"
        if engine == "numba" and not engines.numba_installed():
            raise ConfigError(
                "engine: numba is not installed; allowed: engine='numpy' or 'auto', or "
                "install numba (pip install numba)"
            )
        self.cfg = cfg.with_overrides([f"runs={int(n_envs)}", f"engine={engine}"])
        self.engine = engine
        self.n_envs = int(n_envs)
        self.map, self.params = run.prepare(self.cfg)
        self.n_agents = self.params.n_agents
        self.n_ports = self.map.n_ports
        self.max_steps = int(self.cfg["steps"])
        self.threads = engine_threads.resolve(self.cfg["threads"] if threads == 0 else threads)
        self.seed = int(self.cfg["seed"])
        self.first_run = 0
        self.state: world.State | None = None
        b, k, d = self.n_envs, self.n_agents, self.n_ports
        self.mask = np.zeros((b, k, d), dtype=np.int8)
        self.reward = np.zeros((b, k), dtype=np.float64)
        self._outcome: world.Outcome | None = None

    # --- starting a batch -------------------------------------------------------------
    def reset(self, seed: int | None = None, first_run: int | None = None) -> None:
        """Start runs ``first_run .. first_run + B - 1`` of root ``seed``: each run's
        stream is ``SeedSequence(seed, spawn_key=(0, run))``, as run ``run`` of ``qpatrol
        train`` with that seed. ``seed`` None keeps the last one; ``first_run`` None is 0
        after a new seed, else the run after the last batch's."""
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
                raise ValueError(f"seed: got {seed!r}; allowed: an int >= 0 or None")
            self.seed = int(seed)
            self.first_run = 0 if first_run is None else int(first_run)
        elif first_run is not None:
            self.first_run = int(first_run)
        elif self.state is not None:
            self.first_run += self.n_envs
        ids = np.arange(self.first_run, self.first_run + self.n_envs)
        cfg, m, p = self.cfg, self.map, self.params
        seeds = run_keys(self.seed, range(int(ids[0]), int(ids[-1]) + 1), 0)
        parts = run.new_batch(cfg, m, p, seeds, ids)
        self.streams, self.state, self.measures, self.rec, self.tail, self.timeline = parts
        self.starts = self.state.pos.copy()
        self._outcome = None
        self.reward[:] = 0.0
        if self.engine == "numba":
            self._compiled_start()
        else:
            self._begin_numpy()

    # --- the numpy engine -------------------------------------------------------------
    def _begin_numpy(self) -> None:
        s, p = self.state, self.params
        self._obs = world.begin_step(s, p)
        self._uniforms = self.streams.next()
        o = self._obs
        moves = np.where(o.open.any(axis=-1, keepdims=True), o.open, o.legal)
        np.copyto(self.mask, moves & o.choosing[..., None])

    def _step_numpy(self, choice: np.ndarray) -> None:
        s, p = self.state, self.params
        out = world.step(s, p, self._obs, choice)
        self.rec.episodes(out.t, out.episodes)
        numpy_loop.measure(s, p, out, self.measures, self.tail, self.timeline)
        self._outcome = out
        np.copyto(self.reward, out.reward)
        self.moved = out.moved
        if not self.done_all:
            self._begin_numpy()
        else:
            self.mask[:] = 0

    # --- the compiled engine ----------------------------------------------------------
    def _compiled_start(self) -> None:
        from qpatrol.engines import numba_core, vector

        s, p = self.state, self.params
        dummy = strategies.make("random", self.cfg, self.map, p, self.starts)
        loop = numba_core.Loop(
            s, p, dummy, self.measures, self.tail, self.rec, 1, self.streams.words, self.timeline
        )
        self._loop = loop
        self.words = loop.words
        _, bp, _, _, bs, bm, bo, _ = loop.args
        self._bundles = (bp, bs, bm)
        b, k, d = self.n_envs, self.n_agents, self.n_ports
        self.wb, x = vector.batched_work(b, k, p.n_groups, p.n_cells, d)
        self.lanes = engine_threads.lanes(b, self.threads, b * k * 64)
        # each lane: its rows, its output rows (loop's lane buffers) and its scratch
        self._lane_args = []
        for i, (lo, hi) in enumerate(self.lanes):
            o = loop._lane_args(i, hi - lo)[numba_core.Loop.out_at] if i else bo
            xi = x if i == 0 else type(x)(*(a.copy() for a in x))
            self._lane_args.append((lo, hi, o, xi))
        self.tok_b = np.full(b, -1, dtype=np.int64)
        self.out_i = np.zeros((b, k, vector.OUT_I), dtype=np.int64)
        self.out_f = np.zeros((b, k), dtype=np.float64)
        self._actions = np.full((b, k), -1, dtype=np.int64)
        self._kernel = vector.step_batch
        self._vector = vector
        self._call(0, False, True)

    def _call(self, t: int, finish: bool, begin: bool) -> None:
        bp, bs, bm = self._bundles
        args = (self.words, self.tok_b, bp, bs, bm)
        rest = (self.wb,)
        ends, tls = [], []

        def lane(i: int) -> None:
            lo, hi, o, x = self._lane_args[i]
            n_ep, n_tl = self._kernel(
                lo, hi, t, finish, begin, self._actions, *args, o, *rest, x, self.mask,
                self.out_i, self.out_f,
            )  # fmt: skip
            ends.append((i, o.ep_buf[:n_ep].copy()))
            tls.append((i, o.tl_buf[:n_tl].copy()))

        if len(self._lane_args) == 1:
            lane(0)
        else:
            from qpatrol.engines import numba_core

            pool = numba_core._pool(len(self._lane_args))
            for f in [pool.submit(lane, i) for i in range(len(self._lane_args))]:
                f.result()
        ends.sort(key=lambda e: e[0])
        tls.sort(key=lambda e: e[0])
        self._ep_rows = ends[0][1] if len(ends) == 1 else np.concatenate([e[1] for e in ends])
        if finish:
            self.rec.episode_rows(self._ep_rows)
            if self.timeline is not None and self._loop.timeline is not None:
                for _, rows_tl in tls:
                    self.timeline.add_rows(rows_tl)

    def _step_compiled(self, choice: np.ndarray) -> None:
        from qpatrol.engines import numba_core

        s, p = self.state, self.params
        np.copyto(self._actions, choice)
        self._was_active = s.active.copy()
        t = s.t + 1
        last = t >= self.max_steps
        self._call(t, True, not last)
        s.t = t
        numba_core.sat_out(s, p)
        self.reward[:] = self.out_f
        self.moved = self.out_i[..., self._vector.MOVED].astype(bool)
        self._outcome = None
        if self.done_all:
            self.mask[:] = 0

    # --- stepping -----------------------------------------------------------------------
    def step(self, actions: np.ndarray) -> None:
        """One team step of every active run: ``actions`` int ``[B, K]``, the port each
        robot asks for (-1 or a port without a move: none; read only for robots that
        choose, :attr:`mask`). Then the next step begins, unless every run is done."""
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        if self.done_all:
            raise RuntimeError("the batch is over (every run terminated or truncated); reset()")
        choice = np.asarray(actions)
        if choice.shape != (self.n_envs, self.n_agents):
            raise ValueError(
                f"actions: shape {choice.shape}; allowed: ({self.n_envs}, {self.n_agents})"
            )
        if not np.issubdtype(choice.dtype, np.integer):
            raise ValueError(f"actions: dtype {choice.dtype}; allowed: integers (ports)")
        if self.engine == "numba":
            self._step_compiled(choice)
        else:
            self._step_numpy(np.where(choice < self.n_ports, choice, -1))

    @property
    def t(self) -> int:
        """Team steps taken."""
        return int(self.state.t)

    @property
    def terminated(self) -> np.ndarray:
        """bool ``[B]``: the run's episode quota (``episodes``) is met."""
        return ~self.state.active

    @property
    def truncated(self) -> np.ndarray:
        """bool ``[B]``: ``max_steps`` team steps taken (and the quota not met)."""
        return self.state.active & (self.state.t >= self.max_steps)

    @property
    def done_all(self) -> bool:
        """Every run is over: the batch starts again at the next reset."""
        return self.state.t >= self.max_steps or not self.state.active.any()

    # --- what qpatrol's strategies see ---------------------------------------------------
    @property
    def uniforms(self) -> np.ndarray:
        """float ``[B, K, 2]``: the uniforms ``train`` gives a strategy this step."""
        return self._uniforms if self.engine == "numpy" else self.wb.uniforms

    @property
    def observation(self) -> world.Observation:
        """The :class:`~qpatrol.world.Observation` of the step about to be taken."""
        if self.engine == "numpy":
            return self._obs
        s, p, wb = self.state, self.params, self.wb
        travel = None
        if p.onward is not None:
            travel = np.where(s.active[:, None], wb.travel, -1)
        return world.Observation(
            t=s.t + 1,
            state=s,
            params=p,
            choosing=wb.choosing & s.active[:, None],
            legal=p.wall_legal[s.pos],
            open=wb.open_mask,
            travel=travel,
        )

    @property
    def outcome(self) -> world.Outcome | None:
        """The :class:`~qpatrol.world.Outcome` of the last step (None before one)."""
        if self.engine == "numpy" or self._outcome is not None or self.state.t == 0:
            return self._outcome
        v, oi, rows = self._vector, self.out_i, self._ep_rows
        ends = world.EpisodeEnds(
            runs=rows[:, 0],
            groups=rows[:, 1],
            episode=rows[:, 2],
            start=rows[:, 3],
            dots=rows[:, 4],
            distinct_cells=rows[:, 5],
            distinct_states=rows[:, 6],
            complete=rows[:, 7].astype(bool),
        )
        self._outcome = world.Outcome(
            t=self.state.t,
            active=self._was_active,
            choosing=oi[..., v.CHOOSING].astype(bool),
            ask=oi[..., v.ASK].copy(),
            waiting_for_station=oi[..., v.WAITING].astype(bool),
            moved=oi[..., v.MOVED].astype(bool),
            as_asked=oi[..., v.AS_ASKED].astype(bool),
            prev_pos=oi[..., v.PREV_POS].copy(),
            prev_head=oi[..., v.PREV_HEAD].copy(),
            pos=self.state.pos.copy(),
            reward=self.out_f.copy(),
            eaten=oi[..., v.EATEN].astype(bool),
            blocked_by=oi[..., v.BLOCKED_BY].copy(),
            episodes=ends,
            travelling=oi[..., v.TRAVEL].astype(bool),
        )
        return self._outcome

    # --- results --------------------------------------------------------------------------
    def result(self, strategy: strategies.base.Strategy | None = None) -> run.RunResult:
        """The batch's :class:`~qpatrol.run.RunResult` so far, as ``train`` makes it:
        written by :func:`qpatrol.run.write_run` it gives ``train``'s files when the
        robots were moved by ``strategy``'s choices (its tables and facts go into the
        files; None: a placeholder that has none)."""
        if self.state is None:
            raise RuntimeError("call reset() before result()")
        if strategy is None:
            strategy = strategies.base.Strategy(self.cfg, self.map, self.params, self.starts)
        loop = "general" if self.engine == "numpy" else "vector"
        args = (self.cfg, self.map, self.params, self.state, strategy, self.measures)
        args += (self.rec, self.tail, self.timeline, self.engine, "", loop)
        return run.result_of(*args)

    def metrics(self) -> list[dict[str, Any]]:
        """Each run's patrol measures so far, as ``summary.json`` of ``train`` gives
        them (:func:`qpatrol.measures.summarize`)."""
        return self.result().summary
