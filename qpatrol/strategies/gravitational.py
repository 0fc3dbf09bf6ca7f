"""``gravitational`` (Sampaio, Ramalho and Tedesco 2010): robots pulled by the masses of
idle targets.

Every target has a *mass* that grows with its idleness ``I`` (the robot's group map: the
team's shared last-visit map with communication on, its own without):
``gravity.growth`` ``arithmetic`` (mass ``I``), ``geometric`` (``(1 + r)^(I - 1)``,
``r = gravity.growth_rate``, 0 for ``I = 0``) or ``none`` (mass 1). A target that is a
robot's *goal* (the target at the far end of the port of its last decision, until it
decides again) weighs nothing: with communication on every robot's goal, its own
included, with it off only its own. A target z pulls a robot on target x with the
*force* ``mass(z) / L^e`` (``e = gravity.exponent``, L moves on shortest paths), and
``gravity.propagation`` says where the force acts and ``gravity.combination`` (``sum``
or ``max``) how the forces on one port add up:

- ``edge``: every z but x acts on the lowest port of x that starts a shortest path to z,
  with ``L = L(x, z)``.
- ``node``: each port's far target y gathers a *combined mass*, the combination over
  every target z of ``mass(z) / L(y, z)^e`` (y's own mass counted whole), divided by
  the port's length in moves.
- ``node_no_distance``: the same combined mass, not divided.
- ``mixed``: every z but x acts on every port, with ``L`` the port's length plus
  ``L(y, z)`` from its far target y.

The robot takes the open port of greatest force (every legal port when none is open),
ties to the j-th tied port in port order, ``j = floor(u x ties)`` with its tie-break
uniform; robots decide in robot order, each seeing the goals chosen before it. Forces
are float64 products ``mass x (1 / L^e)`` (the table of ``1 / L^e`` by ``math.pow``,
the same numbers the compiled engine reads), summed target by target in cell order.
SimPatrol's gravitational clients (``GravityManager``, ``GravityPropagator*``,
``MassGrowth``): docs/model.md, "Strategies", says how this differs from them.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from qpatrol.maps.core import far_targets
from qpatrol.strategies import base, learner
from qpatrol.world import battery

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.world import Observation, Params

#: ``gravity.growth``, ``gravity.combination``, ``gravity.propagation``: their codes
#: (the compiled twin reads the same).
GROWTHS = ("arithmetic", "geometric", "none")
COMBINATIONS = ("sum", "max")
PROPAGATIONS = ("edge", "node", "node_no_distance", "mixed")
ARITHMETIC, GEOMETRIC, NO_GROWTH = 0, 1, 2
SUM, MAX = 0, 1
EDGE, NODE, NODE_NO_DISTANCE, MIXED = 0, 1, 2, 3


def power(x: float, y: float) -> float:
    """``x ** y`` by the C library's ``pow`` (``math.pow``, which the compiled engine
    calls too), infinite where it overflows (where ``math.pow`` raises)."""
    try:
        return math.pow(x, y)
    except OverflowError:
        return math.inf


def inverse_powers(n: int, exponent: float) -> np.ndarray:
    """float64 ``[n + 1]``: ``1 / L^exponent`` for L = 0..n moves, 1 for L = 0 (a
    target's own mass in its combined mass)."""
    out = np.ones(n + 1)
    for length in range(1, n + 1):
        out[length] = 1.0 / power(float(length), exponent)
    return out


def growth_of(idle: np.ndarray, growth: int, ratio: float) -> np.ndarray:
    """float64, the shape of ``idle`` (int >= 0): the mass of a target of that idleness.
    ``ratio``: 1 + the geometric growth rate."""
    if growth == ARITHMETIC:
        return idle.astype(np.float64)
    if growth == NO_GROWTH:
        return np.ones(idle.shape)
    values, index = np.unique(idle, return_inverse=True)
    table = np.array([0.0 if v == 0 else power(ratio, float(v - 1)) for v in values.tolist()])
    return table[index.reshape(idle.shape)]


def combine(values: np.ndarray, combination: int) -> np.ndarray:
    """float64 ``[B]``: the rows of ``values`` ``[B, T]`` (forces >= 0, 0 for none)
    summed one by one left to right (``cumsum``: no pairwise summation, so the compiled
    loop's sum is the same to the bit), or their maximum."""
    if combination == MAX:
        return values.max(axis=1)
    return np.cumsum(values, axis=1)[:, -1]


class Strategy(base.Strategy):
    """``goal``: int ``[R, K]``, each robot's goal, the far target of its last decision
    (-1: none). The keys: ``growth``, ``ratio`` (1 + growth rate), ``combination``,
    ``propagation`` (codes), ``inv`` (float64 ``1 / L^e`` by L). ``targets`` int ``[T]``
    (cells, in order); ``dist`` int ``[C, T]`` moves from each cell to each target (-1:
    unreachable); ``tcost`` int ``[C, D]`` each port's length in moves to its far
    target."""

    name = "gravitational"
    numpy_cell_us = 0.07  # (base.Strategy.numpy_cell_us)

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.growth = GROWTHS.index(cfg["gravity.growth"])
        self.ratio = 1.0 + float(cfg["gravity.growth_rate"])
        self.combination = COMBINATIONS.index(cfg["gravity.combination"])
        self.propagation = PROPAGATIONS.index(cfg["gravity.propagation"])
        self.targets = np.flatnonzero(m.target)
        self.dist = np.ascontiguousarray(m.distances()[:, self.targets])
        _, self.tcost = far_targets(m.neighbors, m.back, m.target)
        longest = int(max(self.dist.max(), 0) + max(self.tcost.max(), 0))
        self.inv = inverse_powers(longest, float(cfg["gravity.exponent"]))
        self.goal = np.full((self.n_runs, self.n_agents), -1, dtype=np.int64)

    def exchange(self, swapped: np.ndarray) -> None:
        """Robots that exchanged tasks exchange the goals they announced."""
        self.goal = base.partners(self.goal, swapped)

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        s, p = obs.state, obs.params
        n_runs, n_agents = s.pos.shape
        # a robot that leaves patrolling (homing, charging, failed) announces no goal
        self.goal[s.active[:, None] & (s.mode != battery.PATROL)] = -1
        mask = base.prefer_open(obs)
        ask = np.full((n_runs, n_agents), -1, dtype=np.int64)
        for k in range(n_agents):
            rows = np.flatnonzero(obs.choosing[:, k])
            if rows.size == 0:
                continue
            x = s.pos[rows, k]
            force = self.forces(x, self.masses(obs, k, rows))
            d, has = learner.choose(force, mask[rows, k], u[rows, k, 0], u[rows, k, 1], 0.0)
            d = np.where(has, d, -1)
            ask[rows, k] = d
            self.goal[rows, k] = np.where(d >= 0, p.far_cells[x, np.maximum(d, 0)], -1)
        return ask

    def masses(self, obs: Observation, k: int, rows: np.ndarray) -> np.ndarray:
        """float64 ``[B, T]``: robot k's masses of the targets in runs ``rows``, 0 at the
        goals it knows of (every robot's with communication, else its own)."""
        g = 0 if obs.params.communication else k
        idle = obs.t - obs.state.last[rows[:, None], g, self.targets[None, :]]
        mass = growth_of(idle, self.growth, self.ratio)
        goals = self.goal[rows] if obs.params.communication else self.goal[rows, k : k + 1]
        index = np.searchsorted(self.targets, np.maximum(goals, 0))
        b, j = np.nonzero(goals >= 0)
        mass[b, index[b, j]] = 0.0
        return mass

    def forces(self, x: np.ndarray, mass: np.ndarray) -> np.ndarray:
        """float64 ``[B, D]``: the force on each port of robots on cells ``x`` ``[B]``
        from the masses ``[B, T]`` (0 on a port no force acts on)."""
        nbrs = self.params.neighbors
        far = self.params.far_cells
        n_ports = nbrs.shape[1]
        dist = self.dist
        out = np.zeros((x.size, n_ports))
        if self.propagation == EDGE:
            dx = dist[x]
            pull = np.where(dx > 0, mass * self.inv[np.maximum(dx, 0)], 0.0)
            port = np.full(dx.shape, -1, dtype=np.int64)
            for d in range(n_ports):  # the lowest port that starts a shortest path
                n = nbrs[x, d]
                on = (port < 0) & (n >= 0)[:, None] & (dx > 0)
                port[on & (dist[np.maximum(n, 0)] == dx - 1)] = d
            for d in range(n_ports):
                out[:, d] = combine(np.where(port == d, pull, 0.0), self.combination)
            return out
        for d in range(n_ports):
            y = far[x, d]
            length = self.tcost[x, d]
            dy = dist[np.maximum(y, 0)]
            if self.propagation == MIXED:
                keep = (dy >= 0) & (self.targets[None, :] != x[:, None])
                reach = np.maximum(dy + length[:, None], 0)
            else:
                keep = dy >= 0
                reach = np.maximum(dy, 0)
            pull = np.where(keep, mass * self.inv[reach], 0.0)
            total = combine(pull, self.combination)
            if self.propagation == NODE:
                total = total / np.maximum(length, 1)
            out[:, d] = np.where(y >= 0, total, 0.0)
        return out
