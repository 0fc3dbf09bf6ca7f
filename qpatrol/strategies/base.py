"""What every strategy is: a batch-shaped chooser of moves that may learn from outcomes.

A strategy sees the world through an :class:`~qpatrol.world.Observation` and answers
with one port per robot (``int [R, K]``, 0..D-1; on a grid 0..3 = N, E, S, W; -1 for
no move); the
world asks it only for robots that are patrolling (homing and charging are the
world's). After the step it receives the :class:`~qpatrol.world.Outcome` and may learn.
Its own arrays carry the same leading runs axis ``R`` and robots axis ``K``.

Random numbers: every step each run draws ``u [R, K, 2]`` uniforms in [0, 1) from its
own stream, whether used or not, so a run never depends on its batch; strategies use
``u[..., 0]`` for exploration and ``u[..., 1]`` to break ties.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from qpatrol.strategies.learner import pick
from qpatrol.util.arrays import port_any

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.measures.records import Recorder
    from qpatrol.world import Observation, Outcome, Params


class Strategy:
    """Base class: picks uniformly among open moves and learns nothing.

    Args:
        cfg: the run's config.
        m: the map.
        p: the world's parameters.
        start_cells: int ``[R, K]``, where the robots start.
    """

    name: ClassVar[str] = "base"
    #: True for a strategy that learns as it patrols (it needs a warm-up to settle).
    learns: ClassVar[bool] = False
    #: Names of its array attributes with a leading runs axis ``R`` (the others are
    #: constants of the batch), or None where not declared: :mod:`qpatrol.run.batching` runs
    #: several sweep points in one batch only for a strategy that declares them.
    per_run: ClassVar[tuple[str, ...] | None] = None
    #: The numpy engine's CPU time its robots add per robot-step and cell of the map,
    #: microseconds, beyond the world's step (strategies that read whole rows of the map
    #: at every step): :func:`qpatrol.engines.coldstart.numpy_seconds`, which decides
    #: whether a run waits for the compiled engine. Measured on facility, 8 robots.
    numpy_cell_us: ClassVar[float] = 0.0
    #: Config keys it reads that may differ between the rows of one batch
    #: (:meth:`use_run_values`); it ignores the other per-run keys.
    RUN_KEYS: ClassVar[tuple[str, ...]] = ()
    #: True for a strategy that keeps its plan on a graph's waypoints too (walk
    #: followers, :func:`walking`): the world reads its choice for a robot travelling an
    #: edge, and turns the robot round where it asks for the port behind it
    #: (:func:`qpatrol.world.turn_round`).
    plans_on_edges: ClassVar[bool] = False
    #: True for a strategy whose robots' goals are tasks allocated to them, kept until
    #: reached or exchanged (``dta-*``: vertices won at auction): on a patrol graph with
    #: waypoints the holder of the right of way, head on with one of them, exchanges tasks
    #: with it rather than pushing it back (:func:`qpatrol.world.traffic.head_on`).
    #: Robots that choose their goals from their own records (``cc``, ``hpcc``) or a
    #: neighbouring target are pushed.
    keeps_plans: ClassVar[bool] = False

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        self.cfg = cfg
        self.map = m
        self.params = p
        self.n_runs, self.n_agents = start_cells.shape

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        """int ``[R, K]``: the direction each choosing robot asks for (-1: none)."""
        return choose_min(np.zeros(obs.legal.shape), prefer_open(obs), u[..., 1])

    def learn(self, out: Outcome, rec: Recorder | None = None) -> None:
        """Learn from what happened in a step (default: nothing)."""

    def aims(self, obs: Observation) -> np.ndarray | None:
        """int ``[R, K]``: the cell each robot heads for after :meth:`act` (its goal, its
        next walk cell), -1 for a robot that just chooses a move; None (the default):
        every robot just chooses (the world's task of each robot, ``State.aim``)."""
        return None

    def planned_wait(self) -> int | np.ndarray:
        """The most steps a robot may wait by the strategy's own rule (not the world's),
        per run (int ``[R]``) or one for all, added to ``stall_bound``
        (:func:`qpatrol.measures.stall_bound`). Default 0: its robots ask for a move at
        every step (docs/model.md, hypothesis (S))."""
        return 0

    def exchange(self, swapped: np.ndarray) -> None:
        """The world made robots exchange their tasks (``swapped`` int ``[R, K]``: the
        partner of each robot, -1 for none; ``qpatrol.world.traffic.hand_on``): exchange
        their plans too. Default: nothing (a strategy without a plan)."""

    def use_run_values(self, values: dict[str, np.ndarray] | None, table: bool = True) -> None:
        """Take per-row values of :data:`RUN_KEYS` (config key -> ``[R]``, the keys whose
        value differs between the batch's rows; None: ``cfg``'s values for every row),
        before the first step; ``table``: also set the initial tables from them.
        Default: nothing (it reads none)."""

    def tables(self) -> dict[str, np.ndarray]:
        """Arrays worth saving with the run (e.g. a Q-table); empty by default."""
        return {}

    def describe(self) -> dict[str, object]:
        """Facts about this strategy for summary.json (e.g. a walk's length)."""
        return {}


def partners(values: np.ndarray, swapped: np.ndarray) -> np.ndarray:
    """``values`` (``[R, K, ...]``) with each robot's entry replaced by its partner's where
    ``swapped`` (int ``[R, K]``, -1 for none) names one: an exchange of plans."""
    j = np.maximum(swapped, 0).reshape(swapped.shape + (1,) * (values.ndim - 2))
    taken = np.take_along_axis(values, np.broadcast_to(j, swapped.shape + values.shape[2:]), axis=1)
    mask = (swapped >= 0).reshape(j.shape)
    return np.where(mask, taken, values)


def walking(obs: Observation) -> Observation:
    """``obs`` with the robots travelling a patrol graph's edge (``obs.travel``) counted
    as choosing: a walk follower keeps its plan (its target on its walk) up to date at
    every cell of its walk, waypoints included, though the world moves a robot on a
    waypoint by its edge whatever it asks (the next cell of a walk along the edge)."""
    if obs.travel is None:
        return obs
    return replace(obs, choosing=obs.choosing | (obs.travel >= 0))


def prefer_open(obs: Observation) -> np.ndarray:
    """bool ``[R, K, D]``: the open moves, or every legal move where none is open.

    Robots avoid cells other robots stand in (the paper's "avoiding"), but a robot
    hemmed in still asks for a move, so that the world can make room for it.
    """
    return np.where(port_any(obs.open)[..., None], obs.open, obs.legal)


def choose_min(score: np.ndarray, mask: np.ndarray, u: np.ndarray) -> np.ndarray:
    """int ``[R, K]``: the masked direction of least ``score``, ties broken by ``u``.

    Args:
        score: float ``[R, K, D]``.
        mask: bool ``[R, K, D]``, the ports allowed.
        u: float ``[R, K]`` in [0, 1): the j-th tied port (port order: N, E, S, W on a
            grid) is taken, ``j = floor(u x ties)``.

    Returns:
        The direction, or -1 where the mask allows none.
    """
    masked = np.where(mask, score, np.inf)
    best = masked.min(axis=-1, keepdims=True)
    cand = mask & (masked == best)
    shape = cand.shape[:-1]
    action, has = pick(cand.reshape(-1, cand.shape[-1]), u.reshape(-1))
    return np.where(has, action, -1).reshape(shape)


def neighbour_values(values: np.ndarray, obs: Observation, per_group: bool) -> np.ndarray:
    """float ``[R, K, D]``: a per-cell map read at the far end of each robot's D ports:
    the neighbouring cell on a grid, the vertex at the other end of the edge on a patrol
    graph (:attr:`qpatrol.world.Params.far_cells`; robots choose at vertices only).

    Args:
        values: ``[R, G, C]`` (``per_group``: the robot's group map) or ``[R, K, C]``.
        obs: the observation (robots' cells, groups).
    """
    s, p = obs.state, obs.params
    targets = np.maximum(p.far_cells[s.pos], 0)  # [R, K, D]
    rows = np.arange(s.n_runs)[:, None, None]
    plane = obs.group_of()[None, :, None] if per_group else np.arange(p.n_agents)[None, :, None]
    return values[rows, plane, targets]
