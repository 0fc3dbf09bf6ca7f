"""The compiled loop's arguments, bundled as the numpy engine's objects are.

The loop (:func:`qpatrol.engines.numba_core.run_block`) and its phases (``moves``,
``stations``, ``enter``, ``episodes``, ``observe`` in this package) take these
named tuples instead of some eighty arrays one by one: numba passes a tuple of arrays
field by field, so a field costs what an argument did, and each phase names what it
reads (``p.nbrs``, ``s.pos``). ``R`` runs, ``K`` robots, ``C`` cells, ``G`` dot groups,
``H`` stations. Every field holds the very array of the numpy objects
(:class:`qpatrol.world.State`, :class:`qpatrol.measures.Measures`, ...), updated in
place, or a tiny placeholder where a feature is off.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from qpatrol.world import State


class Params(NamedTuple):
    """The batch's constants (:class:`qpatrol.world.Params`).

    Attributes:
        nbrs: int64 ``[C, D]``, each cell's neighbour by port (N, E, S, W on a grid;
            -1: wall).
        wall_legal: bool ``[C, D]``, the legal moves.
        cell_moves: int64 ``[C]``, the legal moves as D bits
            (:func:`qpatrol.engines.compiled.choice.legal_bits`), read with ``MASKED``.
        entry: int64 ``[C, D]``, the heading after the move out of a cell by a port
            (:attr:`qpatrol.maps.Map.entry`), or None on a grid (4 ports, each move's
            heading the move itself: :func:`compiled_entry`) in the lone and team
            learners' loops. None is a type of its own to the compiler: those loops are
            compiled for a grid with D = 4 a constant and no load of a heading
            (:func:`qpatrol.engines.compiled.choice.ports_of`, ``heading_of``); the
            general loop and the recorders' take a grid's ``entry`` as an array, as a
            graph's (:class:`qpatrol.engines.numba_core.Loop`), so that each is one
            machine code for every map, D read from ``nbrs``.
        dot_value: float64 ``[C]``; has_dot: bool ``[C]``; n_dots: their count.
        reward_w: float64 ``[R, 3]``, each run's reward weights (incremental value,
            idle horizon, lambda).
        communication, avoid: one dot group for the team; collision avoidance
            (``team.interaction: exclusive``).
        diameter, max_ep, quota: right-of-way limit, episode steps (0: none),
            episodes per run (0: none).
        battery ... charge_steps: the battery's rules (:mod:`qpatrol.world.battery`):
            stations ``homes`` ``[H]``, ``home_dist``/``home_dir`` ``[H, C]``,
            ``nearest`` ``[C]``, ``depart_len`` ``[H]``, pockets ``pocket_of``,
            ``pocket_depth`` ``[C]``, ``pocket_entry`` ``[H]``, and scalars.
        target: bool ``[C]``, the cells the measures count; n_targets: their number.
        fail_at: the team step at whose end the robots ``failed`` ``[R, F]`` of the
            world fail (0: none; :mod:`qpatrol.engines.compiled.fail`).
        travels: the map is a patrol graph with waypoints, where robots decide at
            vertices only; onward: int64 ``[C, D]``, the port that continues an edge
            from a waypoint by heading (:attr:`qpatrol.world.Params.onward`; ``[1, 1]``
            without waypoints); far: int64 ``[C, D]``, the target at each port's far
            end (:attr:`qpatrol.world.Params.far_cells`).
        ahead: int64 ``[C, D]``, the target a robot on a waypoint reaches travelling on, by
            heading (:attr:`qpatrol.world.Params.ahead`; ``[1, 1]`` without waypoints).
        interaction: :data:`EXCLUSIVE`, :data:`INTERFERENCE` or :data:`NONE`
            (``team.interaction``); radius, stop_steps, cooldown, ball: the interference
            rule's (:mod:`qpatrol.world.interference`; ``ball`` int64 ``[C, B]``, ``[1,
            1]`` under the other interactions).
    """

    nbrs: np.ndarray
    wall_legal: np.ndarray
    cell_moves: np.ndarray
    entry: np.ndarray | None
    dot_value: np.ndarray
    has_dot: np.ndarray
    n_dots: int
    reward_w: np.ndarray
    communication: bool
    avoid: bool
    diameter: int
    max_ep: int
    quota: int
    battery: bool
    homes: np.ndarray
    home_dist: np.ndarray
    home_dir: np.ndarray
    nearest: np.ndarray
    depart_len: np.ndarray
    pocket_of: np.ndarray
    pocket_depth: np.ndarray
    pocket_entry: np.ndarray
    capacity: int
    margin: int
    charge_steps: int
    target: np.ndarray
    n_targets: int
    fail_at: int
    travels: bool
    onward: np.ndarray
    far: np.ndarray
    ahead: np.ndarray
    interaction: int
    radius: int
    stop_steps: int
    cooldown: int
    ball: np.ndarray


#: ``Params.interaction``'s codes, in :data:`qpatrol.config.INTERACTIONS` order.
EXCLUSIVE, INTERFERENCE, NONE = 0, 1, 2


def interaction_args(p) -> tuple:
    """The interaction's fields of :class:`Params` from the world's parameters ``p``."""
    from qpatrol.config import INTERACTIONS

    ball = p.ball if p.ball is not None else np.full((1, 1), -1, dtype=np.int64)
    return (
        INTERACTIONS.index(p.interaction),
        p.radius,
        p.stop_steps,
        p.cooldown,
        np.ascontiguousarray(ball, dtype=np.int64),
    )


#: The runs' state: the arrays of :class:`qpatrol.world.State` (all its fields but the
#: step ``t``), ``[R, ...]``, by the same names: robots' ``pos``, ``head``, ``wait``
#: ``[R, K]``; ``occ`` ``[R, C]`` (robot on a cell, -1); per group ``dots``, ``last``
#: ``[R, G, C]`` and the episode's ``dots_left``, ``ep_dots``, ``ep_visits``,
#: ``ep_start``, ``ep_count`` ``[R, G]``, ``ep_seen`` ``[R, G, C]``, ``ep_seen_state``
#: ``[R, G, C, D]``; the right of way ``token``, ``token_held``, ``active``,
#: ``steps_done`` ``[R]``; the battery's ``charge``, ``mode``, ``rest``, ``goal``,
#: ``queued_since``, ``depart_left`` ``[R, K]`` and ``reserved`` ``[R, H]``; the robots
#: that fail, ``failed`` ``[R, F]``.
World = NamedTuple(  # noqa: UP014 (its fields are State's, not written again here)
    "World", [(f.name, np.ndarray) for f in dataclasses.fields(State) if f.name != "t"]
)


class Meas(NamedTuple):
    """The measures (:class:`qpatrol.measures.Measures`): ``last`` ``[R, C]`` (last
    visit), ``visits``, ``window_visits`` ``[R, K, C]``, and per run ``[R]`` the sums
    ``last_sum``, ``idle_total``, ``worst``, ``measured``, ``gap_sum``, ``gap_count``,
    ``gap_max``, ``max_wait``, ``wait_total``, ``min_charge``; ``warmup`` (steps); the
    field's measures: per run ``gap_sq``, ``cycle_start``, ``cycle_seen``, ``cycles``,
    ``interferences`` ``[R]`` and per target ``target_gap_sum``, ``target_gap_count``
    ``[R, C]``; the intruder measures' ``attack`` ``[A]`` (durations; empty: off),
    ``horizon`` (steps), ``empty_since`` ``[R, C]``, ``random_missed`` ``[R, A]``,
    ``stretch_count``, ``stretch_sum`` ``[R, A + 1]``, ``stretch_equal`` ``[R, A]``,
    ``gaps`` ``[R, C, A + 1]``, ``tail_departures`` and ``tail_missed`` ``[R, C, A]``;
    ``max_stall`` ``[R]``, the longest stretch without progress."""

    last: np.ndarray
    last_sum: np.ndarray
    visits: np.ndarray
    window_visits: np.ndarray
    idle_total: np.ndarray
    worst: np.ndarray
    measured: np.ndarray
    gap_sum: np.ndarray
    gap_count: np.ndarray
    gap_max: np.ndarray
    max_wait: np.ndarray
    wait_total: np.ndarray
    warmup: int
    min_charge: np.ndarray
    gap_sq: np.ndarray
    target_gap_sum: np.ndarray
    target_gap_count: np.ndarray
    cycle_start: np.ndarray
    cycle_seen: np.ndarray
    cycles: np.ndarray
    interferences: np.ndarray
    attack: np.ndarray
    horizon: int
    empty_since: np.ndarray
    random_missed: np.ndarray
    stretch_count: np.ndarray
    stretch_sum: np.ndarray
    stretch_equal: np.ndarray
    gaps: np.ndarray
    tail_departures: np.ndarray
    tail_missed: np.ndarray
    max_stall: np.ndarray


class Out(NamedTuple):
    """The recorders and the loop's output rows.

    Attributes:
        tail_pos: int64 ``[R, N, K]``, the trajectory ring (``tail_n`` steps, 0: off).
        ep_buf: int64 ``[E, EP_COLS]``, the episodes that ended.
        record_all, watched: Q-updates of every robot, or of the ``watched`` cells
            (bool ``[C]``), as rows of ``up_int`` ``[U, UP_INT]`` and ``up_float``
            ``[U, UP_FLOAT]``.
        tl_window ... tl_steps: the idleness timeline (:class:`qpatrol.measures.timeline.Timeline`,
            0: off), each closed window a row of ``tl_buf`` ``[W, 6]``.
    """

    tail_pos: np.ndarray
    tail_n: int
    ep_buf: np.ndarray
    record_all: bool
    watched: np.ndarray
    up_int: np.ndarray
    up_float: np.ndarray
    tl_window: int
    tl_last: np.ndarray
    tl_last_sum: np.ndarray
    tl_idle_sum: np.ndarray
    tl_worst: np.ndarray
    tl_steps: np.ndarray
    tl_buf: np.ndarray


class Work(NamedTuple):
    """The loop's working arrays for one run's step (:func:`work`), most of them the
    step's outcome (:class:`qpatrol.world.Outcome`): per robot ``[K]`` the cell wanted
    and the move asked (-1: none), the cell and heading before the step, moved, moved
    as asked, reward, eaten, the robot in the way (-1), the strategy chose, yielding,
    held back; ``order``, ``key`` ``[K]`` for sorting; ``open_mask`` bool ``[K, D]``;
    ``ended`` bool ``[G]`` (the group's episode ended); and the push search's
    ``parent``, ``seen``, ``queue``, ``path`` ``[C]`` (``parent`` -2 between calls);
    ``uniforms`` float64 ``[K, 2]``: each robot's two uniforms of the step (epsilon,
    tie-break), drawn by the loop (:func:`qpatrol.engines.compiled.pcg.step_uniforms`);
    ``sink`` float64 ``[1]`` keeps a warming read; ``score`` float64 ``[K, D]``: each
    robot's score of each move (a strategy's scratch); ``travel`` ``[K]``: the port a
    robot travelling a graph's edge asks for (``Observation.travel``), -1 for none;
    ``mark`` ``[C]`` and ``stamp`` ``[1]``: the cells of the robots already looked at
    when robots meet (a cell is marked when ``mark`` holds the current ``stamp``);
    ``aim`` ``[K]``: the cell each robot heads for, as its strategy says (-1: none;
    ``State.aim``); ``swapped`` ``[K]``: the robot it exchanged its task with this step
    (-1: none); ``progressed`` ``[K]``: its task ended this step; ``mode0`` ``[K]``: its
    mode when it asked."""

    want: np.ndarray
    ask: np.ndarray
    prev_pos: np.ndarray
    prev_head: np.ndarray
    moved: np.ndarray
    as_asked: np.ndarray
    reward: np.ndarray
    eaten: np.ndarray
    blocked_by: np.ndarray
    choosing: np.ndarray
    yielding: np.ndarray
    held_back: np.ndarray
    order: np.ndarray
    key: np.ndarray
    open_mask: np.ndarray
    ended: np.ndarray
    parent: np.ndarray
    seen: np.ndarray
    queue: np.ndarray
    path: np.ndarray
    uniforms: np.ndarray
    sink: np.ndarray
    score: np.ndarray
    travel: np.ndarray
    mark: np.ndarray
    stamp: np.ndarray
    aim: np.ndarray
    swapped: np.ndarray
    progressed: np.ndarray
    mode0: np.ndarray


def compiled_entry(neighbors: np.ndarray, entry: np.ndarray) -> np.ndarray | None:
    """:attr:`Params.entry`: None for a map whose cells have 4 ports and whose every
    move's heading is the move (``entry``, int ``[C, D]``, equal to the port wherever
    ``neighbors`` has a move: a grid's), else ``entry``."""
    grid_like = neighbors.shape[1] == 4 and bool(
        (entry == np.where(neighbors >= 0, np.arange(4), entry)).all()
    )
    return None if grid_like else entry


def work(n_agents: int, n_groups: int, n_cells: int, n_ports: int = 4) -> Work:
    """The working arrays, allocated once per batch and lane (the loop allocates
    nothing: it is compiled without numba's reference counting)."""
    i8, b1, k = np.int64, np.bool_, n_agents
    return Work(
        *(np.zeros(k, i8) for _ in range(4)),
        np.zeros(k, b1),
        np.zeros(k, b1),
        np.zeros(k, np.float64),
        np.zeros(k, b1),
        np.zeros(k, i8),
        *(np.zeros(k, b1) for _ in range(3)),
        np.zeros(k, i8),
        np.zeros(k, i8),
        np.zeros((k, n_ports), b1),
        np.zeros(n_groups, b1),
        np.full(n_cells, -2, i8),
        *(np.zeros(n_cells, i8) for _ in range(3)),
        np.zeros((k, 2), np.float64),
        np.zeros(1, np.float64),
        np.zeros((k, n_ports), np.float64),
        np.full(k, -1, i8),
        np.zeros(n_cells, i8),
        np.zeros(1, i8),
        np.full(k, -1, i8),
        np.full(k, -1, i8),
        np.zeros(k, b1),
        np.zeros(k, i8),
    )
