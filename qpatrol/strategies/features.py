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

**Port features** (:func:`ports`), float32 ``[R, K, D, P]``, ``P`` = len(:data:`PORT`),
for port ``d`` of the robot's cell, far target ``v``::

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


def _view(obs: Observation, tab: Tables):
    """The pieces both kinds of features read: idleness of every target on each
    robot's map ``[R, K, C]`` (as float), its largest and mean, the robots' goals and
    who is seen."""
    s = obs.state
    r_n, k_n = s.pos.shape
    group = obs.group_of()
    last = s.last[:, group, :]  # [R, K, C]
    idle = (s.t - last).astype(np.float64)
    tgt_idle = idle[:, :, tab.targets]
    top = np.maximum(tgt_idle.max(axis=-1), 1.0)  # [R, K]
    mean = tgt_idle.mean(axis=-1)
    goal = tab.ahead[s.pos, s.head]  # [R, K]
    alive = s.mode != GONE
    # who sees whom: with communication every live robot sees the other live ones
    see = alive[:, :, None] & alive[:, None, :] & ~np.eye(k_n, dtype=bool)[None]
    if not tab.communication:
        see = np.zeros_like(see)
    return idle, top, mean, goal, see


def ports(obs: Observation, tab: Tables, out: np.ndarray | None = None) -> np.ndarray:
    """float32 ``[R, K, D, P]``: every robot's port features (:data:`PORT`), written
    into ``out`` when given."""
    s = obs.state
    r_n, k_n = s.pos.shape
    idle, top, mean, goal, see = _view(obs, tab)
    pos = s.pos
    legal = tab.legal[pos]  # [R, K, D]
    v = tab.far0[pos]  # [R, K, D]
    rr = np.arange(r_n)[:, None, None]
    kk = np.arange(k_n)[None, :, None]
    idle_v = idle[rr, kk, v]
    if out is None:
        out = np.empty((r_n, k_n, legal.shape[-1], len(PORT)), dtype=np.float32)
    out[..., 0] = legal
    out[..., 1] = idle_v / top[..., None]
    out[..., 2] = tab.length[pos] / tab.max_len
    back = tab.back_port(s.head)[..., None] == np.arange(legal.shape[-1])
    out[..., 3] = back
    # claimed: seen robots bound for v; nearer: seen robots fewer moves from v
    claimed = (see[:, :, :, None] & (goal[:, None, :, None] == v[:, :, None, :])).sum(axis=2)
    out[..., 4] = claimed
    d_other = tab.dist[pos[:, None, :, None], v[:, :, None, :]]  # [R, K, K', D]
    mine = tab.length[pos][:, :, None, :]
    out[..., 5] = (see[:, :, :, None] & (d_other < mine)).sum(axis=2)
    v2 = tab.far2[v]  # [R, K, D, D]
    ok2 = (v2 >= 0) & (v2 != pos[..., None, None])
    idle2 = np.where(ok2, idle[rr[..., None], kk[..., None], np.maximum(v2, 0)], 0.0).max(-1)
    out[..., 6] = idle2 / top[..., None]
    out[..., 7] = idle_v / (mean[..., None] + 1.0)
    out *= legal[..., None]
    return out


def nodes(obs: Observation, tab: Tables, out: np.ndarray | None = None) -> np.ndarray:
    """float32 ``[R, K, N, F]``: every robot's graph features (:data:`NODE`), one row
    per target, written into ``out`` when given."""
    s = obs.state
    r_n, k_n = s.pos.shape
    n = tab.targets.size
    idle, top, mean, goal, see = _view(obs, tab)
    tgt = tab.targets
    if out is None:
        out = np.empty((r_n, k_n, n, len(NODE)), dtype=np.float32)
    idle_t = idle[:, :, tgt]
    out[..., 0] = idle_t / top[..., None]
    out[..., 1] = tab.dist[s.pos][:, :, tgt] / tab.diameter
    out[..., 2] = s.pos[..., None] == tgt
    at = s.pos[:, None, :, None] == tgt  # [R, 1, K', N]: robot k' stands on the target
    out[..., 3] = (see[..., None] & at).sum(axis=2)
    travelling = goal != s.pos  # bound for another target along an edge
    bound = (travelling[:, None, :, None]) & (goal[:, None, :, None] == tgt)
    out[..., 4] = (see[..., None] & bound).sum(axis=2)
    out[..., 5] = idle_t / (mean[..., None] + 1.0)
    return out
