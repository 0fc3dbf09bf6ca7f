"""An exhaustive model checker of the movement and battery rules: every reachable state.

The checker explores, on one small map and one team size, every state the world's rules
can reach when the strategy is an *adversary* that may choose any of a patrolling robot's
moves at every step, from every placement of the robots. It does not restate the rules:
each transition is one call of :func:`qpatrol.world.begin_step` and
:func:`qpatrol.world.step`, the functions every engine's reference is, with the
adversary's choices passed as the strategy's ``choice`` (one batch row per state and
choice vector: the rows of a batch are independent runs, so this is R = 1 many times
over, :func:`replay` re-runs a found cycle with R = 1).

Adversaries (:class:`Case.adversary`)
    ``open``: each choosing (patrolling) robot asks for any one of its open moves, or any
    legal move when none is open (:func:`qpatrol.strategies.base.prefer_open`, what
    every avoiding strategy chooses among). ``legal``: any non-wall move. ``goal``: each
    patrolling robot has a goal cell (its aim, :attr:`qpatrol.world.State.aim`), any
    cell outside another robot's held pocket, chosen by the adversary when the robot has
    none or stands on it and kept until reached, and asks for a first move of a
    shortest path to it (the lowest open one, else it insists on the lowest): the goal
    and walk followers. Robots that are not choosing (homing, queued, charging) ask
    what the rules make them ask. A patrolling robot always asks for some move.

State (what the rules read), :func:`Checker.encode`
    Robot positions (``occ`` is derived from them and checked), the token, ``t mod K``
    (the turn), and per robot mode, charge, charging steps left, held station,
    ``depart_left``, aim, and the order of ``since`` and ``queued_since``; ``reserved``
    is derived from the held stations and checked. Any field of
    :class:`qpatrol.world.State` not named in :data:`IGNORED` or :data:`ORDER_ONLY` is
    kept as it is, so a field the rules gain later is part of the state (if it grows
    without bound the exploration stops at ``max_states`` and says so).

Abstraction of the unbounded counters (why it is sound, and exact)
    ``since`` is the step a robot's task began; the rules read it only through ages
    ``t - since`` compared between robots (:func:`qpatrol.world.traffic.priority`,
    :func:`~qpatrol.world.traffic.pass_token`), exchange it between robots
    (:func:`~qpatrol.world.traffic.hand_on`) and set it to ``t``, later than every
    earlier one, when a task ends. ``queued_since`` is read only to order the queued
    robots (first come, first served, ties by index). ``t`` is read through ``t mod K``
    and as the value given to new tasks and queues. So two states that agree on
    everything else and on the *order with ties* of ``since`` and of the queued robots'
    ``queued_since`` take the same moves under the same choices, and their successors
    again agree in that sense. The checker stores both as dense ranks: the quotient is a
    bisimulation, every abstract cycle is an infinite run of the real rules (:func:`replay`
    shows it with R = 1), and every real run is a path of the graph.
    ``test_abstraction_is_exact`` checks the claim on the live rules (random
    order-preserving task starts and queue times, garbage in the ignored fields, same
    successors). Fields in :data:`IGNORED` are read only by strategies, rewards,
    episodes and measures (``wait`` is measured, not read; ``episodes`` is null, so no
    run ever stops).

Livelock (the fairness notion)
    A robot has a *task* while it patrols, homes or queues; the task ends when the robot
    reaches its aim or, without one, enters a target (``Outcome.progressed``). A token
    holder that cannot push hands it on, and when both patrol the robot in its way hands
    its own task to the holder in exchange (``Outcome.swapped``, set for both; two robots
    exchanging goals before the step hand theirs on too). Robot i *fails* on a step if it
    has a task that did not end and that it did not hand on. A task can fail
    to end in two ways, and the criterion catches both: (1) a robot keeps a task that
    never ends, so it fails at every step of a cycle (edge bit i); (2) a task passes from
    robot to robot and never ends, so no robot fails at every step but the oldest age
    of the team is kept on every step (edge bit K: some robot still carries, at the end
    of the step, the oldest ``since`` of its beginning and did not end it). As every
    other task is younger, (1) implies (2) once the starving task is the oldest; both
    are checked. (2) alone catches every task that never ends: no task is older than one
    that began before it (Lemma 1 of docs/model.md), so the oldest of the tasks that
    never end is, after its elders have ended, the team's oldest for ever. A robot that
    hands its tasks on for ever does not starve: they end elsewhere and its stall, the
    age of the task it carries, stays bounded (three robots on ``......`` with the
    exchange head on each shuttle on a third of the line, every task ending at an end of
    it; counted as failing, robot b of each exchange made six such cycles look like
    livelocks). In the finite graph a livelock is a strongly connected component (more
    than one state, or one state with a self-loop) of the subgraph of edges that carry
    the bit (iterative Tarjan, :func:`strong_components`). Every state is reachable, so
    each such component is a reachable livelock, along which ``max_stall`` grows without
    bound. The checker reports, for each, the robot (K: the oldest task), a shortest
    path from a starting placement and one cycle, and whether the robot is at least
    pushed around on it or never leaves its cell. Safety is checked on every transition
    on the way: one robot per cell, no swaps, moves between neighbours only, no charge
    below 0.
"""

from __future__ import annotations

import itertools
from collections import deque
from dataclasses import dataclass, field, fields

import numpy as np
from numba import njit

from qpatrol import world
from qpatrol.config import ConfigError, from_flat
from qpatrol.maps import Map, parse_map
from qpatrol.strategies.base import prefer_open
from qpatrol.world import traffic

#: State fields the rules never read (strategies, rewards, episodes, measures only);
#: ``occ`` and ``reserved`` are derived from positions and held stations (and checked).
IGNORED = {
    "t",
    "head",
    "wait",  # measured only: the right of way goes by the task's age (since)
    "met",  # read only under team.interaction: interference (the checker's is exclusive)
    "token_held",
    "occ",
    "reserved",
    "dots",
    "last",
    "dots_left",
    "ep_dots",
    "ep_visits",
    "ep_start",
    "ep_count",
    "ep_seen",
    "ep_seen_state",
    "active",
    "steps_done",
}
#: Unbounded counters the rules only compare between robots: kept as dense ranks.
ORDER_ONLY = ("since", "queued_since")


@dataclass(frozen=True)
class Case:
    """One model-checking problem: a map, a team size, battery settings, an adversary."""

    text: str  # the map, in qpatrol's format
    k: int
    battery: bool = False
    capacity: int = 0  # 0: the smallest the config accepts (battery.margin 0) + extra
    extra_capacity: int = 0
    departure: bool = False  # add 2 x max depart_len to the capacity (the departure)
    charge_steps: int = 1
    initial_charge: str = "staggered"
    adversary: str = "open"  # 'open', 'legal' or 'goal'
    # the holder head on with a goal robot exchanges tasks (rule 2 for dta robots)
    head_on: bool = False
    # two goal robots each of whose next cell is the other's exchange goals and tasks
    # before the step (the walk followers' exchange before meeting)
    early: bool = False

    def label(self) -> str:
        rows = [r for r in self.text.splitlines() if r and not r.startswith(";")]
        bat = (
            f"battery cap={self.capacity or f'min+{self.extra_capacity}'}"
            f"{'+departure' if self.departure else ''} "
            f"charge_steps={self.charge_steps} initial={self.initial_charge}"
            if self.battery
            else "battery off"
        )
        how = " head-on exchange" if self.head_on else ""
        how += " exchange before meeting" if self.early else ""
        return f"K={self.k} {bat} adversary={self.adversary}{how} map " + "/".join(rows)


@dataclass
class Livelock:
    """A reachable cycle of states on which ``robot`` fails at every step."""

    robot: int
    component: int  # states in its strongly connected component
    prefix: list[tuple[bytes, tuple[int, ...], tuple[int, ...]]]  # (state, choice, aims)
    cycle: list[tuple[bytes, tuple[int, ...], tuple[int, ...]]]  # back to cycle[0]
    pushed: bool  # the robot changes cells somewhere on the cycle


@dataclass
class Result:
    """What :meth:`Checker.explore` found on one case."""

    case: Case
    states: int
    edges: int
    livelocks: list[Livelock] = field(default_factory=list)
    complete: bool = True  # False: max_states reached
    checker: Checker | None = None  # the explored graph (for reports and replays)


def smallest_capacity(m: Map, margin: int = 0) -> int:
    """The smallest ``battery.capacity`` :func:`qpatrol.world.make_params` accepts: above
    the farthest cell's distance to a station, the margin, 1 and the moves of leaving a
    station (``2 x depart_len``)."""
    nearest = int(m.distances()[m.homes].min(axis=0).max())
    return nearest + margin + 2 + 2 * departure_length(m)


def departure_length(m: Map) -> int:
    """The longest ``depart_len`` of the map's stations (:class:`qpatrol.world.Params`)."""
    dist = m.distances()
    junction = m.degree >= 3
    if not junction.any():
        return 1
    return max(max(1, int(dist[h][junction].min())) for h in m.homes.tolist())


class Checker:
    """The state graph of one :class:`Case`, explored breadth-first from every placement."""

    def __init__(self, case: Case):
        self.case = case
        self.m = parse_map(case.text)
        flat = {
            "agents": case.k,
            "runs": 1,
            "policy": "random",
            "team.avoid_collisions": True,
            "team.communication": True,
            "battery.enabled": case.battery,
            "battery.capacity": 1,  # battery off: a constant charge, never read
            "episodes": None,
            "max_episode_steps": None,
        }
        if case.battery:
            capacity = case.capacity or smallest_capacity(self.m) + case.extra_capacity
            if case.departure:
                capacity += 2 * departure_length(self.m)
            flat.update(
                {
                    "battery.capacity": capacity,
                    "battery.margin": 0,
                    "battery.charge_steps": case.charge_steps,
                    "battery.initial_charge": case.initial_charge,
                }
            )
        self.p = world.make_params(from_flat(flat), self.m)
        self.dist = self.m.distances()
        probe = world.init_state(self.p, np.arange(case.k, dtype=np.int64)[None])
        names = [f.name for f in fields(probe)]
        self.fields = [n for n in names if n not in IGNORED]
        self.shapes = {n: np.shape(getattr(probe, n))[1:] for n in self.fields}
        self.width = 1 + sum(int(np.prod(s)) for s in self.shapes.values())
        # every choice vector of K robots, directions 0..3
        self.table = np.array(list(itertools.product(range(4), repeat=case.k)), dtype=np.int64)
        self._toward_ports: list | None = None
        self._ask_table: list | None = None

    # --- abstract states <-> world states -------------------------------------------
    def encode(self, s: world.State, tmod: int) -> np.ndarray:
        """int8 ``[R, width]``: the abstract state of every row of ``s``."""
        R, K = s.pos.shape
        occ = np.full_like(s.occ, -1)
        occ[np.arange(R)[:, None], s.pos] = np.arange(K)[None]
        assert (occ == s.occ).all(), "occ disagrees with pos"
        if self.p.homes.size:
            res = np.full_like(s.reserved, -1)
            rr, kk = np.nonzero(s.goal >= 0)
            res[rr, s.goal[rr, kk]] = kk
            assert (res == s.reserved).all(), "reserved disagrees with goal"
        cols = [np.full((R, 1), tmod, dtype=np.int64)]
        for n in self.fields:
            v = np.asarray(getattr(s, n)).reshape(R, -1)
            if n == "since":
                v = dense_rank(v, v >= 0, with_zero=False)
            elif n == "queued_since":
                v = dense_rank(v, s.mode == world.QUEUED, with_zero=False)
            cols.append(v.astype(np.int64))
        out = np.concatenate(cols, axis=1)
        assert out.min() >= -128 and out.max() <= 127, "a state value out of int8"
        return out.astype(np.int8)

    def decode(self, rows: np.ndarray, t: int | None = None) -> world.State:
        """A world of ``len(rows)`` runs in the abstract states ``rows`` (all one ``t mod
        K``); ``t``: the steps taken (default: one above every stored queue rank)."""
        K = self.case.k
        tmod = int(rows[0, 0])
        assert (rows[:, 0] == tmod).all()
        R = rows.shape[0]
        values = {}
        i = 1
        for n in self.fields:
            size = int(np.prod(self.shapes[n]))
            values[n] = rows[:, i : i + size].astype(np.int64).reshape((R,) + self.shapes[n])
            i += size
        s = world.init_state(self.p, values["pos"])
        for n, v in values.items():
            setattr(s, n, v.copy())
        s.t = t if t is not None else K * (K + 2) + tmod
        if self.p.homes.size:
            s.reserved[:] = -1
            rr, kk = np.nonzero(s.goal >= 0)
            s.reserved[rr, s.goal[rr, kk]] = kk
        return s

    def starts(self) -> np.ndarray:
        """The abstract states before the first step: every placement of the K robots."""
        c, K = self.p.n_cells, self.case.k
        pos = np.array(list(itertools.permutations(range(c), K)), dtype=np.int64)
        return self.encode(world.init_state(self.p, pos), 0)

    # --- one step of every row, under every choice of the adversary ----------------
    def successors(self, rows: np.ndarray, t: int | None = None, perturb=None):
        """``(src [M], succ [M, width], fail [M, K], moved [M, K], choice [M, K])``: one
        entry per row of ``rows`` (abstract states, one ``t mod K``) and adversary choice
        vector; ``fail``: the step added to the robot's wait. ``perturb(state)``, if
        given, edits the decoded world first (``test_abstraction_is_exact``)."""
        K = self.case.k
        tmod = int(rows[0, 0])
        s = self.decode(rows, t)
        if perturb is not None:
            perturb(s)
        # the oldest task's age as the step begins (a task dropped at the step's start,
        # for a station, ends it as surely as reaching its aim)
        on_map = s.mode != world.GONE
        oldest_all = np.where(on_map, s.since, np.iinfo(np.int64).max).min(axis=1)
        obs = world.begin_step(s, self.p)
        aim = None
        pre = None
        if self.case.adversary == "goal":
            src, choice, aim = self._goal_options(s, obs)
            if self.case.early:
                src, pre, choice, aim = self._exchange_options(s, obs, src, choice, aim)
        else:
            allowed = prefer_open(obs) if self.case.adversary == "open" else obs.legal
            tab = self.table
            ok_dir = allowed[:, np.arange(K)[None, :], tab]  # [R, T, K]: choice allowed for k
            ok = np.where(obs.choosing[:, None, :], ok_dir, (tab == 0)[None])
            src, combo = np.nonzero(ok.all(axis=2))
            choice = np.where(obs.choosing[src], tab[combo], -1)
        # a robot has a task while it patrols, heads for a station or waits for one
        mode = s.mode[src]
        task = (mode == world.PATROL) | (mode == world.HOMING) | (mode == world.QUEUED)
        oldest = oldest_all[src][:, None]
        s2 = _rows_of(s, src)
        obs2 = _rows_of(obs, src)
        obs2.state = s2
        exchanged = np.zeros(choice.shape, dtype=bool)
        if pre is not None:  # the tasks go with the goals exchanged (the world's rule)
            exchanged = self.exchange_before_meeting(s2, pre)
        out = world.step(s2, self.p, obs2, choice, aim, plans=self.case.head_on)
        # safety on every transition: one robot per cell, no swaps, moves between
        # neighbours only, no charge below 0
        before, after = s.pos[src], s2.pos
        cells = np.sort(after, axis=1)
        assert not (cells[:, 1:] == cells[:, :-1]).any(), "two robots in one cell"
        swap = (after[:, :, None] == before[:, None, :]) & (before[:, :, None] == after[:, None, :])
        assert not (swap & ~np.eye(K, dtype=bool)[None]).any(), "two robots swapped cells"
        step = after != before
        adjacent = (self.p.neighbors[before] == after[..., None]).any(axis=-1)
        assert adjacent[step].all(), "a robot jumped"
        assert (s2.charge >= 0).all(), "a charge below 0"
        succ = self.encode(s2, (tmod + 1) % K)
        if aim is None:
            aim = np.full(choice.shape, -1, dtype=np.int64)
        # robot i fails: it has a task, its task did not end, and it did not hand it on
        # (exchanged it: the holder and the robot in its way both patrolling, rule 2,
        # traffic.hand_on, each carrying on the other's task; or the robot it exchanged
        # goals with before the step: its task went on, or ended there); the oldest age
        # is kept: a robot on the map still has the age that was the oldest
        gave = (out.swapped >= 0) | exchanged
        fail = task & ~out.progressed & ~gave
        kept = ((s2.since == oldest) & (s2.mode != world.GONE) & ~out.progressed).any(axis=1)
        # the witnesses keep the asks before an exchange (the exchange and the asks after
        # it follow from them and the aims: replay)
        return src, succ, fail, out.moved, choice if pre is None else pre, aim, kept

    def _pairs(self, pos: np.ndarray, choice: np.ndarray) -> tuple[np.ndarray, ...]:
        """The robots about to meet (int ``[B]`` each: rows, k, j with k < j): both
        choosing, each asking for the other's cell (``pos``, ``choice`` int ``[M, K]``)."""
        nxt = np.where(choice >= 0, self.p.neighbors[pos, np.maximum(choice, 0)], -1)
        k = np.arange(self.case.k)
        meets = (nxt[:, :, None] == pos[:, None, :]) & (nxt[:, None, :] == pos[:, :, None])
        meets &= (k[:, None] < k[None, :])[None]
        return np.nonzero(meets)

    def exchange_before_meeting(self, s: world.State, pre: np.ndarray) -> np.ndarray:
        """Two robots of ``s`` (rows: options) each asking for the other's cell (``pre``,
        their asks before the exchange) exchange their tasks as the walk followers do
        (:func:`qpatrol.world.traffic.exchange_plans`: the ages and the right of way go
        with the goals, a task handed to the robot on its aim ends). Returns bool ``[M,
        K]``, the robots that exchanged."""
        rr, kk, jj = self._pairs(s.pos, pre)
        traffic.exchange_plans(s, rr, kk, jj)
        out = np.zeros(pre.shape, dtype=bool)
        out[rr, kk] = out[rr, jj] = True
        return out

    def asks_after(self, pos, is_open, pre, aim, movers=None) -> list[int]:
        """The asks of one option (``pos``, ``pre``, ``aim`` int ``[K]``; ``is_open`` bool
        ``[K, D]``): a robot that exchanged goals (``movers``; None: found from ``pre``)
        asks for the lowest open port on a shortest path to its new aim (else the lowest
        such port: it insists); the others as before."""
        if movers is None:
            _, kk, jj = self._pairs(np.asarray(pos)[None], np.asarray(pre)[None])
            movers = kk.tolist() + jj.tolist()
        out = [int(x) for x in pre]
        toward = self._toward()
        for k in movers:
            out[k] = _ask_toward(toward[int(pos[k])][int(aim[k])], is_open[k])
        return out

    def _exchange_options(self, s, obs, src, pre, aim):
        """The goal adversary's options with the exchange before meeting (``Case.early``):
        ``(src, pre, choice, aim)``. Two choosing robots each asking for the other's cell
        exchange goals; a robot handed the goal it stands on (its task ends) is given
        any target but its cell outside a pocket another robot holds, as at the end of
        a task; the robots that exchanged then ask towards their goals
        (:meth:`asks_after`). ``pre``: the asks before the exchange."""
        targets = np.flatnonzero(self.p.target).tolist()
        held = self._held_by_other(s)
        mm, kk, jj = self._pairs(s.pos[src], pre)
        keep = np.ones(src.size, dtype=bool)
        keep[mm] = False
        out_src, out_pre, out_choice, out_aim = [src[keep]], [pre[keep]], [pre[keep]], [aim[keep]]
        pairs: dict[int, list[tuple[int, int]]] = {}
        for m, k, j in zip(mm.tolist(), kk.tolist(), jj.tolist(), strict=True):
            pairs.setdefault(m, []).append((k, j))
        pos_all, open_all = s.pos.tolist(), obs.open.tolist()
        for m, ms in pairs.items():
            r = int(src[m])
            pos, aim_m = pos_all[r], aim[m].tolist()
            goals = [[a] for a in aim_m]
            for k, j in ms:
                goals[k], goals[j] = [aim_m[j]], [aim_m[k]]
            for k, j in ms:
                for x in (k, j):
                    if goals[x][0] == pos[x]:
                        goals[x] = [y for y in targets if y != pos[x] and held[r][y] in (-1, x)]
            combos = list(itertools.product(*goals))
            out_src.append(np.full(len(combos), r, dtype=np.int64))
            out_pre.append(np.repeat(pre[m][None], len(combos), axis=0))
            out_aim.append(np.array(combos, dtype=np.int64))
            movers = [x for pair in ms for x in pair]
            asks = [self.asks_after(pos, open_all[r], pre[m], a, movers) for a in combos]
            out_choice.append(np.array(asks, dtype=np.int64))
        return tuple(np.concatenate(x) for x in (out_src, out_pre, out_choice, out_aim))

    def _held_by_other(self, s: world.State) -> list[list[int]]:
        """Per row of ``s`` and cell, the robot holding the station of the cell's pocket
        (-1: no pocket, or its station held by nobody): a goal follower other than that
        robot takes none of these cells as a goal."""
        h = self.p.pocket_of
        R = s.pos.shape[0]
        if not self.p.homes.size:
            return [[-1] * h.size] * R
        return np.where(h >= 0, s.reserved[:, np.maximum(h, 0)], -1).tolist()

    def _toward(self) -> list[list[list[int]]]:
        """``[c][g]``: the ports of cell c on a shortest path to g, lowest first."""
        if self._toward_ports is None:
            dist = self.dist.tolist()
            nbrs = self.p.neighbors.tolist()
            self._toward_ports = [
                [
                    [d for d, x in enumerate(nb) if x >= 0 and dist[x][g] == dist[c][g] - 1]
                    for g in range(len(nbrs))
                ]
                for c, nb in enumerate(nbrs)
            ]
        return self._toward_ports

    def _asks(self) -> list[list[list[int]]]:
        """``[c][g][bits]``: the goal adversary's ask at cell c for goal g
        (:func:`_ask_toward`) when the open ports are the bits of ``bits`` (-1 if c is
        g): a table, as a family asks it millions of times."""
        if self._ask_table is None:
            D = self.p.neighbors.shape[1]
            masks = [[bool(b >> d & 1) for d in range(D)] for b in range(1 << D)]
            self._ask_table = [
                [[_ask_toward(on, m) if on else -1 for m in masks] for on in row]
                for row in self._toward()
            ]
        return self._ask_table

    def _goal_options(self, s: world.State, obs: world.Observation):
        """The goal adversary's options: ``(src [M], choice [M, K], aim [M, K])``. A
        choosing robot keeps its aim (``State.aim``) until it reaches it; then, or
        without one, the adversary gives it any target but its cell outside a pocket
        whose station another robot holds. It asks for the lowest open port on a
        shortest path to its aim, else the lowest such port (it insists, as the goal
        followers do)."""
        n_cells = self.p.n_cells
        targets = np.flatnonzero(self.p.target).tolist()
        asks = self._asks()
        held = self._held_by_other(s)
        pos, aim_all = s.pos.tolist(), s.aim.tolist()
        D = obs.open.shape[-1]
        bits = (obs.open.astype(np.int64) << np.arange(D)).sum(axis=-1)  # [R, K]
        choosing, bits_all = obs.choosing.tolist(), bits.tolist()
        src, choices, aims = [], [], []
        for r in range(s.pos.shape[0]):
            options = []
            held_r = held[r]
            for k in range(self.case.k):
                c = pos[r][k]
                if not choosing[r][k]:
                    options.append([(-1, -1)])
                    continue
                a = aim_all[r][k]
                if 0 <= a < n_cells and a != c:
                    goals = [a]
                else:
                    goals = [x for x in targets if x != c and (held_r[x] < 0 or held_r[x] == k)]
                ask_c, b = asks[c], bits_all[r][k]
                options.append([(ask_c[g][b], g) for g in goals] if goals else [(-1, -1)])
            for combo in itertools.product(*options):
                src.append(r)
                choices.append([d for d, _ in combo])
                aims.append([g for _, g in combo])
        return (
            np.array(src, dtype=np.int64),
            np.array(choices, dtype=np.int64).reshape(-1, self.case.k),
            np.array(aims, dtype=np.int64).reshape(-1, self.case.k),
        )

    # --- the whole graph ----------------------------------------------------------
    def explore(self, max_states: int = 2_000_000, chunk: int = 4000) -> Result:
        """Every reachable state and transition; then the livelocks (:func:`livelocks`)."""
        K = self.case.k
        start = self.starts()
        keys = _keys(start)
        ids: dict[bytes, int] = {}
        order: list[bytes] = []
        for key in keys:
            if key not in ids:
                ids[key] = len(order)
                order.append(key)
        frontier = np.arange(len(order))
        store = [np.frombuffer(b"".join(order), dtype=np.int8).reshape(-1, self.width)]
        n_start = len(order)
        e_src, e_dst, e_fail, e_moved, e_choice, e_aim = [], [], [], [], [], []
        base = self.p.n_cells + 1
        weights = (1 << np.arange(K)).astype(np.int64)
        complete = True
        while frontier.size:
            nxt: list[int] = []
            all_rows = _rows(store, frontier, self.width)
            for lo in range(0, frontier.size, chunk):
                rows = all_rows[lo : lo + chunk]
                src, succ, fail, moved, choice, aim, kept = self.successors(rows)
                skeys = _keys(succ)
                dst = np.empty(src.size, dtype=np.int64)
                new_keys = []
                for j, key in enumerate(skeys):
                    i = ids.get(key)
                    if i is None:
                        i = ids[key] = len(order)
                        order.append(key)
                        new_keys.append(key)
                        nxt.append(i)
                    dst[j] = i
                if new_keys:
                    store.append(
                        np.frombuffer(b"".join(new_keys), dtype=np.int8).reshape(-1, self.width)
                    )
                e_src.append(frontier[lo : lo + chunk][src])
                e_dst.append(dst)
                # bit K: the oldest age was kept (a task as old as any did not end)
                e_fail.append(fail.astype(np.int64) @ weights + (kept.astype(np.int64) << K))
                e_moved.append(moved.astype(np.int64) @ weights)
                e_choice.append((choice + 1) @ (5 ** np.arange(K)))
                e_aim.append((aim + 1) @ (base ** np.arange(K)))
            if len(order) > max_states:
                complete = False
                break
            frontier = np.array(nxt, dtype=np.int64)
        self.order = order
        self.n_start = n_start
        cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0, dtype=np.int64)  # noqa: E731
        self.edges = (cat(e_src), cat(e_dst), cat(e_fail), cat(e_moved), cat(e_choice))
        self.edge_aims = cat(e_aim)
        result = Result(self.case, len(order), int(self.edges[0].size), complete=complete)
        if complete:
            result.livelocks = self.livelocks()
        return result

    def livelocks(self) -> list[Livelock]:
        """One witness per robot and per component of its failing subgraph, and per
        component of the subgraph on which the oldest age is kept (robot ``K`` in the
        witness: the oldest task, whoever carries it)."""
        src, dst, fail, moved, choice = self.edges
        n = len(self.order)
        found = []
        for i in range(self.case.k + 1):
            sel = (fail >> i) & 1 == 1
            comp = strong_components(n, src[sel], dst[sel])
            s_i, d_i = src[sel], dst[sel]
            inside = comp[s_i] == comp[d_i]
            if not inside.any():
                continue
            for c in np.unique(comp[s_i[inside]]):
                e = np.flatnonzero(sel)[inside & (comp[s_i] == c)]
                found.append(self._witness(i, int(c), comp, e))
        found.sort(key=lambda w: (len(w.cycle), len(w.prefix)))
        return found

    def _witness(self, robot: int, c: int, comp: np.ndarray, e: np.ndarray) -> Livelock:
        src, dst, fail, moved, choice = self.edges
        # one cycle in the component: breadth-first from a state back to itself
        nodes_out: dict[int, list[int]] = {}
        for j in e.tolist():
            nodes_out.setdefault(int(src[j]), []).append(j)
        first = min(nodes_out)
        parent: dict[int, int] = {}
        queue = deque([first])
        cycle_edges: list[int] = []
        while queue and not cycle_edges:
            v = queue.popleft()
            for j in nodes_out.get(v, []):
                w = int(dst[j])
                if w == first:
                    cycle_edges = [j]
                    while v != first:
                        cycle_edges.append(parent[v])
                        v = int(src[parent[v]])
                    cycle_edges.reverse()
                    break
                if w not in parent:
                    parent[w] = j
                    queue.append(w)
        prefix_edges = self._path_to(first)
        base = self.p.n_cells + 1
        decode = lambda j: (  # noqa: E731
            self.order[int(src[j])],
            tuple(int(x) - 1 for x in _digits(int(choice[j]), self.case.k)),
            tuple(int(x) - 1 for x in _digits(int(self.edge_aims[j]), self.case.k, base)),
        )
        pushed = any((int(moved[j]) >> robot) & 1 for j in cycle_edges)
        return Livelock(
            robot=robot,
            component=int((comp == c).sum()),
            prefix=[decode(j) for j in prefix_edges],
            cycle=[decode(j) for j in cycle_edges],
            pushed=pushed,
        )

    def _path_to(self, target: int) -> list[int]:
        """Edges of a shortest path from a start state to ``target``."""
        src, dst = self.edges[0], self.edges[1]
        if target < self.n_start:
            return []
        # states are numbered in breadth-first order: the first edge into a state found
        # in the layer before is on a shortest path
        first_in = np.full(len(self.order), -1, dtype=np.int64)
        seen, at = np.unique(dst, return_index=True)
        first_in[seen] = at
        path = []
        v = target
        while v >= self.n_start:
            j = int(first_in[v])
            path.append(j)
            v = int(src[j])
        return path[::-1]

    def describe(self, key: bytes) -> str:
        """One abstract state in words."""
        row = np.frombuffer(key, dtype=np.int8).astype(np.int64)
        parts = [f"t%K={row[0]}"]
        i = 1
        for n in self.fields:
            size = int(np.prod(self.shapes[n]))
            v = row[i : i + size].tolist()
            i += size
            if n in ("charge", "rest", "goal", "depart_left", "queued_since", "mode"):
                if not self.case.battery:
                    continue
            if n == "mode":
                v = [world.battery.MODE_NAMES[x] for x in v]
            parts.append(f"{n}={v if len(v) != 1 else v[0]}")
        return " ".join(parts)

    def grid(self, key: bytes) -> str:
        """The map with robot digits on their cells (H: a station nobody stands on)."""
        row = np.frombuffer(key, dtype=np.int8).astype(np.int64)
        i = 1
        pos = None
        for n in self.fields:
            size = int(np.prod(self.shapes[n]))
            if n == "pos":
                pos = row[i : i + size].tolist()
            i += size
        lines = [list(r) for r in self.m_rows()]
        cell = 0
        where = {}
        for r, line in enumerate(lines):
            for c, ch in enumerate(line):
                if ch != "#":
                    where[cell] = (r, c)
                    cell += 1
                    if ch not in "H":
                        line[c] = "."
        for k, cpos in enumerate(pos or []):
            r, c = where[cpos]
            lines[r][c] = str(k)
        return "\n".join("".join(x) for x in lines)

    def m_rows(self) -> list[str]:
        return [r for r in self.case.text.splitlines() if r and not r.startswith(";")]

    def report(self, w: Livelock) -> str:
        """A livelock in words: the map, the path to the cycle and the cycle."""
        out = [f"{self.case.label()}", f"robot {w.robot} fails at every step of this cycle "]
        out[-1] += f"({len(w.cycle)} steps, component of {w.component} states, "
        out[-1] += "pushed around on it)" if w.pushed else "never leaves its cell)"
        dirs = "NESW"
        for title, seq in (("from a start", w.prefix), ("cycle", w.cycle)):
            out.append(f"-- {title}:")
            for key, ch, aim in seq:
                out.append(self.grid(key))
                out.append(
                    "   "
                    + self.describe(key)
                    + "  choice="
                    + "".join(dirs[c] if c >= 0 else "-" for c in ch)
                    + ("  aims=" + str(list(aim)) if self.case.adversary == "goal" else "")
                )
        return "\n".join(out)


def replay(ck: Checker, w: Livelock, loops: int = 3) -> np.ndarray:
    """Run the witness with R = 1 from its start through ``loops`` turns of its cycle,
    with concrete steps; returns the robot's *stall* (steps since its task began, ``t -
    since``; for robot ``K``, the oldest task's age) after each turn (int ``[loops]``),
    and asserts every state met is the one the graph predicts."""
    seq = w.prefix + w.cycle * loops
    s = ck.decode(np.frombuffer(seq[0][0], dtype=np.int8)[None].copy(), t=0)
    K = ck.case.k
    waits = []
    for n, (key, ch, aim) in enumerate(seq):
        assert ck.encode(s, s.t % K).tobytes() == key, f"state {n} differs from the graph"
        obs = world.begin_step(s, ck.p)
        aims = np.array([aim], dtype=np.int64) if ck.case.adversary == "goal" else None
        asks = np.array([ch], dtype=np.int64)
        if ck.case.early:  # the witness keeps the asks before the exchange
            after = ck.asks_after(s.pos[0], obs.open[0], ch, aim)
            ck.exchange_before_meeting(s, asks)
            asks = np.array([after], dtype=np.int64)
        world.step(s, ck.p, obs, asks, aims, plans=ck.case.head_on)
        if n >= len(w.prefix) and (n - len(w.prefix)) % len(w.cycle) == len(w.cycle) - 1:
            if w.robot < K:
                waits.append(int(s.t - s.since[0, w.robot]))
            else:  # the oldest task, whoever carries it
                waits.append(int(s.t - s.since[0][s.mode[0] != world.GONE].min()))
    assert ck.encode(s, s.t % K).tobytes() == w.cycle[0][0]
    return np.array(waits)


def strong_components(n: int, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """int ``[n]``: the strongly connected component of each node (iterative Tarjan,
    compiled: a family's graphs have millions of edges) of the graph with edges
    ``src[j] -> dst[j]``; nodes without out-edges are components of their own."""
    src = np.asarray(src, dtype=np.int64)
    order = np.argsort(src, kind="stable")
    heads = np.searchsorted(src[order], np.arange(n + 1)).astype(np.int64)
    return _tarjan(n, heads, np.asarray(dst, dtype=np.int64)[order])


@njit(cache=True)
def _tarjan(n, heads, succ):  # pragma: no cover - compiled
    index = np.full(n, -1, dtype=np.int64)
    low = np.zeros(n, dtype=np.int64)
    on_stack = np.zeros(n, dtype=np.bool_)
    comp = np.full(n, -1, dtype=np.int64)
    stack = np.empty(n, dtype=np.int64)
    work_v = np.empty(n, dtype=np.int64)  # the depth-first path: node, next edge
    work_j = np.empty(n, dtype=np.int64)
    top = 0  # stack size
    depth = 0  # work size
    counter = 0
    n_comp = 0
    for root in range(n):
        if index[root] >= 0 or heads[root] == heads[root + 1]:
            continue
        work_v[0], work_j[0] = root, heads[root]
        depth = 1
        index[root] = low[root] = counter
        counter += 1
        stack[top] = root
        top += 1
        on_stack[root] = True
        while depth:
            v, j = work_v[depth - 1], work_j[depth - 1]
            if j < heads[v + 1]:
                work_j[depth - 1] = j + 1
                w = succ[j]
                if index[w] < 0:
                    index[w] = low[w] = counter
                    counter += 1
                    stack[top] = w
                    top += 1
                    on_stack[w] = True
                    work_v[depth], work_j[depth] = w, heads[w]
                    depth += 1
                elif on_stack[w] and index[w] < low[v]:
                    low[v] = index[w]
                continue
            depth -= 1
            if depth:
                u = work_v[depth - 1]
                if low[v] < low[u]:
                    low[u] = low[v]
            if low[v] == index[v]:
                while True:
                    top -= 1
                    w = stack[top]
                    on_stack[w] = False
                    comp[w] = n_comp
                    if w == v:
                        break
                n_comp += 1
    for v in range(n):  # nodes without out-edges are their own components
        if comp[v] < 0:
            comp[v] = n_comp
            n_comp += 1
    return comp


def dense_rank(v: np.ndarray, mask: np.ndarray, with_zero: bool) -> np.ndarray:
    """int ``[R, K]``: each masked value's rank among the distinct masked values of its
    row (and 0, if ``with_zero``), 0 for the smallest; unmasked entries 0."""
    R, K = v.shape
    big = np.where(mask, v, np.iinfo(np.int64).max)
    less = big[:, None, :] < big[:, :, None]  # [R, i, j]: v_j < v_i
    same_before = np.triu(np.ones((K, K), dtype=bool), 1).T[None] & (
        big[:, :, None] == big[:, None, :]
    )  # [R, j, j']: j' < j with v_j' == v_j
    first = mask & ~same_before.any(axis=2)
    rank = (less & first[:, None, :]).sum(axis=2)
    if with_zero:
        zero_present = (mask & (v == 0)).any(axis=1, keepdims=True)
        rank = rank + ((v > 0) & ~zero_present)
    return np.where(mask, rank, 0)


def _ask_toward(on_path: list[int], is_open) -> int:
    """The goal adversary's ask: the lowest open port of ``on_path`` (the ports on a
    shortest path to the goal, lowest first), else the lowest of them (it insists)."""
    open_ = [d for d in on_path if is_open[d]]
    return (open_ or on_path)[0]


def _rows_of(obj, src: np.ndarray):
    """A copy of a world dataclass (State, Observation) whose arrays keep the runs
    ``src`` (int ``[M]``) of their leading runs axis; other fields as they are."""
    values = {}
    for f in fields(obj):
        v = getattr(obj, f.name)
        values[f.name] = v[src].copy() if isinstance(v, np.ndarray) and v.ndim else v
    return type(obj)(**values)


def _keys(rows: np.ndarray) -> list[bytes]:
    a = np.ascontiguousarray(rows, dtype=np.int8)
    return a.view(np.dtype((np.void, a.shape[1]))).ravel().tolist()


def _rows(store: list[np.ndarray], ids: np.ndarray, width: int) -> np.ndarray:
    offsets = np.cumsum([0] + [b.shape[0] for b in store])
    out = np.empty((ids.size, width), dtype=np.int8)
    for b, (lo, hi) in enumerate(zip(offsets[:-1], offsets[1:], strict=True)):
        sel = (ids >= lo) & (ids < hi)
        if sel.any():
            out[sel] = store[b][ids[sel] - lo]
    return out


def _digits(x: int, k: int, base: int = 5) -> list[int]:
    return [(x // base**i) % base for i in range(k)]


# --- the family of small maps --------------------------------------------------------


def shapes(n: int, max_cycles: int = 1) -> list[frozenset[tuple[int, int]]]:
    """Every connected set of ``n`` grid cells whose cell graph (4-neighbourhood) has at
    most ``max_cycles`` independent cycles (0: trees), up to translation (the rules
    break ties in N, E, S, W order, so rotations and mirror images are different maps)."""
    step = ((-1, 0), (0, 1), (1, 0), (0, -1))

    def norm(cells):
        r0 = min(r for r, _ in cells)
        c0 = min(c for _, c in cells)
        return frozenset((r - r0, c - c0) for r, c in cells)

    def cycles(cells):
        edges = sum((r + 1, c) in cells for r, c in cells) + sum(
            (r, c + 1) in cells for r, c in cells
        )
        return edges - len(cells) + 1

    level = {frozenset({(0, 0)})}
    for _ in range(n - 1):
        nxt = set()
        for sh in level:
            for r, c in sh:
                for dr, dc in step:
                    x = (r + dr, c + dc)
                    if x not in sh:
                        new = sh | {x}
                        if cycles(new) <= max_cycles:
                            nxt.add(norm(new))
        level = nxt
    return sorted(level, key=lambda s: sorted(s))


def map_text(cells: frozenset[tuple[int, int]], stations: tuple[tuple[int, int], ...] = ()) -> str:
    """Map text of a cell set (walls around it), with ``H`` on ``stations``."""
    h = max(r for r, _ in cells) + 1
    w = max(c for _, c in cells) + 1
    lines = []
    for r in range(h):
        line = ""
        for c in range(w):
            line += "H" if (r, c) in stations else "." if (r, c) in cells else "#"
        lines.append(line)
    return "\n".join(lines) + "\n"


def degree(cells: frozenset[tuple[int, int]], x: tuple[int, int]) -> int:
    r, c = x
    return sum((r + dr, c + dc) in cells for dr, dc in ((-1, 0), (0, 1), (1, 0), (0, -1)))


def cut_cells(cells: frozenset[tuple[int, int]]) -> list[tuple[int, int]]:
    """The cells whose removal disconnects the others (cut vertices), row-major."""
    out = []
    for x in sorted(cells):
        rest = cells - {x}
        start = next(iter(rest))
        seen, todo = {start}, [start]
        while todo:
            r, c = todo.pop()
            for y in ((r - 1, c), (r, c + 1), (r + 1, c), (r, c - 1)):
                if y in rest and y not in seen:
                    seen.add(y)
                    todo.append(y)
        if len(seen) < len(rest):
            out.append(x)
    return out


def station_choices(
    cells: frozenset[tuple[int, int]],
    two: bool = False,
    dead_pair: bool = False,
    corridor: bool = False,
) -> list[tuple[tuple[int, int], ...]]:
    """One station at the first dead end (row-major), one on the first junction, with
    ``two`` both at once, and with ``dead_pair`` (only) one at the first and one at the
    last dead end; with ``corridor`` also one on the first cell of two neighbours that
    is a cut vertex (a corridor's cell whose robot, charging, cuts the map in two) and
    one on the first cell of a loop (two neighbours, not a cut vertex)."""
    ordered = sorted(cells)
    dead = [x for x in ordered if degree(cells, x) == 1]
    if dead_pair:
        return [(dead[0], dead[-1])] if len(dead) >= 2 else []
    out = []
    junction = [x for x in ordered if degree(cells, x) >= 3]
    if dead:
        out.append((dead[0],))
    if junction:
        out.append((junction[0],))
    if corridor:
        cuts = set(cut_cells(cells)) if len(cells) > 2 else set()
        two_way = [x for x in ordered if degree(cells, x) == 2]
        on_cut = [x for x in two_way if x in cuts]
        on_loop = [x for x in two_way if x not in cuts]
        out += [(on_cut[0],)] if on_cut else []
        out += [(on_loop[0],)] if on_loop else []
    if two and dead and junction:
        out.append((dead[0], junction[0]))
    elif two and len(dead) >= 2:
        out.append((dead[0], dead[-1]))
    return out


def family(
    sizes: range,
    ks: range | None = None,
    battery: bool = False,
    every: int = 1,
    two_stations: bool = False,
    dead_pair: bool = False,
    corridor: bool = False,
    seed: int | None = None,
    sample: int | None = None,
    **kw,
) -> list[Case]:
    """Cases on every tree and one-loop shape of each size (``every``: one shape in that
    many, in a fixed order), K from 2 up to the density limit (or ``ks``); with the
    battery, a station at a dead end, on a junction, and with ``two_stations`` two at
    once, ``corridor`` on a corridor cell that cuts the map and on a loop
    (:func:`station_choices`); ``kw``: the :class:`Case` fields. Cases the config
    refuses (:func:`qpatrol.world.make_params`: too many robots for the map, a capacity
    too small, a battery team without room to reach a station,
    :func:`qpatrol.world.check_battery_room`) are left out: the density limit is whatever
    the world accepts. With ``sample``, that many of the accepted cases, drawn with
    ``seed`` (numpy's default generator), in the family's order."""
    out = []
    for n in sizes:
        for sh in shapes(n)[::every]:
            for k in ks or range(2, n + 1):
                if battery:
                    for st in station_choices(sh, two_stations, dead_pair, corridor):
                        out.append(Case(map_text(sh, st), k, battery=True, **kw))
                else:
                    out.append(Case(map_text(sh), k, **kw))
    cases = [c for c in out if accepted(c)]
    if sample is not None and sample < len(cases):
        pick = np.random.default_rng(seed).choice(len(cases), sample, replace=False)
        cases = [cases[i] for i in sorted(pick.tolist())]
    return cases


def accepted(case: Case) -> bool:
    """The config and the world accept the case (:func:`qpatrol.world.make_params`)."""
    try:
        Checker(case)
    except ConfigError:
        return False
    return True


def check_all(cases: list[Case], max_states: int = 2_000_000, verbose: bool = False):
    """Explore every case; returns (results, total states, total edges)."""
    results = []
    for case in cases:
        ck = Checker(case)
        res = ck.explore(max_states=max_states)
        res.checker = ck
        if not res.livelocks:
            ck.edges, ck.order = (), []  # nothing to report: let the graph go
        results.append(res)
        if verbose and res.livelocks:
            print(ck.report(res.livelocks[0]))
    return results


def main(argv: list[str] | None = None) -> int:  # pragma: no cover - by hand
    """Check a family from the command line; prints counts and the smallest livelock."""
    import argparse
    import time

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="4-6", help="cells per map, e.g. 4-6")
    ap.add_argument("--k", default="", help="team sizes, e.g. 2-3 (default 2 to C/2)")
    ap.add_argument("--battery", action="store_true")
    ap.add_argument("--charge-steps", type=int, default=1)
    ap.add_argument("--extra-capacity", type=int, default=0, help="above the smallest")
    ap.add_argument("--initial-charge", default="staggered")
    ap.add_argument("--adversary", default="open", choices=("open", "legal", "goal"))
    ap.add_argument("--two-stations", action="store_true", help="also two stations at once")
    ap.add_argument("--show", type=int, default=1, help="livelocks to draw")
    a = ap.parse_args(argv)

    def span(text: str) -> range:
        lo, _, hi = text.partition("-")
        return range(int(lo), int(hi or lo) + 1)

    t0 = time.perf_counter()
    kw = {"adversary": a.adversary}
    if a.battery:
        kw.update(
            charge_steps=a.charge_steps,
            initial_charge=a.initial_charge,
            extra_capacity=a.extra_capacity,
        )
    ks = span(a.k) if a.k else None
    cases = family(span(a.sizes), ks, battery=a.battery, two_stations=a.two_stations, **kw)
    res = check_all(cases)
    bad = [r for r in res if r.livelocks]
    print(
        f"{len({c.text for c in cases})} maps, {len(cases)} cases, "
        f"{sum(r.states for r in res)} states, {sum(r.edges for r in res)} transitions, "
        f"{len(bad)} cases with a livelock, {time.perf_counter() - t0:.1f} s"
    )
    bad.sort(key=lambda r: (r.checker.p.n_cells, r.case.k, len(r.livelocks[0].cycle)))
    for r in bad[: a.show]:
        print(r.checker.report(r.livelocks[0]))
        print("replayed with R=1, the robot's wait after each turn of the cycle:")
        print(replay(r.checker, r.livelocks[0]).tolist())
    return 1 if bad else 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
