"""The patrol world: a team of Q-learning agents on a grid maze, many runs in lockstep.

Description (paper §2; the model is specified in docs/model.md)
    Each free cell of the map is a *state*; agents move North, East, South or West
    (0..3), never into a wall. Dots lie on the free cells; entering a dot cell eats
    its dot. When every dot of a dot map is eaten the episode ends and the next one
    starts at once with all dots back, the agents where they are and their Q-tables
    kept: learning is online and never stops. An episode still running after
    ``max_episode_steps`` team steps ends as *truncated*.

State of an agent (the Q-table index)
    ``(cell, heading)``, heading being the direction of the move that brought the
    agent to the cell; with ``state_space: cell`` the heading index is always 0.

Reward on entering ``s'``
    ``dot(s') + incremental_value * min(1, idle(s') / idle_horizon) + lambda_w * lambda``
    with ``idle(s') = t - last visit of s'`` on the agent's last-visit map and
    ``lambda = dots eaten / state visits`` in the current episode of its dot map
    (this move included).

Team (paper §4)
    Agents act one after the other in index order within a team step. With
    communication on they share one dot map and one last-visit map ("group" 0); with
    it off each agent k has private ones (group k). With collision avoidance a move
    into a cell where another agent stood at the start of the step, or that an
    earlier agent has claimed this step, is masked: two agents never share a cell and
    never swap. An agent with no legal move waits (no Q-update).

Battery
    Each move costs 1. A patrolling agent whose charge is at most its distance to the
    nearest ``H`` plus ``margin`` turns to *homing*: it follows a shortest path to the
    nearest charging station not occupied by another agent that its charge can reach
    (else to the nearest one, waiting while its path is blocked), rests ``charge_steps``
    team steps there and resumes patrol with a full charge. Homing moves eat dots and
    count as visits but do not update Q.

Arrays carry a leading axis over runs ``R`` and then agents ``K``; ``G`` is the
number of dot maps per run (1 with communication, K without), ``C`` the number of
cells. :func:`step` advances every run by one team step, in place, with no Python
loop over runs (only over the agents of the team, whose moves are sequential).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from qpatrol import learner
from qpatrol.config import Config, ConfigError
from qpatrol.maps import BIG, DIRECTIONS, SMALL_DOT, Map, bfs

PATROL, HOMING, CHARGING = 0, 1, 2


@dataclass(frozen=True)
class Params:
    """Everything constant during a run, built once from a config and a map.

    Cell arrays are ``[C]`` or ``[C, 4]``; home arrays ``[H]`` or ``[H, C]``.
    """

    n_cells: int
    n_agents: int
    neighbors: np.ndarray  # int [C, 4], next state per direction, -1 = wall
    wall_legal: np.ndarray  # bool [C, 4], move is not into a wall
    dot_value: np.ndarray  # float [C], reward of the dot initially on the cell (0 if none)
    has_dot: np.ndarray  # bool [C], the cell holds a dot at an episode's start
    homes: np.ndarray  # int [H], states of charging stations
    is_home: np.ndarray  # bool [C]
    home_dist: np.ndarray  # int [H, C], moves from cell to home h
    home_dir: np.ndarray  # int [H, C], first direction on a shortest path to h (-1 at h)
    nearest_home_dist: np.ndarray  # int [C]
    starts: np.ndarray  # int [n], start cells given by the map's digits
    gamma: float
    epsilon: float
    q_init: np.ndarray  # float [4], initial Q per direction (multiplier applied)
    use_heading: bool
    initial_heading: int
    incremental_value: float
    idle_horizon: float
    lambda_weight: float
    communication: bool
    avoid_collisions: bool
    battery: bool
    capacity: int
    margin: int
    charge_steps: int
    max_episode_steps: int  # 0 = no limit
    episodes: int  # 0 = no limit
    warmup: int

    @property
    def n_groups(self) -> int:
        """Dot maps per run: 1 shared map with communication, one per agent without."""
        return 1 if self.communication else self.n_agents


def make_params(cfg: Config, m: Map) -> Params:
    """Build :class:`Params`; raise :class:`ConfigError` if config and map do not fit."""
    k = cfg["agents"]
    c = m.n_cells
    if k > c:
        raise ConfigError(f"agents: {k} agents do not fit on map {m.name} ({c} free cells)")
    dot_value = np.zeros(c)
    dot_value[m.dot_kind == SMALL_DOT] = cfg["reward.dot_value"]
    dot_value[m.dot_kind == BIG] = cfg["reward.big_dot_value"]
    has_dot = m.dot_kind > 0
    if not has_dot.any():
        raise ConfigError(f"map: {m.name} has no dot, so no episode could ever end")
    homes = m.homes
    home_dist = (
        np.stack([bfs(m.neighbors, int(h)) for h in homes])
        if homes.size
        else (np.zeros((0, c), dtype=np.int64))
    )
    home_dir = np.full((homes.size, c), -1, dtype=np.int64)
    for i in range(homes.size):
        d = home_dist[i]
        for direction in range(3, -1, -1):  # N wins ties: written last
            nb = m.neighbors[:, direction]
            ok = (nb >= 0) & (d[np.maximum(nb, 0)] == d - 1)
            home_dir[i, ok] = direction
    nearest = home_dist.min(axis=0) if homes.size else np.zeros(c, dtype=np.int64)
    battery = bool(cfg["battery.enabled"])
    if battery:
        if not homes.size:
            raise ConfigError(
                f"battery.enabled: map {m.name} has no charging station 'H'; "
                "set battery.enabled=false or add one"
            )
        need = int(nearest.max()) + cfg["battery.margin"]
        if cfg["battery.capacity"] <= need:
            raise ConfigError(
                f"battery.capacity: {cfg['battery.capacity']} is too small for map {m.name}; "
                f"allowed: > {need} (farthest cell {int(nearest.max())} moves from H, plus "
                "battery.margin)"
            )
    q_init = np.array([cfg[f"learning.q_init.{d}"] for d in DIRECTIONS], dtype=np.float64)
    return Params(
        n_cells=c,
        n_agents=k,
        neighbors=m.neighbors,
        wall_legal=m.neighbors >= 0,
        dot_value=dot_value,
        has_dot=has_dot,
        homes=homes,
        is_home=np.isin(np.arange(c), homes),
        home_dist=home_dist,
        home_dir=home_dir,
        nearest_home_dist=nearest,
        starts=m.starts,
        gamma=float(cfg["learning.gamma"]),
        epsilon=float(cfg["learning.epsilon"]),
        q_init=q_init * cfg["learning.multiplier"],
        use_heading=cfg["learning.state_space"] == "cell_heading",
        initial_heading=DIRECTIONS.index(cfg["learning.initial_heading"]),
        incremental_value=float(cfg["reward.incremental_value"]),
        idle_horizon=float(cfg["reward.idle_horizon"]),
        lambda_weight=float(cfg["reward.lambda"]),
        communication=bool(cfg["team.communication"]),
        avoid_collisions=bool(cfg["team.avoid_collisions"]),
        battery=battery,
        capacity=int(cfg["battery.capacity"]),
        margin=int(cfg["battery.margin"]),
        charge_steps=int(cfg["battery.charge_steps"]),
        max_episode_steps=int(cfg["max_episode_steps"] or 0),
        episodes=int(cfg["episodes"] or 0),
        warmup=int(cfg["record.warmup"]),
    )


@dataclass
class State:
    """The whole simulation state; every array has a leading runs axis ``R``.

    Attributes:
        t: team steps taken so far (the same for every run).
        pos: int ``[R, K]``, the cell of each agent.
        head: int ``[R, K]``, direction of each agent's last move.
        q: float ``[R, K, C, 4, 4]``, Q[cell, heading, action] of each agent.
        n: int ``[R, K, C, 4, 4]``, times each (state, action) was chosen.
        dots: bool ``[R, G, C]``, dot still present on a group's dot map.
        last: int ``[R, G, C]``, team step of the group's last visit of a cell (0 = never).
        dots_left: int ``[R, G]``, dots left in the current episode.
        ep_dots, ep_visits: int ``[R, G]``, dots eaten and cells entered this episode.
        ep_start: int ``[R, G]``, team step at which the current episode started (0-based).
        ep_count: int ``[R, G]``, episodes ended so far.
        ep_seen: bool ``[R, G, C]``, cells entered this episode.
        ep_seen_state: bool ``[R, G, C, 4]``, (cell, heading) states entered this episode.
        charge: int ``[R, K]``, battery left; mode: ``[R, K]`` PATROL/HOMING/CHARGING;
        rest: int ``[R, K]``, charging steps left.
        active: bool ``[R]``, run still going (False once its episode quota is met).
        steps_done: int ``[R]``, team steps the run has taken.
        world_last: int ``[R, C]``, true last visit of each cell by any agent.
        visits: int ``[R, K, C]``, cells entered by each agent.
        idle_sum: float ``[R]``, sum over measured steps of the mean idleness over cells.
        idle_max: int ``[R]``, worst idleness seen; measured: int ``[R]``, steps measured.
        gap_sum, gap_count, gap_max: ``[R]``, intervals between two visits of a cell.
        waits: int ``[R, K]``, steps an agent could have moved but had no legal move.
    """

    t: int
    pos: np.ndarray
    head: np.ndarray
    q: np.ndarray
    n: np.ndarray
    dots: np.ndarray
    last: np.ndarray
    dots_left: np.ndarray
    ep_dots: np.ndarray
    ep_visits: np.ndarray
    ep_start: np.ndarray
    ep_count: np.ndarray
    ep_seen: np.ndarray
    ep_seen_state: np.ndarray
    charge: np.ndarray
    mode: np.ndarray
    rest: np.ndarray
    active: np.ndarray
    steps_done: np.ndarray
    world_last: np.ndarray
    visits: np.ndarray
    idle_sum: np.ndarray
    idle_max: np.ndarray
    measured: np.ndarray
    gap_sum: np.ndarray
    gap_count: np.ndarray
    gap_max: np.ndarray
    waits: np.ndarray

    @property
    def n_runs(self) -> int:
        return int(self.pos.shape[0])


def place_agents(p: Params, m: Map, rng: np.random.Generator) -> np.ndarray:
    """int ``[K]``: start cells of one run's agents.

    Agent k < (number of start digits) starts on its digit. Each further agent goes to
    the free cell farthest (shortest path) from every agent placed so far, ties broken
    by ``rng``, which spreads the team over the map.
    """
    k = p.n_agents
    placed = list(p.starts[:k])
    if len(placed) < k:
        dist = m.distances()
        while len(placed) < k:
            if placed:
                far = dist[placed].min(axis=0)
            else:
                far = np.ones(p.n_cells, dtype=np.int64)
            far[placed] = -1
            best = np.flatnonzero(far == far.max())
            placed.append(int(best[rng.integers(best.size)]))
    return np.array(placed, dtype=np.int64)


def init_state(p: Params, start_cells: np.ndarray) -> State:
    """The state before the first step. ``start_cells``: int ``[R, K]``."""
    r, k, c, g = start_cells.shape[0], p.n_agents, p.n_cells, p.n_groups
    q = np.broadcast_to(p.q_init, (r, k, c, 4, 4)).copy()
    dots = np.broadcast_to(p.has_dot, (r, g, c)).copy()
    zeros_rg = np.zeros((r, g), dtype=np.int64)
    return State(
        t=0,
        pos=start_cells.astype(np.int64).copy(),
        head=np.full((r, k), p.initial_heading, dtype=np.int64),
        q=q,
        n=np.zeros((r, k, c, 4, 4), dtype=np.int64),
        dots=dots,
        last=np.zeros((r, g, c), dtype=np.int64),
        dots_left=np.full((r, g), int(p.has_dot.sum()), dtype=np.int64),
        ep_dots=zeros_rg.copy(),
        ep_visits=zeros_rg.copy(),
        ep_start=zeros_rg.copy(),
        ep_count=zeros_rg.copy(),
        ep_seen=np.zeros((r, g, c), dtype=bool),
        ep_seen_state=np.zeros((r, g, c, 4), dtype=bool),
        charge=np.full((r, k), p.capacity, dtype=np.int64),
        mode=np.zeros((r, k), dtype=np.int64),
        rest=np.zeros((r, k), dtype=np.int64),
        active=np.ones(r, dtype=bool),
        steps_done=np.zeros(r, dtype=np.int64),
        world_last=np.zeros((r, c), dtype=np.int64),
        visits=np.zeros((r, k, c), dtype=np.int64),
        idle_sum=np.zeros(r),
        idle_max=np.zeros(r, dtype=np.int64),
        measured=np.zeros(r, dtype=np.int64),
        gap_sum=np.zeros(r),
        gap_count=np.zeros(r, dtype=np.int64),
        gap_max=np.zeros(r, dtype=np.int64),
        waits=np.zeros((r, k), dtype=np.int64),
    )


class Recorder(Protocol):
    """Receives what happens during a step; see :mod:`qpatrol.records`."""

    wants_updates: bool

    def updates(self, t: int, agent: int, runs: np.ndarray, cols: dict[str, np.ndarray]) -> None:
        """Q-updates of agent ``agent`` at step ``t`` in batch rows ``runs``; ``cols`` holds
        ``[B]`` arrays cell, heading, action, reward, next_cell, next_heading, alpha,
        q_before, q_after, bootstrap (gamma max Q(s')) and ``q_row`` ``[B, 4]`` (after)."""
        ...

    def episodes(
        self, t: int, runs: np.ndarray, groups: np.ndarray, state: State, complete: np.ndarray
    ) -> None: ...


def step(state: State, p: Params, u: np.ndarray, rec: Recorder | None = None) -> State:
    """Advance every active run by one team step, in place; returns ``state``.

    Args:
        state: the current state (modified).
        p: the run parameters.
        u: float ``[R, K, 2]`` uniforms in [0, 1) for this step: ``u[..., 0]`` decides
            epsilon exploration, ``u[..., 1]`` breaks ties.
        rec: optional recorder of Q-updates and episode ends.
    """
    s = state
    s.t += 1
    t = s.t
    R, K = s.pos.shape
    ar = np.arange(R)
    active = s.active
    start_pos = s.pos.copy()
    record = rec is not None and rec.wants_updates
    for k in range(K):
        c = s.pos[:, k].copy()  # [R] cell before the move (s.pos changes below)
        g = 0 if p.communication else k
        hs = s.head[:, k].copy() if p.use_heading else np.zeros(R, dtype=np.int64)

        # --- battery: charging countdown, patrol -> homing ---------------------------
        resting = np.zeros(R, dtype=bool)
        if p.battery:
            resting = active & (s.mode[:, k] == CHARGING)
            if resting.any():
                s.rest[resting, k] -= 1
                done = resting & (s.rest[:, k] <= 0)
                s.mode[done, k] = PATROL
                s.charge[done, k] = p.capacity
            low = (
                active
                & (s.mode[:, k] == PATROL)
                & (s.charge[:, k] <= p.nearest_home_dist[c] + p.margin)
            )
            s.mode[low, k] = HOMING
            arrived = active & (s.mode[:, k] == HOMING) & p.is_home[c]
            if arrived.any():
                _start_charging(s, p, arrived, k)
                resting |= arrived
        patrol = active & (s.mode[:, k] == PATROL) & ~resting
        homing = active & (s.mode[:, k] == HOMING)

        # --- legal moves: walls, then other agents' cells and claims -----------------
        targets = p.neighbors[c]  # [R, 4]
        legal = targets >= 0
        if p.avoid_collisions and K > 1:
            others = np.concatenate([start_pos[:, :k], start_pos[:, k + 1 :], s.pos[:, :k]], axis=1)
            legal &= ~(targets[:, :, None] == others[:, None, :]).any(axis=2)

        # --- choice: learned policy while patrolling, shortest path while homing -----
        q_row = s.q[ar, k, c, hs]  # [R, 4]
        action, can = learner.choose(q_row, legal, u[:, k, 0], u[:, k, 1], p.epsilon)
        if homing.any():
            occupied = start_pos[:, :, None] == p.homes[None, None, :]  # [R, K, H]
            occupied[:, k] = False
            dist = p.home_dist[:, c].T  # [R, H]
            free = np.where(occupied.any(axis=1), 10 * p.n_cells, dist)
            # a free station within reach of the charge left, else the nearest one
            reach = free.min(axis=1) <= s.charge[:, k]
            goal = np.where(reach, free.argmin(axis=1), dist.argmin(axis=1))
            a_home = p.home_dir[goal, c]
            ok = (a_home >= 0) & legal[ar, np.maximum(a_home, 0)]
            action = np.where(homing, np.maximum(a_home, 0), action)
            can = np.where(homing, ok, can)
        wants = patrol | homing
        s.waits[wants & ~can, k] += 1
        movers = np.flatnonzero(wants & can)
        if movers.size == 0:
            continue

        # --- move and world effects -----------------------------------------------
        a = action[movers]
        c0 = c[movers]
        c1 = targets[movers, a]
        h0 = hs[movers]
        eaten = s.dots[movers, g, c1]
        s.dots[movers, g, c1] = False
        s.dots_left[movers, g] -= eaten
        s.ep_dots[movers, g] += eaten
        s.ep_visits[movers, g] += 1
        idle = t - s.last[movers, g, c1]
        s.last[movers, g, c1] = t
        s.ep_seen[movers, g, c1] = True
        s.ep_seen_state[movers, g, c1, a] = True
        reward = (
            np.where(eaten, p.dot_value[c1], 0.0)
            + p.incremental_value * np.minimum(1.0, idle / p.idle_horizon)
            + p.lambda_weight * s.ep_dots[movers, g] / s.ep_visits[movers, g]
        )
        s.pos[movers, k] = c1
        s.head[movers, k] = a
        if p.battery:
            s.charge[movers, k] -= 1

        # patrolling measures: intervals between two visits of a cell, visit counts
        prev = s.world_last[movers, c1]
        s.world_last[movers, c1] = t
        s.visits[movers, k, c1] += 1
        if t > p.warmup:
            seen_before = prev > 0
            gap = np.where(seen_before, t - prev, 0)
            s.gap_sum[movers] += gap
            s.gap_count[movers] += seen_before
            s.gap_max[movers] = np.maximum(s.gap_max[movers], gap)

        # --- Q-learning update (patrol moves only) -----------------------------------
        learn = patrol[movers]
        if learn.any():
            rl, ca, ha, aa, cb = movers[learn], c0[learn], h0[learn], a[learn], c1[learn]
            hb = aa if p.use_heading else np.zeros_like(aa)
            target, bootstrap = learner.td_target(
                reward[learn], s.q[rl, k, cb, hb], p.wall_legal[cb], p.gamma
            )
            q_before = s.q[rl, k, ca, ha, aa]
            q_after, n_after, alpha = learner.update(q_before, s.n[rl, k, ca, ha, aa], target)
            s.q[rl, k, ca, ha, aa] = q_after
            s.n[rl, k, ca, ha, aa] = n_after
            if record:
                rec.updates(
                    t,
                    k,
                    rl,
                    {
                        "cell": ca,
                        "heading": ha,
                        "action": aa,
                        "reward": reward[learn],
                        "next_cell": cb,
                        "next_heading": hb,
                        "alpha": alpha,
                        "q_before": q_before,
                        "q_after": q_after,
                        "bootstrap": bootstrap,
                        "q_row": s.q[rl, k, ca, ha],
                    },
                )

        # --- homing agents that reached a station start charging --------------------
        if p.battery:
            home_now = np.zeros(R, dtype=bool)
            home_now[movers] = homing[movers] & p.is_home[c1]
            if home_now.any():
                _start_charging(s, p, home_now, k)

    # --- idleness over the whole map, after the team has moved ------------------------
    if t > p.warmup:
        idle_now = t - s.world_last  # [R, C]
        s.idle_sum[active] += idle_now[active].mean(axis=1)
        s.idle_max[active] = np.maximum(s.idle_max[active], idle_now[active].max(axis=1))
        s.measured[active] += 1
    s.steps_done[active] = t

    # --- episode ends: all dots eaten, or too long ---------------------------------
    complete = active[:, None] & (s.dots_left == 0)
    ended = complete.copy()
    if p.max_episode_steps:
        ended |= active[:, None] & (t - s.ep_start >= p.max_episode_steps)
    if ended.any():
        runs, groups = np.nonzero(ended)
        if rec is not None:
            rec.episodes(t, runs, groups, s, complete[runs, groups])
        s.dots[runs, groups] = p.has_dot
        s.dots_left[runs, groups] = int(p.has_dot.sum())
        s.ep_dots[runs, groups] = 0
        s.ep_visits[runs, groups] = 0
        s.ep_seen[runs, groups] = False
        s.ep_seen_state[runs, groups] = False
        s.ep_start[runs, groups] = t
        s.ep_count[runs, groups] += 1
        if p.episodes:
            s.active &= s.ep_count.min(axis=1) < p.episodes
    return s


def _start_charging(s: State, p: Params, which: np.ndarray, k: int) -> None:
    """Agents ``k`` of the runs in bool ``which [R]`` begin ``charge_steps`` of rest."""
    if p.charge_steps > 0:
        s.mode[which, k] = CHARGING
        s.rest[which, k] = p.charge_steps
    else:
        s.mode[which, k] = PATROL
        s.charge[which, k] = p.capacity
