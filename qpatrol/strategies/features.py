"""What a learned patrol policy observes: per-port features and graph features.

One implementation, read by the batched environment (:class:`qpatrol.envs.PatrolVectorEnv`,
both engines) and by the ``neural`` strategy that evaluates a trained policy inside
``qpatrol train``, so that a policy sees in ``train`` exactly what it saw in training.
Everything is computed from a :class:`~qpatrol.world.Observation` (the world before a
step), batched over runs ``R`` and robots ``K``; a robot decides at a patrol graph's
vertices (every cell of a grid), choosing one of ``D`` ports.

The *far target* of a port is the target at the other end of the edge it starts
(:func:`qpatrol.maps.core.far_targets`: the neighbour on a grid, the next vertex through
waypoints on a graph). A robot's *goal* is the target it is bound for: the far end of
the edge it travels (on a waypoint), else its own cell. Idleness of a target is ``t -
last visit`` on the robot's own last-visit map (the team's with ``team.communication``
on, its private one with it off): the world's, as the reward uses it. Other robots'
positions and goals are seen only with communication on (zeros with it off), as in
MAGEC's "with and without communication" (Goeckner et al., IROS 2024). Robots that
failed (``failures.robots``) are seen by no one.

**Port features** (:func:`ports`), float32 ``[R, K, P, D]``, ``P`` = len(:data:`PORT`)
features of each of the ``D`` ports (feature-major: ``[p, d]``); for port ``d`` of the
robot's cell and its far target ``v``::

    0 legal      1 if the port has a move (else every feature of the port is 0)
    1 idle       idleness of v / the largest idleness of a target (0..1)
    2 length     moves to v by the port / the map's longest such way (0..1]
    3 back       1 if the port leads back the way the robot came
    4 claimed    other robots whose goal is v
    5 nearer     other robots fewer moves from v than this robot by the port
    6 idle2      largest idleness among v's far targets but the robot's cell, as 1
    7 urgency    idleness of v / (the mean idleness of the targets + 1)

**Graph features** (:func:`nodes`), float32 ``[R, K, N, F]``, the ``N`` targets in cell
order (``graph_edges`` gives their edges)::

    0 idle       idleness of the target / the largest idleness (0..1)
    1 distance   moves from the robot to the target / the map's diameter
    2 self       1 where the robot stands
    3 others     other robots standing on the target
    4 goals      other robots bound for it along an edge
    5 urgency    idleness / (the mean idleness + 1)

Edges (:meth:`Tables.graph_edges`): int64 ``edge_index`` ``[2, E]`` (both directions of
each way between two targets, indices into the ``N`` targets) and float32
``edge_attr`` ``[E, 1]`` (its moves / the longest way).
"""

from __future__ import annotations

import numpy as np

from qpatrol.maps import Map
from qpatrol.maps.core import far_targets
from qpatrol.world import GONE, Observation, Params

GONE = int(GONE)

PORT: tuple[str, ...] = (
    "legal",
    "idle",
    "length",
    "back",
    "claimed",
    "nearer",
    "idle2",
    "urgency",
)
NODE: tuple[str, ...] = ("idle", "distance", "self", "others", "goals", "urgency")


class Tables:
    """A map's constants for the features (built once per map and config).

    Attributes:
        far, length: int ``[C, D]``, each port's far target and moves to it (-1: none).
        grid: True when a heading is the direction of the last move (a grid), False when
            it is the port arrived through (a patrol graph).
        ahead: int ``[C, D]``, the target a robot on cell c with heading h is bound for:
            the far end of its edge on a waypoint, c itself elsewhere.
        dist: int ``[C, C]``, moves between cells.
        targets: int ``[N]``, the target cells; index: int ``[C]``, a cell's index among
            them (-1: not a target).
    """

    def __init__(self, m: Map, p: Params):
        far, length = far_targets(m.neighbors, m.back, m.target)
        self.far, self.length = far, length
        self.legal = far >= 0
        self.far0 = np.maximum(far, 0)
        self.max_len = float(max(1, int(length.max())))
        self.grid = not m.is_graph
        self.dist = m.distances()
        self.diameter = float(max(1, int(self.dist.max())))
        self.targets = np.flatnonzero(m.target)
        self.index = np.full(m.n_cells, -1, dtype=np.int64)
        self.index[self.targets] = np.arange(self.targets.size)
        self.target = m.target
        self.communication = p.communication
        self.ahead = _ahead(m, p)
        # each target's far targets (the 2-hop look-ahead of a port)
        self.far2 = np.where(self.legal, far, -1)

    def back_port(self, head: np.ndarray) -> np.ndarray:
        """int: the port that leads back the way a robot came, from its heading."""
        return (head + 2) % 4 if self.grid else head

    def adjacency(self) -> np.ndarray:
        """float64 ``[N, N]``: row i averages over target i's neighbours (the far targets
        of its ports): a graph network's mean aggregation."""
        index, _ = self.graph_edges()
        n = self.targets.size
        a = np.zeros((n, n))
        a[index[1], index[0]] = 1.0
        return a / np.maximum(a.sum(axis=1, keepdims=True), 1.0)

    def port_nodes(self, pos: np.ndarray) -> np.ndarray:
        """int ``[..., D]``: the index among the targets of each port's far target from
        cells ``pos`` (0 where the port has none)."""
        return np.maximum(self.index[self.far0[pos]], 0) * self.legal[pos]

    def graph_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """``(edge_index int64 [2, E], edge_attr float32 [E, 1])`` between targets."""
        src, port = np.nonzero(self.legal & self.target[:, None])
        dst = self.far[src, port]
        index = np.stack([self.index[src], self.index[dst]]).astype(np.int64)
        attr = (self.length[src, port] / self.max_len).astype(np.float32)[:, None]
        return index, attr


def _ahead(m: Map, p: Params) -> np.ndarray:
    """int ``[C, D]``: the target a robot standing on cell c with heading h is bound for
    (:attr:`Tables.ahead`)."""
    c_all = np.arange(m.n_cells)
    ahead = np.repeat(c_all[:, None], m.neighbors.shape[1], axis=1)
    if p.onward is None:
        return ahead
    for c in np.flatnonzero(~m.target).tolist():
        for h in range(m.neighbors.shape[1]):
            out = int(p.onward[c, h])
            if out < 0:
                continue
            cur, port, n = c, out, 0
            while not m.target[cur] and n <= m.n_cells:
                nxt = int(m.neighbors[cur, port])
                came = int(m.back[cur, port])
                cur = nxt
                if m.target[cur]:
                    break
                port = int(p.onward[cur, came]) if p.onward[cur, came] >= 0 else -1
                if port < 0:
                    break
                n += 1
            ahead[c, h] = cur if m.target[cur] else c
    return ahead


def _scalar(f):
    """``f`` compiled by numba when it imports, else run as
    the plain Python it is: the same numbers, slower."""
    try:
        from numba import njit
    except ImportError:  # pragma: no cover - CI installs numba
        return f
    return njit(cache=True, nogil=True, error_model="numpy")(f)


@_scalar
def _idle_stats(t, last, targets, top, mean):
    """The largest idleness (at least 1) and the mean idleness of the targets on each
    dot group's map: ``top``, ``mean`` float ``[R, G]``."""
    for r in range(last.shape[0]):
        for g in range(last.shape[1]):
            oldest = t
            total = 0.0
            for i in range(targets.shape[0]):
                x = last[r, g, targets[i]]
                oldest = min(oldest, x)
                total += t - x
            top[r, g] = max(1.0, float(t - oldest))
            mean[r, g] = total / targets.shape[0]


@_scalar
def _fill_ports(t, pos, head, mode, last, comm, tab_i, length, max_len, grid, dist, out):
    """:func:`ports` on the world's arrays (``pos``, ``head``, ``mode`` ``[R, K]``,
    ``last`` ``[R, G, C]``) and the map's: ``tab_i`` = (far ``[C, D]``, ahead ``[C,
    D]``, targets ``[N]``), ``length`` ``[C, D]``; into ``out`` ``[R, K, P, D]``."""
    far, ahead, targets = tab_i
    n_runs, n_agents = pos.shape
    n_ports = far.shape[1]
    top = np.empty((n_runs, last.shape[1]))
    mean = np.empty((n_runs, last.shape[1]))
    _idle_stats(t, last, targets, top, mean)
    for r in range(n_runs):
        for k in range(n_agents):
            g = 0 if comm else k
            c = pos[r, k]
            back = (head[r, k] + 2) % 4 if grid else head[r, k]
            for d in range(n_ports):
                for j in range(out.shape[2]):
                    out[r, k, j, d] = 0.0
                v = far[c, d]
                if v < 0:
                    continue
                idle_v = float(t - last[r, g, v])
                out[r, k, 0, d] = 1.0
                out[r, k, 1, d] = idle_v / top[r, g]
                out[r, k, 2, d] = length[c, d] / max_len
                out[r, k, 3, d] = 1.0 if d == back else 0.0
                if comm:  # the other live robots: bound for v, fewer moves from v
                    claimed = 0
                    nearer = 0
                    for j in range(n_agents):
                        if j == k or mode[r, j] == GONE or mode[r, k] == GONE:
                            continue
                        if ahead[pos[r, j], head[r, j]] == v:
                            claimed += 1
                        if dist[pos[r, j], v] < length[c, d]:
                            nearer += 1
                    out[r, k, 4, d] = claimed
                    out[r, k, 5, d] = nearer
                best2 = 0.0
                for e in range(n_ports):
                    v2 = far[v, e]
                    if v2 >= 0 and v2 != c:
                        best2 = max(best2, float(t - last[r, g, v2]))
                out[r, k, 6, d] = best2 / top[r, g]
                out[r, k, 7, d] = idle_v / (mean[r, g] + 1.0)
    return out


@_scalar
def _fill_nodes(t, pos, head, mode, last, comm, ahead, targets, dist, diameter, out):
    """:func:`nodes` on the world's arrays, into ``out`` ``[R, K, N, F]``."""
    n_runs, n_agents = pos.shape
    top = np.empty((n_runs, last.shape[1]))
    mean = np.empty((n_runs, last.shape[1]))
    _idle_stats(t, last, targets, top, mean)
    for r in range(n_runs):
        for k in range(n_agents):
            g = 0 if comm else k
            c = pos[r, k]
            for i in range(targets.shape[0]):
                v = targets[i]
                idle = float(t - last[r, g, v])
                out[r, k, i, 0] = idle / top[r, g]
                out[r, k, i, 1] = dist[c, v] / diameter
                out[r, k, i, 2] = 1.0 if c == v else 0.0
                out[r, k, i, 3] = 0.0
                out[r, k, i, 4] = 0.0
                out[r, k, i, 5] = idle / (mean[r, g] + 1.0)
            if not comm or mode[r, k] == GONE:
                continue
            for j in range(n_agents):  # the other live robots: where they stand, are bound
                if j == k or mode[r, j] == GONE:
                    continue
                cj = pos[r, j]
                if targets_index_of(targets, cj) >= 0:
                    out[r, k, targets_index_of(targets, cj), 3] += 1.0
                goal = ahead[cj, head[r, j]]
                if goal != cj:
                    out[r, k, targets_index_of(targets, goal), 4] += 1.0
    return out


@_scalar
def targets_index_of(targets, c):
    """The index of cell ``c`` among the sorted ``targets``, -1 if it is none."""
    lo, hi = 0, targets.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if targets[mid] < c:
            lo = mid + 1
        else:
            hi = mid
    return lo if lo < targets.shape[0] and targets[lo] == c else -1


def ports(obs: Observation, tab: Tables, out: np.ndarray | None = None) -> np.ndarray:
    """float32 ``[R, K, P, D]``: every robot's port features (:data:`PORT`, each for
    the ``D`` ports in turn), written into ``out`` when given."""
    s = obs.state
    r_n, k_n = s.pos.shape
    if out is None:
        out = np.empty((r_n, k_n, len(PORT), tab.far.shape[1]), dtype=np.float32)
    tab_i = (tab.far, tab.ahead, tab.targets)
    args = (s.t, s.pos, s.head, s.mode, s.last, tab.communication, tab_i, tab.length)
    _fill_ports(*args, tab.max_len, tab.grid, tab.dist, out)
    return out


def nodes(obs: Observation, tab: Tables, out: np.ndarray | None = None) -> np.ndarray:
    """float32 ``[R, K, N, F]``: every robot's graph features (:data:`NODE`), one row
    per target, written into ``out`` when given."""
    s = obs.state
    r_n, k_n = s.pos.shape
    if out is None:
        out = np.empty((r_n, k_n, tab.targets.size, len(NODE)), dtype=np.float32)
    args = (s.t, s.pos, s.head, s.mode, s.last, tab.communication, tab.ahead, tab.targets)
    _fill_nodes(*args, tab.dist, tab.diameter, out)
    return out
