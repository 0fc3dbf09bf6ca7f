"""What one robot observes: a flat float32 vector, and its bounds.

Layout (``FEATURES``; ``C`` cells, ``T`` = ``max_steps``)::

    0 cell      state number of the robot's cell, 0..C-1
    1 row, 2 col  its grid position
    3 heading   direction of its last move, 0..3 = N, E, S, W
    4 battery   charge left, 0..capacity (stays at capacity with the battery off)
    5 mode      0 patrol, 1 homing, 2 queued, 3 charging (qpatrol.world.battery)
    6.. 13      for N, E, S, W in turn: dot, idleness of the neighbour cell
                dot: 1 dot present, 0 none, -1 wall; idleness: team steps since the
                cell's last visit (t - last visit, every cell visited at step 0), -1 wall
    14 .. 14+C  (only with ``idleness_map``) idleness of every cell, by state number

On a patrol graph (``D`` ports): row and col are 0, the heading is the port the robot
arrived through (0..D-1), and features 6 .. 6+2D-1 are the pairs of ports 0..D-1 in
turn (:func:`features`), then the idleness map.

Dots and idleness are read on the robot's own maps: the team's shared dot and
last-visit maps with ``team.communication`` on, the robot's private ones with it off;
the same maps the world's reward uses.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from qpatrol import world
from qpatrol.envs.sim import Sim

FEATURES: tuple[str, ...] = (
    "cell",
    "row",
    "col",
    "heading",
    "battery",
    "mode",
    "dot_n",
    "idle_n",
    "dot_e",
    "idle_e",
    "dot_s",
    "idle_s",
    "dot_w",
    "idle_w",
)
N_BASE = len(FEATURES)


def features(n_ports: int) -> tuple[str, ...]:
    """The names of an observation's base features on a map with ``n_ports`` ports:
    :data:`FEATURES` on a grid (4), ``dot_0``, ``idle_0``, ... per port otherwise."""
    if n_ports == 4:
        return FEATURES
    pairs = tuple(f"{k}_{d}" for d in range(n_ports) for k in ("dot", "idle"))
    return FEATURES[:6] + pairs


def space(sim: Sim, idleness_map: bool) -> spaces.Box:
    """The observation space of one robot of ``sim`` (float32, :func:`bounds`)."""
    shape = sim.map.free.shape if not sim.map.is_graph else (1, 1)
    low, high = bounds(sim.params, shape, sim.max_steps, idleness_map)
    return spaces.Box(low, high, dtype=np.float32)


def bounds(p: world.Params, shape: tuple[int, int], max_steps: int, idleness_map: bool):
    """``(low, high)`` float32 ``[D]``: the bounds of an observation vector.

    ``shape`` is the map grid's (rows, cols). Idleness never exceeds the team steps
    taken, hence ``max_steps``.
    """
    rows, cols = shape
    d = p.neighbors.shape[1]
    low = [0, 0, 0, 0, 0, 0] + [-1, -1] * d
    high = [max(p.n_cells - 1, 1), max(rows - 1, 1), max(cols - 1, 1), d - 1]
    high += [max(p.capacity, 1), 3] + [1, max_steps] * d
    if idleness_map:
        low += [0] * p.n_cells
        high += [max_steps] * p.n_cells
    return np.array(low, dtype=np.float32), np.array(high, dtype=np.float32)


def observe(s: world.State, p: world.Params, coords: np.ndarray, idleness_map: bool) -> np.ndarray:
    """float32 ``[K, D]``: every robot's observation vector (run 0 of ``s``).

    Args:
        s: the world (``R = 1``).
        p: its parameters.
        coords: int ``[C, 2]``, (row, col) of each cell (a graph's -1: read as 0).
        idleness_map: append the idleness of every cell on the robot's map.
    """
    k = p.n_agents
    pos = s.pos[0]
    group = np.zeros(k, dtype=np.int64) if p.communication else np.arange(k)
    idle = s.t - s.last[0]  # [G, C]
    nb = p.neighbors[pos]  # [K, D]
    wall = nb < 0
    nbc = np.maximum(nb, 0)
    dots = np.where(wall, -1, s.dots[0][group[:, None], nbc])
    idles = np.where(wall, -1, idle[group[:, None], nbc])
    base = np.column_stack([pos, np.maximum(coords[pos], 0), s.head[0], s.charge[0], s.mode[0]])
    pairs = np.stack([dots, idles], axis=-1).reshape(k, 2 * nb.shape[1])
    parts = [base, pairs]
    if idleness_map:
        parts.append(idle[group])
    return np.concatenate(parts, axis=1).astype(np.float32)


def infos(sim: Sim) -> list[dict]:
    """One ``info`` dict per robot, after a reset or a step.

    Keys: ``action_mask`` int8 ``[D]`` (4 on a grid; 1 = a move the robot may choose:
    its open moves, or every non-wall move when none is open; all 0 when the world moves the robot
    itself, or once the run is over), ``choosing`` (the world asks this robot for the
    next move), ``t`` (team steps taken), and about the last step: ``moved``,
    ``as_asked`` (made the move it asked for), ``eaten`` (ate a dot), ``episode_ended``
    (an episode of its dot map ended).
    """
    k = sim.n_agents
    if sim.done:
        mask = np.zeros((k, sim.map.n_ports), dtype=np.int8)
        choosing = np.zeros(k, dtype=bool)
    else:
        mask = sim.open_moves().astype(np.int8)
        choosing = sim.obs.choosing[0]
    out = sim.outcome
    ended = np.zeros(k, dtype=bool)
    if out is not None and out.episodes.runs.size:
        group = np.zeros(k, dtype=np.int64) if sim.params.communication else np.arange(k)
        ended = np.isin(group, out.episodes.groups)
    result = []
    for i in range(k):
        result.append(
            {
                "action_mask": mask[i],
                "choosing": bool(choosing[i]),
                "t": int(sim.state.t),
                "moved": bool(out.moved[0, i]) if out is not None else False,
                "as_asked": bool(out.as_asked[0, i]) if out is not None else False,
                "eaten": bool(out.eaten[0, i]) if out is not None else False,
                "episode_ended": bool(ended[i]),
            }
        )
    return result
