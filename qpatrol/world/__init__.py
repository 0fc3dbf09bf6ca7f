"""The patrol world: robots, dots, batteries and collisions on a grid maze, many runs in lockstep.

The world knows the map and where every robot is; it does not know how robots choose
where to go. A *strategy* (``qpatrol/strategies/``) picks the moves of the patrolling
robots; the world applies them under its rules and reports what happened in an
:class:`Outcome`, from which a strategy may learn and measures and recorders take
what they watch. The full model, in words, is ``docs/model.md``.

Description (paper §2)
    Each free cell of the map is a *state*; robots move North, East, South or West
    (0..3), never into a wall; on a patrol graph they move by a cell's ports 0..D-1
    (:attr:`qpatrol.maps.Map.entry` gives the heading after each move). Dots lie on the
    free cells; entering a dot cell eats its dot. When every dot of a dot map is eaten
    the episode ends and the next one starts at once with all dots back and the robots
    where they are. An episode still running after ``max_episode_steps`` team steps ends
    as *truncated*.

Reward on entering ``s'`` (what a learning strategy is paid)
    ``dot(s') + incremental_value * min(1, idle(s') / idle_horizon) + lambda_w * lambda``
    with ``idle(s') = t - last visit of s'`` on the robot's last-visit map and ``lambda =
    dots eaten / cells entered`` in the current episode of its dot map, this move
    included.

Team (paper §4)
    With communication on, the team shares one dot map and one last-visit map (group
    0); with it off each robot k has private ones (group k). Moves are resolved by
    :mod:`qpatrol.world.traffic` (never two robots in a cell, never a swap, and blocked
    robots yield) and batteries by :mod:`qpatrol.world.battery` (homing, station queues).

Arrays carry a leading axis over runs ``R``, then robots ``K``; ``G`` is the number of
dot maps per run (1 with communication, K without), ``C`` the number of cells and
``H`` the number of charging stations. :func:`step` advances every run by one team
step, in place, with Python loops only over the robots of a team.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from qpatrol.config import INTERACTIONS, Config, ConfigError
from qpatrol.maps import BIG, DIRECTIONS, SMALL_DOT, Map, bfs, search
from qpatrol.maps.core import balls, far_targets
from qpatrol.util.arrays import at, flat, port_any
from qpatrol.world import battery, interference, traffic

PATROL, HOMING, QUEUED, CHARGING = battery.PATROL, battery.HOMING, battery.QUEUED, battery.CHARGING
GONE = battery.GONE
EXCLUSIVE, INTERFERENCE, NONE = INTERACTIONS


@dataclass(frozen=True)
class Params:
    """Everything constant during a run, built once from a config and a map.

    Cell arrays are ``[C]`` or ``[C, D]`` (``D`` ports: 4 on a grid, N, E, S, W);
    station arrays ``[H]`` or ``[H, C]``.
    """

    n_cells: int
    n_agents: int
    neighbors: np.ndarray  # int [C, D], next state per port, -1 = wall (no move)
    wall_legal: np.ndarray  # bool [C, D], move is not into a wall
    entry: np.ndarray  # int [C, D], heading after the move out of c by port p (Map.entry)
    dot_value: np.ndarray  # float [C], reward of the dot initially on the cell (0 if none)
    has_dot: np.ndarray  # bool [C], the cell holds a dot at an episode's start
    homes: np.ndarray  # int [H], states of charging stations
    station_of: np.ndarray  # int [C], index into homes of the station on a cell, -1 if none
    home_dist: np.ndarray  # int [H, C], moves from cell to station h
    home_dir: np.ndarray  # int [H, C], first port on a shortest path to h (-1 at h)
    nearest_home_dist: np.ndarray  # int [C]
    depart_len: np.ndarray  # int [H], moves from station h to the nearest junction (>= 1)
    pocket_of: np.ndarray  # int [C], the station whose dead-end pocket holds the cell, -1
    pocket_depth: np.ndarray  # int [C], distance from the pocket's junction (0 outside)
    pocket_entry: np.ndarray  # int [H], the junction that cuts off a station's pocket, -1
    starts: np.ndarray  # int [n], start cells given by the map's digits
    target: np.ndarray  # bool [C], the cells the measures count (every grid cell; graph vertices)
    diameter: int  # longest shortest path between two cells
    # the most moves a task's aim lies from its robot (the stall bound's trip): the
    # diameter, or for hpcc, whose route is a simple path weighed by idleness, C - 1
    task_moves: int
    initial_heading: int
    # the reward's weights: a float, or float64 [R] when the rows of a batch differ
    # (:func:`with_run_values`; read a row's value with :func:`per_row`)
    incremental_value: float | np.ndarray
    idle_horizon: float | np.ndarray
    lambda_weight: float | np.ndarray
    communication: bool
    # how robots meet (team.interaction): EXCLUSIVE (one robot per cell, right of way,
    # pushes; :mod:`qpatrol.world.traffic`), INTERFERENCE (robots pass each other and stop
    # when they meet, :mod:`qpatrol.world.interference`) or NONE (they ignore each other)
    interaction: str
    battery: bool
    capacity: int
    margin: int
    charge_steps: int
    staggered: bool  # battery.initial_charge == "staggered"
    max_episode_steps: int  # 0 = no limit
    episodes: int  # 0 = no limit
    failures_at: int = 0  # the team step at whose end State.failed robots fail (0: none)
    # int [C, D]: on a graph's waypoint, for each heading (the port arrived by), the port
    # that continues the edge (the other one); -1 on vertices, every grid cell and unused
    # headings (onward_ports). None: no waypoint (every cell decides)
    onward: np.ndarray | None = None
    # int [C, D]: the target at the far end of each port of a target, through waypoints
    # (maps.core.far_targets; on a grid the neighbour); -1 elsewhere. None: neighbors
    far: np.ndarray | None = None
    # int [C, D]: on a graph's waypoint, for each heading (the port arrived by), the
    # target the robot reaches by travelling on (ahead_targets); -1 on targets and unused
    # headings. None: no waypoint
    ahead: np.ndarray | None = None
    # interference: a robot that comes within ``radius`` moves of a lower-numbered robot
    # stops for ``stop_steps`` team steps, at most once per ``cooldown`` steps; ``ball``
    # int [C, B], the cells within ``radius`` moves of each cell (maps.core.balls), None
    # under the other interactions
    radius: int = 0
    stop_steps: int = 0
    cooldown: int = 1
    ball: np.ndarray | None = None

    @property
    def avoid_collisions(self) -> bool:
        """One robot per cell, never a swap (``team.interaction: exclusive``)."""
        return self.interaction == EXCLUSIVE

    @property
    def n_targets(self) -> int:
        """Number of target cells (``target.sum()``)."""
        return int(self.target.sum())

    @property
    def far_cells(self) -> np.ndarray:
        """int ``[C, D]``: :attr:`far`, or :attr:`neighbors` where there is no waypoint."""
        return self.neighbors if self.far is None else self.far

    @property
    def n_groups(self) -> int:
        """Dot maps per run: 1 shared map with communication, one per robot without."""
        return 1 if self.communication else self.n_agents


def onward_ports(m: Map) -> np.ndarray | None:
    """int ``[C, D]``: for a robot on a patrol graph's waypoint ``c`` that arrived by port
    ``h``, the port ``onward[c, h]`` that continues its edge (the other port); -1 on
    vertices and for a heading that is no port of ``c``. None on a grid and on a graph
    without waypoints (no cell but decides)."""
    inside = ~m.target
    if not m.is_graph or not inside.any():
        return None
    onward = np.full(m.neighbors.shape, -1, dtype=np.int64)
    for c in np.flatnonzero(inside).tolist():
        ports = np.flatnonzero(m.neighbors[c] >= 0).tolist()
        if len(ports) == 2:
            onward[c, ports[0]], onward[c, ports[1]] = ports[1], ports[0]
    return onward


def ahead_targets(m: Map, onward: np.ndarray) -> np.ndarray:
    """int ``[C, D]``: for a robot on waypoint c that arrived by port h, the target it
    reaches travelling on by ``onward`` (the vertex at that end of its edge); -1 on
    targets and for a heading that is no port of c."""
    ahead = np.full(onward.shape, -1, dtype=np.int64)
    for c in np.flatnonzero(~m.target).tolist():
        for h in np.flatnonzero(onward[c] >= 0).tolist():
            prev, cur = c, int(m.neighbors[c, onward[c, h]])
            while not m.target[cur]:
                nxt = next(x for x in m.neighbors[cur].tolist() if x >= 0 and x != prev)
                prev, cur = cur, nxt
            ahead[c, h] = cur
    return ahead


def make_params(cfg: Config, m: Map) -> Params:
    """Build :class:`Params`; raise :class:`ConfigError` if config and map do not fit."""
    k = cfg["agents"]
    c = m.n_cells
    interaction = cfg["team.interaction"]
    exclusive = interaction == EXCLUSIVE
    if exclusive and 2 * k > c:
        raise ConfigError(
            f"agents: {k} robots on map {m.name} ({c} free cells) leave no room to yield; "
            f"allowed: at most {c // 2} (half the free cells)"
        )
    if k > c:
        raise ConfigError(f"agents: {k} agents do not fit on map {m.name} ({c} free cells)")
    if cfg["record.watch"] and m.n_ports != 4:
        raise ConfigError(
            f"record.watch: watch.csv holds a cell's four Q-values (q_north..q_west), and map "
            f"{m.name} has {m.n_ports} ports per cell; allowed here: [] (no watched cell)"
        )
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
        else np.zeros((0, c), dtype=np.int64)
    )
    home_dir = np.full((homes.size, c), -1, dtype=np.int64)
    for i in range(homes.size):
        d = home_dist[i]
        for direction in range(m.n_ports - 1, -1, -1):  # port 0 (N) wins ties: written last
            nb = m.neighbors[:, direction]
            ok = (nb >= 0) & (d[np.maximum(nb, 0)] == d - 1)
            home_dir[i, ok] = direction
    nearest = home_dist.min(axis=0) if homes.size else np.zeros(c, dtype=np.int64)
    station_of = np.full(c, -1, dtype=np.int64)
    station_of[homes] = np.arange(homes.size)
    junction = m.degree >= 3
    depart_len = np.array(
        [
            max(1, int(home_dist[i][junction].min())) if junction.any() else 1
            for i in range(homes.size)
        ],
        dtype=np.int64,
    )
    if exclusive:
        pocket_of, pocket_depth, pocket_entry = battery.station_pockets(m.neighbors, homes)
    else:  # robots pass each other: a held station closes no pocket (docs/model.md)
        pocket_of = np.full(c, -1, dtype=np.int64)
        pocket_depth = np.zeros(c, dtype=np.int64)
        pocket_entry = np.full(homes.size, -1, dtype=np.int64)
    battery_on = bool(cfg["battery.enabled"])
    if battery_on:
        if not homes.size:
            raise ConfigError(
                f"battery.enabled: map {m.name} has no charging station 'H'; "
                "set battery.enabled=false or add one"
            )
        # a robot leaving a station walks up to 2 x depart_len moves before its charge
        # is checked again: it must still be above the threshold then (docs/model.md)
        leave = 2 * int(depart_len.max())
        need = int(nearest.max()) + cfg["battery.margin"] + 1 + leave
        if cfg["battery.capacity"] <= need:
            raise ConfigError(
                f"battery.capacity: {cfg['battery.capacity']} is too small for map {m.name}; "
                f"allowed: > {need} (farthest cell {int(nearest.max())} moves from H, plus "
                f"battery.margin, plus 1, plus {leave} moves leaving a station)"
            )
    if battery_on and exclusive:
        check_battery_room(k, m, pocket_of, station_of, home_dir, pocket_entry)
    onward = onward_ports(m)
    diameter = m.diameter()
    return Params(
        n_cells=c,
        n_agents=k,
        neighbors=m.neighbors,
        wall_legal=m.neighbors >= 0,
        entry=m.entry,
        dot_value=dot_value,
        has_dot=has_dot,
        homes=homes,
        station_of=station_of,
        home_dist=home_dist,
        home_dir=home_dir,
        nearest_home_dist=nearest,
        depart_len=depart_len,
        pocket_of=pocket_of,
        pocket_depth=pocket_depth,
        pocket_entry=pocket_entry,
        starts=m.starts,
        target=m.target,
        diameter=diameter,
        task_moves=m.n_cells - 1 if cfg["policy"] == "hpcc" else diameter,
        # on a patrol graph a heading is a port, not a compass direction: port 0
        initial_heading=0 if m.is_graph else DIRECTIONS.index(cfg["learning.initial_heading"]),
        incremental_value=float(cfg["reward.incremental_value"]),
        idle_horizon=float(cfg["reward.idle_horizon"]),
        lambda_weight=float(cfg["reward.lambda"]),
        communication=bool(cfg["team.communication"]),
        interaction=interaction,
        battery=battery_on,
        capacity=int(cfg["battery.capacity"]),
        margin=int(cfg["battery.margin"]),
        charge_steps=int(cfg["battery.charge_steps"]),
        staggered=cfg["battery.initial_charge"] == "staggered",
        max_episode_steps=int(cfg["max_episode_steps"] or 0),
        episodes=int(cfg["episodes"] or 0),
        failures_at=int(cfg["failures.at"]) if cfg["failures.robots"] else 0,
        onward=onward,
        far=far_targets(m.neighbors, m.back, m.target)[0] if onward is not None else None,
        ahead=ahead_targets(m, onward) if onward is not None else None,
        radius=int(cfg["team.interference_radius"]),
        stop_steps=int(cfg["team.interference_steps"]),
        cooldown=int(cfg["team.interference_cooldown"]),
        ball=balls(m.neighbors, cfg["team.interference_radius"])
        if interaction == INTERFERENCE
        else None,
    )


def check_battery_room(
    k: int,
    m: Map,
    pocket_of: np.ndarray,
    station_of: np.ndarray,
    home_dir: np.ndarray,
    pocket_entry: np.ndarray,
) -> None:
    """Raise :class:`ConfigError` if a team of ``k`` robots with batteries (collisions
    avoided) has no room on map ``m`` to let every robot reach a station: on a one-wide
    line (a path), no station with ``k - 1`` cells on each side; on any map, more than half
    the free cells that are neither a station nor in a station's pocket, or more robots
    than the room ahead of a robot on its way to a station (:func:`battery.door_room`;
    docs/model.md, "What is proven, and what is not"). ``pocket_of``, ``station_of``,
    ``home_dir``, ``pocket_entry``: as in :class:`Params`."""
    if k < 2:
        return
    if (m.degree <= 2).all() and (m.degree == 1).sum() == 2:
        # a one-wide line: robots keep their order, so the i-th from one end reaches only
        # cells with at least i cells before them and K - 1 - i after them
        along = bfs(m.neighbors, int(np.flatnonzero(m.degree == 1)[0]))[station_of >= 0]
        most = int(np.minimum(along, m.n_cells - 1 - along).max()) + 1
        if k > most:
            cells = "cell" if k == 2 else "cells"
            raise ConfigError(
                f"agents: {k} robots with battery.enabled on map {m.name}, a one-wide line "
                f"without a station {k - 1} {cells} or more from both ends: a robot never "
                f"gets past the others to a station; allowed: at most {most} (a station with "
                "K - 1 cells on each side), or a map that is not a line"
            )
    closed = int(((pocket_of >= 0) | (station_of >= 0)).sum())
    if 2 * k > m.n_cells - closed:
        raise ConfigError(
            f"agents: {k} robots with battery.enabled on map {m.name} ({m.n_cells} free "
            f"cells, {closed} of them stations or in their pockets) leave no room to yield; "
            f"allowed: at most {(m.n_cells - closed) // 2} (half the free cells outside "
            "stations and their pockets)"
        )
    room, door = battery.door_room(m.neighbors, m.homes, home_dir, pocket_of, pocket_entry)
    if k > room:
        row, col = (int(x) for x in m.coords[door])
        raise ConfigError(
            f"agents: {k} robots with battery.enabled on map {m.name} can fill the {room} "
            f"cells a robot on its way to a station may push them into past the door at "
            f"row {row}, col {col} (pockets closed), and it would be stuck there; allowed: "
            f"at most {room} (the room ahead of the narrowest door)"
        )


#: Config key of each reward weight of :class:`Params` that may differ between the rows
#: of one batch (:func:`with_run_values`).
RUN_VALUE_FIELDS = {
    "reward.incremental_value": "incremental_value",
    "reward.idle_horizon": "idle_horizon",
    "reward.lambda": "lambda_weight",
}


def with_run_values(p: Params, values: dict[str, np.ndarray] | None) -> Params:
    """``p`` with the reward weights that differ between the rows of a batch as float64
    ``[R]`` arrays (``values``: config key -> one value per row, for the keys that
    differ; keys of :data:`RUN_VALUE_FIELDS` only are read)."""
    if not values:
        return p
    changes = {
        name: np.asarray(values[key], dtype=np.float64)
        for key, name in RUN_VALUE_FIELDS.items()
        if key in values
    }
    return replace(p, **changes) if changes else p


def per_row(v: float | np.ndarray, rows: np.ndarray) -> float | np.ndarray:
    """A per-run value at batch rows ``rows``: ``v`` itself if it is one number for
    every row, else ``v[rows]`` (the same bits either way in the arithmetic)."""
    return v if np.ndim(v) == 0 else v[rows]


@dataclass
class State:
    """The whole world; every array has a leading runs axis ``R``.

    Attributes:
        t: team steps taken so far (the same for every run).
        pos: int ``[R, K]``, the cell of each robot.
        head: int ``[R, K]``, each robot's heading: the direction of its last move on a
            grid, the port of its cell it arrived through on a graph (``Map.entry``).
        occ: int ``[R, C]``, the robot standing on each cell, -1 if none.
        dots: bool ``[R, G, C]``, dot still present on a group's dot map.
        last: int ``[R, G, C]``, team step of the group's last visit of a cell (0 = never).
        dots_left: int ``[R, G]``, dots left in the current episode.
        ep_dots, ep_visits: int ``[R, G]``, dots eaten and cells entered this episode.
        ep_start: int ``[R, G]``, team step at which the current episode started (0-based).
        ep_count: int ``[R, G]``, episodes ended so far.
        ep_seen: bool ``[R, G, C]``, cells entered this episode.
        ep_seen_state: bool ``[R, G, C, D]``, (cell, heading) states entered this episode.
        charge: int ``[R, K]``, battery left (never below 0).
        mode: int ``[R, K]``, PATROL, HOMING, QUEUED or CHARGING (:mod:`qpatrol.world.battery`).
        rest: int ``[R, K]``, charging steps left.
        goal: int ``[R, K]``, the station (index into homes) a robot holds, -1 if none.
        queued_since: int ``[R, K]``, step at which a robot began to need a station.
        depart_left: int ``[R, K]``, moves left before a charged robot has cleared its
            station (it holds the station and has right of way until then).
        reserved: int ``[R, H]``, the robot holding each station, -1 if free.
        wait: int ``[R, K]``, consecutive team steps a robot has been unable to make the
            move its strategy or its battery asked for.
        token: int ``[R]``, the robot with right of way this step (may push), -1 if none.
        token_held: int ``[R]``, consecutive steps the token has been with that robot.
        active: bool ``[R]``, run still going (False once its episode quota is met).
        steps_done: int ``[R]``, team steps the run has taken.
        aim: int ``[R, K]``, the cell of each robot's current *task* (the goal it heads
            for: a goal follower's goal, a walk follower's next walk cell, the vertex ahead
            of a robot travelling an edge, the station of a homing robot), -1 for a robot
            whose task is to enter any target (it chooses among its moves) or that has
            none (queued, charging); set each step from the strategy and the world.
        since: int ``[R, K]``, the team step at which each robot's current task began (it
            began needing a station, or its last task ended: it entered its aim or was
            handed one it stands on, or, with none, entered a target). The right of way
            goes by its age, ``t - since``.
        met: int ``[R, K]``, under ``team.interaction: interference`` the team step at
            whose end the robot last met another and stopped (:mod:`qpatrol.world.interference`;
            a large negative number if never): it stops in the ``stop_steps`` steps after.
        failed: int ``[R, F]``, the robots that fail at team step ``Params.failures_at``
            (:mod:`qpatrol.world.failures`; ``F = 0`` without failures).
    """

    t: int
    pos: np.ndarray
    head: np.ndarray
    occ: np.ndarray
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
    goal: np.ndarray
    queued_since: np.ndarray
    depart_left: np.ndarray
    reserved: np.ndarray
    wait: np.ndarray
    token: np.ndarray
    token_held: np.ndarray
    active: np.ndarray
    steps_done: np.ndarray
    failed: np.ndarray
    met: np.ndarray
    aim: np.ndarray
    since: np.ndarray

    @property
    def n_runs(self) -> int:
        return int(self.pos.shape[0])


@dataclass
class EpisodeEnds:
    """The episodes that ended this step, one entry per (run, group); arrays ``[E]``."""

    runs: np.ndarray
    groups: np.ndarray
    episode: np.ndarray  # 0-based index of the episode in its run and group
    start: np.ndarray  # team step before the episode's first step
    dots: np.ndarray
    distinct_cells: np.ndarray
    distinct_states: np.ndarray
    complete: np.ndarray  # bool: all dots eaten (else truncated)


@dataclass
class Outcome:
    """What happened in one team step; arrays ``[R, K]`` unless stated.

    Attributes:
        t: the team step (1-based).
        active: bool ``[R]``, the runs that took this step.
        choosing: bool, the robot was patrolling and its strategy chose a move.
        ask: int, the direction the robot asked for (strategy or homing), -1 if none.
        waiting_for_station: bool, the robot needs a station and has none yet.
        moved: bool, the robot entered a new cell (as asked, or pushed aside).
        as_asked: bool, the robot made the move it asked for.
        prev_pos, prev_head: cell and heading before the step.
        pos: the cell after the step.
        reward: float, the reward of the cell entered (0 if the robot did not move).
        eaten: bool, a dot was eaten on entering.
        blocked_by: int, the robot standing in the asked cell when the move failed, -1.
        episodes: the episodes that ended this step.
        travelling: bool, the robot was patrolling on a graph's waypoint and asked for
            the port that continues its edge (:attr:`Observation.travel`; not choosing).
        progressed: bool, the robot's task ended (it entered its aim, or was handed a task
            whose aim is its cell, or with none entered a target); its next task begins.
        swapped: int, the robot it exchanged its task with (the strategies exchange their
            plans too: a goal, a place on a walk), -1 if none.
    """

    t: int
    active: np.ndarray
    choosing: np.ndarray
    ask: np.ndarray
    waiting_for_station: np.ndarray
    moved: np.ndarray
    as_asked: np.ndarray
    prev_pos: np.ndarray
    prev_head: np.ndarray
    pos: np.ndarray
    reward: np.ndarray
    eaten: np.ndarray
    blocked_by: np.ndarray
    episodes: EpisodeEnds
    travelling: np.ndarray | None = None
    progressed: np.ndarray | None = None
    swapped: np.ndarray | None = None


def place_agents(p: Params, m: Map, rng: np.random.Generator) -> np.ndarray:
    """int ``[K]``: start cells of one run's robots.

    Robot k < (number of start digits) starts on its digit. Each further robot goes to
    the target cell (any cell of a grid, a graph's vertex) farthest (shortest path) from
    every robot placed so far, ties broken by ``rng``, which spreads the team over the map.
    """
    k = p.n_agents
    placed = [int(x) for x in p.starts[:k]]
    if len(placed) < k:
        # moves to the nearest robot placed (a map is connected), kept by one pruned
        # search per robot (search.relax), not a [C, C] table
        near = np.full(p.n_cells, np.iinfo(np.int64).max // 4, dtype=np.int64)
        for c in placed:
            search.relax(m.neighbors, c, near)
        while len(placed) < k:
            far = near.copy() if placed else np.ones(p.n_cells, dtype=np.int64)
            far[placed] = -1
            far[~p.target] = -1  # a graph's robots start on vertices, not inside edges
            best = np.flatnonzero(far == far.max())
            placed.append(int(best[rng.integers(best.size)]))
            search.relax(m.neighbors, placed[-1], near)
    return np.array(placed, dtype=np.int64)


def init_state(p: Params, start_cells: np.ndarray, failed: np.ndarray | None = None) -> State:
    """The world before the first step. ``start_cells``: int ``[R, K]``; ``failed``:
    int ``[R, F]``, the robots that fail at step ``p.failures_at`` (None: none)."""
    r, k, c, g = start_cells.shape[0], p.n_agents, p.n_cells, p.n_groups
    pos = start_cells.astype(np.int64).copy()
    occ = np.full((r, c), -1, dtype=np.int64)
    occ[np.arange(r)[:, None], pos] = np.arange(k)[None, :]
    zeros_rg = np.zeros((r, g), dtype=np.int64)
    zeros_rk = np.zeros((r, k), dtype=np.int64)
    return State(
        t=0,
        pos=pos,
        head=np.full((r, k), p.initial_heading, dtype=np.int64),
        occ=occ,
        dots=np.broadcast_to(p.has_dot, (r, g, c)).copy(),
        last=np.zeros((r, g, c), dtype=np.int64),
        dots_left=np.full((r, g), int(p.has_dot.sum()), dtype=np.int64),
        ep_dots=zeros_rg.copy(),
        ep_visits=zeros_rg.copy(),
        ep_start=zeros_rg.copy(),
        ep_count=zeros_rg.copy(),
        ep_seen=np.zeros((r, g, c), dtype=bool),
        ep_seen_state=np.zeros((r, g, c, p.neighbors.shape[1]), dtype=bool),
        charge=battery.initial_charge(p, pos),
        mode=np.full((r, k), PATROL, dtype=np.int64),
        rest=zeros_rk.copy(),
        goal=np.full((r, k), -1, dtype=np.int64),
        queued_since=zeros_rk.copy(),
        depart_left=zeros_rk.copy(),
        reserved=np.full((r, p.homes.size), -1, dtype=np.int64),
        wait=zeros_rk.copy(),
        token=np.full(r, -1, dtype=np.int64),
        token_held=np.zeros(r, dtype=np.int64),
        active=np.ones(r, dtype=bool),
        steps_done=np.zeros(r, dtype=np.int64),
        failed=(
            np.zeros((r, 0), dtype=np.int64)
            if failed is None
            else np.array(failed, dtype=np.int64).reshape(r, -1)
        ),
        met=np.full((r, k), interference.NEVER, dtype=np.int64),
        aim=np.full((r, k), -1, dtype=np.int64),
        since=zeros_rk.copy(),
    )


@dataclass
class Observation:
    """What a strategy sees before it chooses; arrays ``[R, K, ...]``.

    Attributes:
        t: the team step about to be taken (1-based).
        state: the world (read only).
        params: the world's parameters.
        choosing: bool ``[R, K]``, robots whose strategy chooses this step (patrolling,
            in an active run).
        legal: bool ``[R, K, D]``, moves that do not run into a wall.
        open: bool ``[R, K, D]``, legal moves into a cell no other robot stands in at the
            start of the step, and not into the pocket of a station another robot holds
            (:mod:`qpatrol.world.battery`); for the robot holding the right of way, every legal
            move outside such pockets into an empty cell or into one a push empties
            (:func:`qpatrol.world.traffic.feasible_moves`).
        travel: int ``[R, K]``, on a patrol graph the port a patrolling robot standing
            on a waypoint asks for, the one that continues its edge (:func:`onward_ports`;
            it is not choosing, and no strategy is asked); -1 for every other robot.
            None where the map has no waypoint.
    """

    t: int
    state: State
    params: Params
    choosing: np.ndarray
    legal: np.ndarray
    open: np.ndarray
    travel: np.ndarray | None = None

    def group_of(self) -> np.ndarray:
        """int ``[K]``: the dot/last-visit map each robot uses."""
        k = self.params.n_agents
        return np.zeros(k, dtype=np.int64) if self.params.communication else np.arange(k)


def begin_step(state: State, p: Params) -> Observation:
    """Battery bookkeeping for the step about to start, then what strategies see."""
    s = state
    battery.begin(s, p, s.t + 1)
    if p.battery:
        battery.close_tasks(s, p, s.t + 1)
    targets = np.take(p.neighbors, s.pos, axis=0)  # [R, K, D]
    legal = targets >= 0
    if p.battery:
        legal_open = legal & ~battery.closed_cells(s, p, targets)
    else:
        legal_open = legal
    if p.avoid_collisions:
        rows = np.arange(s.n_runs)[:, None, None]
        occupied = flat(s.occ)[at(s.occ.shape, rows, np.maximum(targets, 0))] >= 0
        open_ = legal_open & ~occupied
        r_tok = np.flatnonzero(s.token >= 0)
        k_tok = s.token[r_tok]
        open_[r_tok, k_tok] = legal_open[r_tok, k_tok]
        # the holder of the right of way: the moves it can make, pushing if need be
        # (feasible_moves; one whose open moves all lead into empty cells makes any)
        pushing = s.active[r_tok] & port_any(legal_open[r_tok, k_tok] & occupied[r_tok, k_tok])
        for r, k in zip(r_tok[pushing].tolist(), k_tok[pushing].tolist(), strict=True):
            open_[r, k] = traffic.feasible_moves(s, p, r, k, legal_open[r, k])
    else:
        open_ = legal_open.copy()
    choosing = s.active[:, None] & (s.mode == PATROL)
    if p.battery:
        choosing &= ~battery.shut_in(s, p)
    travel = None
    if p.onward is not None:
        choosing, travel = travelling(s, p, choosing)
    return Observation(
        t=s.t + 1, state=s, params=p, choosing=choosing, legal=legal, open=open_, travel=travel
    )


def travelling(s: State, p: Params, patrolling: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The decision points of a patrol graph: ``(choosing, travel)``, bool and int
    ``[R, K]``. A ``patrolling`` robot (bool ``[R, K]``) on a vertex chooses; one on a
    waypoint does not, and asks for the port that continues its edge, the other port
    than its heading (the port it arrived by, or was pushed in by): ``travel``, -1 for
    every other robot."""
    onward = p.onward[s.pos, s.head]  # [R, K]
    on_edge = patrolling & (onward >= 0)
    return patrolling & ~on_edge, np.where(on_edge, onward, -1)


def step(
    state: State,
    p: Params,
    obs: Observation,
    choice: np.ndarray,
    aim: np.ndarray | None = None,
    turns: bool = False,
    plans: bool = False,
) -> Outcome:
    """Apply one team step, in place, given the strategy's ``choice``.

    Args:
        state: the world (modified).
        p: its parameters.
        obs: what :func:`begin_step` returned for this step.
        choice: int ``[R, K]``, the port (0..D-1; N, E, S, W on a grid) each choosing
            robot asks for; -1 (or a wall) for no move. Ignored for robots that are not choosing.
        aim: int ``[R, K]``, the cell each choosing robot heads for (its strategy's goal,
            :meth:`qpatrol.strategies.base.Strategy.aims`), -1 for a robot that just
            chooses a move; None: -1 for every robot.
        turns: the strategy plans on a graph's waypoints too (walk followers,
            :attr:`qpatrol.strategies.base.Strategy.plans_on_edges`): its ``choice`` for a
            robot travelling an edge is read, and turns it round where it asks for the
            port behind it and that cell is free (:func:`turn_round`; collisions avoided).
        plans: the strategy's robots' goals are tasks allocated to them
            (:attr:`qpatrol.strategies.base.Strategy.keeps_plans`; ``dta-*``): the
            holder of the right of way head on with one hands its task on
            (:func:`qpatrol.world.traffic.head_on`).
    """
    s = state
    s.t += 1
    t = s.t
    R, K = s.pos.shape
    active = s.active.copy()  # the runs taking this step (an episode quota may end some)
    ar = np.arange(R)[:, None]
    prev_pos = s.pos.copy()
    prev_head = s.head.copy()
    travel = obs.travel
    if travel is not None and turns and p.avoid_collisions:
        travel = turn_round(s, p, travel, choice)
    choice = np.where(obs.choosing, choice, -1)
    port = at(obs.legal.shape, ar, np.arange(K), np.maximum(choice, 0))  # [R, K]
    legal_choice = (choice >= 0) & flat(obs.legal)[port]
    ask = np.where(legal_choice, choice, -1)
    on_edge = np.zeros((R, K), dtype=bool) if travel is None else travel >= 0
    if travel is not None:  # travelling on an edge: its onward port (begin_step)
        ask = np.where(on_edge, travel, ask)
    if p.battery:
        # a held pocket is closed: no robot but its holder moves deeper into it
        cell = np.where(ask >= 0, p.neighbors[s.pos, np.maximum(ask, 0)], -1)
        ask = np.where(battery.closed_cells(s, p, cell[..., None])[..., 0], -1, ask)
    homing = active[:, None] & (s.mode == HOMING)
    queued = active[:, None] & (s.mode == QUEUED)
    if p.battery:
        # patrolling robots that do not choose are those shut in a held pocket
        # (begin_step): they step out, like queued ones
        queued = queued | (active[:, None] & (s.mode == PATROL) & ~obs.choosing & ~on_edge)
    held_back = yielding = np.zeros((R, K), dtype=bool)
    if homing.any():
        home_ask, held_back, yielding = battery.homing_ask(s, p)
        ask = np.where(homing, home_ask, ask)
        held_back &= homing
        yielding &= homing
    if queued.any():
        ask = np.where(queued, battery.queued_ask(s, p), ask)
        yielding = yielding | (queued & (ask >= 0))
    move = at(p.neighbors.shape, s.pos, np.maximum(ask, 0))  # [R, K], flat in [C, D]
    want = np.where(ask >= 0, flat(p.neighbors)[move], -1)
    s.aim = task_aims(s, p, obs, aim, on_edge, active)
    mode0 = s.mode.copy()

    res = traffic.resolve(s, p, want, plans)
    if p.interaction == INTERFERENCE:
        interference.meet(s, p, prev_pos, res.moved)
    if p.ahead is not None and (res.swapped >= 0).any():
        partner_asked = np.take_along_axis(want, np.maximum(res.swapped, 0), axis=1)
        head_on = (res.swapped >= 0) & (partner_asked == s.pos)
        turn_back(s, p, (res.swapped >= 0) & on_edge, head_on)

    # --- what entering a cell does: dots, visits, reward, heading, charge ----------------
    moved = res.moved
    reward = np.zeros((R, K))
    eaten = np.zeros((R, K), dtype=bool)
    # the heading after the move: the direction moved on a grid, the port arrived
    # through on a graph (Map.entry)
    direction = traffic.direction_of(p, prev_pos, s.pos)
    heading = flat(p.entry)[at(p.entry.shape, prev_pos, direction)]
    # the dot maps' cells [R, G, C] and episode counts [R, G] a move changes, as flat views
    dots, last, ep_dots, ep_visits = flat(s.dots), flat(s.last), flat(s.ep_dots), flat(s.ep_visits)
    for k in range(K):
        rows = np.flatnonzero(moved[:, k])
        if rows.size == 0:
            continue
        g = 0 if p.communication else k
        rk = at((R, K), rows, k)  # int [B], the moved robots, flat in [R, K]
        rg = at(s.dots_left.shape, rows, g)  # their dot maps, in [R, G]
        c1 = flat(s.pos)[rk]
        a = flat(heading)[rk]
        cell = at(s.dots.shape, rows, g, c1)  # the cells entered, in [R, G, C]
        ate = dots[cell]
        dots[cell] = False
        flat(s.dots_left)[rg] -= ate
        eaten_now, entered = ep_dots[rg] + ate, ep_visits[rg] + 1  # this episode's, after
        ep_dots[rg], ep_visits[rg] = eaten_now, entered
        idle = t - last[cell]
        last[cell] = t
        flat(s.ep_seen)[cell] = True
        flat(s.ep_seen_state)[at((-1, p.neighbors.shape[1]), cell, a)] = True
        flat(reward)[rk] = (
            np.where(ate, p.dot_value[c1], 0.0)
            + per_row(p.incremental_value, rows)
            * np.minimum(1.0, idle / per_row(p.idle_horizon, rows))
            + per_row(p.lambda_weight, rows) * eaten_now / entered
        )
        flat(eaten)[rk] = ate
        flat(s.head)[rk] = a
    if p.battery:
        # yielding (pushed aside, or stepping out of a station's pocket) costs nothing
        yielded = moved & (~res.as_asked | yielding)
        s.charge -= moved & ~yielded
        battery.credit_detour(s, p, yielded, prev_pos)
    asked = ask >= 0
    battery.end(s, p, moved, asked)
    # a task ends when its robot enters its aim, or is handed a task whose aim is its
    # cell, or, with no aim, enters a target (waiting on its aim is not progress)
    got = moved | (res.swapped >= 0)
    progressed = active[:, None] & (
        (got & (s.aim >= 0) & (s.pos == s.aim) & ((mode0 == PATROL) | (mode0 == HOMING)))
        | ((s.aim < 0) & (mode0 == PATROL) & moved & p.target[s.pos])
    )
    s.since = np.where(progressed, t, s.since)
    waiting_station = (active[:, None] & (s.mode == QUEUED)) | held_back
    failed = (asked & ~res.as_asked) | waiting_station
    s.wait = np.where(failed, s.wait + 1, 0)
    # the robot standing in the asked cell (with robots passing each other, none)
    blocked = asked & ~res.as_asked & p.avoid_collisions
    blocked_by = np.where(blocked, flat(s.occ)[at(s.occ.shape, ar, np.maximum(want, 0))], -1)
    traffic.pass_token(s, p, want, res, progressed)
    s.steps_done[active] = t
    ends = _end_episodes(s, p)
    return Outcome(
        t=t,
        active=active,
        choosing=obs.choosing,
        ask=ask,
        waiting_for_station=waiting_station,
        moved=moved,
        as_asked=res.as_asked,
        prev_pos=prev_pos,
        prev_head=prev_head,
        pos=s.pos.copy(),
        reward=reward,
        eaten=eaten,
        blocked_by=blocked_by,
        episodes=ends,
        travelling=on_edge,
        progressed=progressed,
        swapped=res.swapped,
    )


def task_aims(
    s: State,
    p: Params,
    obs: Observation,
    aim: np.ndarray | None,
    on_edge: np.ndarray,
    active: np.ndarray,
) -> np.ndarray:
    """int ``[R, K]``: each robot's aim this step (``State.aim``): the strategy's for a
    choosing robot (``aim``; -1 without), the vertex ahead for one travelling an edge,
    its station for a homing robot; -1 for the others (queued, charging, failed)."""
    out = np.full(s.pos.shape, -1, dtype=np.int64)
    if aim is not None:
        out = np.where(obs.choosing, aim, -1)
    if p.ahead is not None:
        out = np.where(on_edge, p.ahead[s.pos, s.head], out)
    homing = active[:, None] & (s.mode == HOMING)
    if homing.any():
        out = np.where(homing, p.homes[np.maximum(s.goal, 0)], out)
    return out


def turn_round(s: State, p: Params, travel: np.ndarray, choice: np.ndarray) -> np.ndarray:
    """Robots travelling an edge (``travel`` int ``[R, K]``, their onward port, -1 for
    the others) whose strategy's ``choice`` is the port behind them (their heading),
    and whose cell behind is free, turn round: their heading becomes the onward port,
    and they ask for the one behind. Returns the ports the travellers ask for;
    ``s.head`` is modified."""
    behind = p.neighbors[s.pos, s.head]  # (a waypoint's two ports both lead somewhere)
    free = s.occ[np.arange(s.n_runs)[:, None], np.maximum(behind, 0)] < 0
    back = (travel >= 0) & (choice == s.head) & free
    out = np.where(back, s.head, travel)
    s.head = np.where(back, travel, s.head)
    return out


def turn_back(s: State, p: Params, who: np.ndarray, head_on: np.ndarray) -> None:
    """Robots ``who`` (bool ``[R, K]``, travelling a graph's edge, that exchanged tasks)
    turn round when their new task's aim is the vertex behind them, or when they took
    over the task of a robot that asked for their cell (``head_on``: its way goes on
    behind them): their heading becomes the port they were leaving by."""
    onward = p.onward[s.pos, s.head]
    behind = p.ahead[s.pos, np.maximum(onward, 0)]
    back = (s.aim == behind) & (s.aim != p.ahead[s.pos, s.head])
    flip = who & (onward >= 0) & (head_on | back)
    s.head = np.where(flip, onward, s.head)


def _end_episodes(s: State, p: Params) -> EpisodeEnds:
    """End the episodes whose dots are all eaten, or that ran too long; start the next."""
    t = s.t
    active = s.active
    complete = active[:, None] & (s.dots_left == 0)
    ended = complete.copy()
    if p.max_episode_steps:
        ended |= active[:, None] & (t - s.ep_start >= p.max_episode_steps)
    runs, groups = np.nonzero(ended)
    ends = EpisodeEnds(
        runs=runs,
        groups=groups,
        episode=s.ep_count[runs, groups].copy(),
        start=s.ep_start[runs, groups].copy(),
        dots=s.ep_dots[runs, groups].copy(),
        distinct_cells=s.ep_seen[runs, groups].sum(axis=1),
        distinct_states=s.ep_seen_state[runs, groups].sum(axis=(1, 2)),
        complete=complete[runs, groups],
    )
    if runs.size:
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
    return ends
