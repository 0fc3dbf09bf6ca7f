"""``learned-tour``: robots that learn a short closed route online, and keep their spacing on it.

What the team learns is a *routing table*: for each cell and each side a robot arrives
by, the port to leave by. A table is a deterministic walker, so from any start a robot
that obeys it falls into one closed loop: the team's *route*. A route that traverses no
directed edge (move from one cell to the next) twice is exactly a table, and the
shortest closed walk through every target is such a route (a walk that crosses one
edge twice the same way can be shortened by 2, :func:`repair`). So the table can hold
a tour as short as ``cyclic``'s, and this learner searches for one while it patrols.

Why not value learning: paid the idleness of the cells it enters, a robot on any closed
covering walk earns on average the number of cells per step, whatever the walk's
length (docs/model.md, "Idleness-paid rewards are blind to tour length"), so a value
learner cannot prefer the short tour. This learner scores a table by the length of its
route, and keeps a change only when the route gets shorter.

How it learns (one learner per team with ``team.communication`` on, one per robot
otherwise; a learner proposes one change per team step in which one of its robots
patrols, during the first ``tour.learn_steps`` team steps if that is set). Its memory
is an *order* of the targets, the order in which its route first visits them; the route
is that order joined by shortest paths (first port one move closer: N, E, S, W on a
grid) and then :func:`repair`-ed, and the table is the route's exits. Each step it
draws one proposal from robot g's first uniform of the step, for learner g:

* a 2-opt move: reverse the part of the route between two passes, so that a target
  is followed by one of its ``tour.neighbours`` nearest targets (the exits of the two
  passes exchanged);
* an or-opt move: carry one to three consecutive targets, either way round, next to
  one of their nearest targets (a stretch the route walks out and back rerouted);

and keeps it when the order's length (the sum of shortest-path lengths between
consecutive targets) does not grow. After ``tour.kick_after`` proposals without a
shortening it restarts from the best order with a random double bridge (two
neighbouring stretches of at most 40 targets swapped). The route the robots walk is
the best order's; it changes only when a proposal makes the order strictly shorter
than the best so far and its route is shorter than the one the robots follow.
Starting order: depth-first from the learner's first robot's start cell (on a tree,
already the optimum).

Walking the route: the robots follow it as ``cyclic``'s robots follow their walk
(:mod:`qpatrol.strategies.follow`: a displaced robot takes a shortest path back to its
target; robots meeting head-on exchange plans; targets in a held station pocket are
skipped). Spacing is a stated rule, not learned: a robot waits on its target while the
next robot ahead on the route is nearer than ``floor(n / K)`` route steps (``n`` the
route's length, ``K`` the robots on it). When the route changes, every robot on it
heads for the first route cell nearest its old target cell.

Arrays (``R`` runs, ``G`` learners, ``T`` targets, ``C`` cells): ``order``, ``best``
int ``[R, G, T]`` (cells); ``pos`` int ``[R, G, C]`` (index of a target cell in
``order``); ``cur_len``, ``best_len``, ``stall`` int ``[R, G]``; the route is the
follower's ``walk [R, G, Lmax]`` and ``length [R, G]``; ``history``: per run and
learner, the (team step, route length) of every change.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from qpatrol.maps import walks
from qpatrol.strategies import base, follow

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.world import Observation, Params

#: Largest stretch of targets a double bridge swaps (as :mod:`qpatrol.maps.walks`).
KICK_WINDOW = 40
#: A proposal's integer draw: ``floor(u x 2**31)`` of a uniform ``u`` of the step.
DRAW = 2147483648.0


class Strategy(follow.WalkFollower):
    """A routing table per team (or per robot), learned by local search on its route."""

    name = "learned-tour"
    learns = True

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        R, K = start_cells.shape
        G = 1 if p.communication else K
        dist = m.distances()
        targets = np.flatnonzero(m.target)
        T = targets.size
        self.kick_after = int(cfg["tour.kick_after"])
        steps = cfg["tour.learn_steps"]
        self.learn_steps = -1 if steps is None else int(steps)
        self.near = nearest_targets(dist, targets, min(int(cfg["tour.neighbours"]), max(T - 1, 1)))
        first = [
            [depth_first_order(m.neighbors, m.target, int(start_cells[r, g])) for g in range(G)]
            for r in range(R)
        ]
        self.order = np.array(first, dtype=np.int64).reshape(R, G, T)
        self.best = self.order.copy()
        self.pos = np.zeros((R, G, m.n_cells), dtype=np.int64)
        for r in range(R):
            for g in range(G):
                self.pos[r, g, self.order[r, g]] = np.arange(T)
        self.cur_len = np.array(
            [[order_length(dist, self.order[r, g]) for g in range(G)] for r in range(R)],
            dtype=np.int64,
        ).reshape(R, G)
        self.best_len = self.cur_len.copy()
        self.stall = np.zeros((R, G), dtype=np.int64)
        routes = [route_of(m.neighbors, dist, self.best[r, g]) for r in range(R) for g in range(G)]
        super().__init__(cfg, m, p, start_cells, routes[:G])
        # no later route is longer than its order, and no order than the first
        width = max(int(self.best_len.max()), max(w.size for w in routes))
        self.walk = np.zeros((R, G, width), dtype=np.int64)
        self.length = np.zeros((R, G), dtype=np.int64)
        for r in range(R):
            for g in range(G):
                w = routes[r * G + g]
                self.walk[r, g] = np.pad(w, (0, width - w.size), mode="edge")
                self.length[r, g] = w.size
        self.wid[:] = 0 if G == 1 else np.arange(K)[None, :]
        for r in range(R):
            for k in range(K):
                g = self.wid[r, k]
                self.target[r, k] = follow.nearest_index(
                    self.dist, self.walk[r, g, : self.length[r, g]], int(start_cells[r, k])
                )
        self.spacing = self.lap() // (K // G)
        self.history = [[[(0, int(self.length[r, g]))] for g in range(G)] for r in range(R)]
        self.reference = walks.closed_walk(m).size

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        obs = base.walking(obs)
        if self.learn_steps < 0 or obs.t < self.learn_steps:  # else it keeps its route
            x = np.floor(u[..., 0] * DRAW).astype(np.int64)  # [R, K]
            R, G = self.order.shape[:2]
            for r in range(R):
                for g in range(G):
                    if (obs.choosing[r] & (self.wid[r] == g)).any() and self._propose(
                        r, g, int(x[r, g])
                    ):
                        self._new_route(r, g, obs.t)
        return super().act(obs, u)

    def _propose(self, r: int, g: int, x: int) -> bool:
        """One proposal of learner ``g`` of run ``r``; True when its best order got
        strictly shorter (the route changes)."""
        order, pos, dist = self.order[r, g], self.pos[r, g], self.dist
        if order.size < 5:
            return False
        if self.stall[r, g] >= self.kick_after:
            order[:] = self.best[r, g]
            pos[order] = np.arange(order.size)
            double_bridge(order, pos, x, KICK_WINDOW)
            self.cur_len[r, g] = order_length(dist, order)
            self.stall[r, g] = 0
            return False
        if x % 2 == 0:
            delta = two_opt(order, pos, dist, self.near, x // 2)
        else:
            delta = or_opt(order, pos, dist, self.near, x // 2)
        self.cur_len[r, g] += delta
        self.stall[r, g] = 0 if delta < 0 else self.stall[r, g] + 1
        if self.cur_len[r, g] < self.best_len[r, g]:
            self.best[r, g] = order
            self.best_len[r, g] = self.cur_len[r, g]
            return True
        return False

    def _new_route(self, r: int, g: int, t: int) -> None:
        """The route of the best order, if shorter than the route the robots follow: its
        robots head for the route cell nearest their old target cell; spacing
        ``floor(n / K)``."""
        w = route_of(self.params.neighbors, self.dist, self.best[r, g])
        if w.size >= self.length[r, g]:
            return
        on = self.wid[r] == g
        old = self.walk[r, g, self.target[r]]  # [K] (only the robots on it count)
        self.walk[r, g, : w.size] = w
        self.walk[r, g, w.size :] = w[-1]
        self.length[r, g] = w.size
        for k in np.flatnonzero(on):
            self.target[r, k] = follow.nearest_index(self.dist, w, int(old[k]))
        self.spacing[r, on] = w.size // on.sum()
        self.history[r][g].append((int(t), int(w.size)))

    def start_lengths(self) -> np.ndarray:
        """int ``[R, G]``: each route's length at the start (it only gets shorter)."""
        return np.array([[h[0][1] for h in run] for run in self.history], dtype=np.int64)

    def tables(self) -> dict[str, np.ndarray]:
        """``route``: int8 ``[R, G, C, D]``, the routing table (the exit port per cell and
        arrival port, -1 off the route)."""
        R, G = self.order.shape[:2]
        nbrs, back = self.params.neighbors, self.map.back
        table = np.full((R, G, *nbrs.shape), -1, dtype=np.int8)
        for r in range(R):
            for g in range(G):
                w = self.walk[r, g, : self.length[r, g]]
                for i in range(w.size if w.size > 1 else 0):
                    a, c, b = w[i - 1], w[i], w[(i + 1) % w.size]
                    table[r, g, c, port(back, nbrs, a, c)] = port_to(nbrs, c, b)
        return {"route": table}

    def describe(self) -> dict[str, object]:
        return {"reference_walk_length": int(self.reference)}

    def run_facts(self) -> list[dict[str, object]]:
        """Per run, for ``summary.json``: ``tour_length`` (the route's length at the end;
        without communication the longest of the robots' routes), ``tour_ratio`` (over
        the closed walk ``cyclic`` uses), ``tour_changes``/``tour_lengths`` (the team
        steps at which the route changed and its new lengths; the first robot's
        learner without communication)."""
        out = []
        for r in range(self.order.shape[0]):
            n = int(self.length[r].max())
            steps, lengths = zip(*self.history[r][0], strict=True)
            out.append(
                {
                    "tour_length": n,
                    "tour_ratio": n / self.reference,
                    "tour_changes": list(steps),
                    "tour_lengths": list(lengths),
                }
            )
        return out


# --- one learner's search (1-D arrays; the compiled twin is engines/compiled/tour.py) ---


def nearest_targets(dist: np.ndarray, targets: np.ndarray, n: int) -> np.ndarray:
    """int ``[C, n]``: for each target cell, its ``n`` nearest other targets (ties: lower
    cell first); rows of other cells are -1."""
    C = dist.shape[0]
    out = np.full((C, n), -1, dtype=np.int64)
    if targets.size < 2:
        return out
    d = dist[np.ix_(targets, targets)].astype(np.float64)
    np.fill_diagonal(d, np.inf)
    out[targets] = targets[np.argsort(d, axis=1, kind="stable")[:, :n]]
    return out


def depth_first_order(nbrs: np.ndarray, target: np.ndarray, start: int) -> np.ndarray:
    """int ``[T]``: the target cells in depth-first preorder from ``start`` (ports in
    order)."""
    order = walks._depth_first_order(nbrs, start)
    return order[target[order]].astype(np.int64)


def order_length(dist: np.ndarray, order: np.ndarray) -> int:
    """The closed order's length: shortest-path moves between consecutive targets."""
    return int(dist[order, np.roll(order, -1)].sum())


def reverse(order: np.ndarray, pos: np.ndarray, i: int, j: int) -> None:
    """Reverse ``order[i..j]`` (``i <= j``), keeping ``pos`` its inverse."""
    order[i : j + 1] = order[i : j + 1][::-1].copy()
    pos[order[i : j + 1]] = np.arange(i, j + 1)


def two_opt(order: np.ndarray, pos: np.ndarray, dist: np.ndarray, near: np.ndarray, x: int) -> int:
    """From draw ``x``: target ``a = order[i]`` and ``c``, one of its nearest; make
    ``a -> c`` and ``b -> d`` (``b``, ``d`` the successors of ``a``, ``c``) by reversing
    ``b..c``, if that does not lengthen the order. Returns the change (0 if none)."""
    T = order.size
    i = x % T
    x //= T
    a, b = order[i], order[(i + 1) % T]
    c = near[a, x % near.shape[1]]
    j = pos[c]
    d = order[(j + 1) % T]
    if c == b or d == a:
        return 0
    delta = int(dist[a, c] + dist[b, d] - dist[a, b] - dist[c, d])
    if delta > 0:
        return 0
    if (i + 1) % T <= j:
        reverse(order, pos, (i + 1) % T, j)
    else:  # b..c wraps round: reverse the rest, d..a, instead
        reverse(order, pos, j + 1, i)
    return delta


def or_opt(order: np.ndarray, pos: np.ndarray, dist: np.ndarray, near: np.ndarray, x: int) -> int:
    """From draw ``x``: the 1 to 3 targets from ``order[i]``, carried (``rev``: turned
    round) between ``c``, a nearest target of the end that will touch it, and ``c``'s
    successor ``d``, if that does not lengthen the order. Returns the change."""
    T = order.size
    i = x % T
    x //= T
    n_seg = 1 + x % 3
    x //= 3
    rev = x % 2
    x //= 2
    if T < n_seg + 3:
        return 0
    s0, s1 = order[i], order[(i + n_seg - 1) % T]
    p, n = order[(i - 1) % T], order[(i + n_seg) % T]
    c = near[s1 if rev else s0, x % near.shape[1]]
    j = pos[c]
    if (j - i) % T < n_seg or c == p:
        return 0
    d = order[(j + 1) % T]
    add = dist[c, s1] + dist[s0, d] if rev else dist[c, s0] + dist[s1, d]
    delta = int(dist[p, n] + add - dist[p, s0] - dist[s1, n] - dist[c, d])
    if delta > 0:
        return 0
    seg = order[(i + np.arange(n_seg)) % T]
    head = order[(i + n_seg + np.arange((j - i - n_seg) % T + 1)) % T]  # n .. c
    tail = order[(j + 1 + np.arange(T - n_seg - head.size)) % T]  # d .. p
    order[:] = np.concatenate([head, seg[::-1] if rev else seg, tail])
    pos[order] = np.arange(T)
    return delta


def double_bridge(order: np.ndarray, pos: np.ndarray, x: int, window: int) -> None:
    """From draw ``x``: rotate ``order`` to start at ``order[i]``, then swap the
    neighbouring stretches ``[1..a]`` and ``[a+1..b]`` (``b < window``)."""
    T = order.size
    i = x % T
    x //= T
    w = min(window, T - 1)
    a = 1 + x % (w - 2)
    x //= w - 2
    b = a + 1 + x % (w - 1 - a) if w - 1 - a > 0 else a + 1
    rot = np.roll(order, -i)
    order[:] = np.concatenate([rot[:1], rot[a + 1 : b + 1], rot[1 : a + 1], rot[b + 1 :]])
    pos[order] = np.arange(T)


def expand(nbrs: np.ndarray, dist: np.ndarray, order: np.ndarray) -> np.ndarray:
    """int ``[L]``: the closed walk through ``order`` by shortest paths (each move the
    first port one move closer)."""
    out = []
    T = order.size
    for k in range(T):
        c, goal = int(order[k]), int(order[(k + 1) % T])
        out.append(c)
        while dist[c, goal] > 1:
            row = nbrs[c]
            ok = (row >= 0) & (dist[np.maximum(row, 0), goal] == dist[c, goal] - 1)
            c = int(row[np.argmax(ok)])
            out.append(c)
    return np.array(out, dtype=np.int64)


def repair(w: np.ndarray, nbrs: np.ndarray) -> np.ndarray:
    """The closed walk ``w`` with no move made twice the same way: while a move
    ``a -> b`` is made at positions ``p < q``, replace ``a b Y a b`` by ``a Y' b``
    (``Y'`` = ``Y`` reversed), 2 moves shorter, every cell still visited."""
    D = nbrs.shape[1]
    while True:
        n = w.size
        if n < 3:
            return w
        nxt = np.roll(w, -1)
        key = w * D + np.argmax(nbrs[w] == nxt[:, None], axis=1)  # (cell, exit port)
        first = {}
        hit = None
        for q in range(n):
            k = int(key[q])
            if k in first:
                hit = (first[k], q)
                break
            first[k] = q
        if hit is None:
            return w
        p, q = hit
        w = np.concatenate([w[: p + 1], w[p + 2 : q][::-1], w[q + 1 :]])


def route_of(nbrs: np.ndarray, dist: np.ndarray, order: np.ndarray) -> np.ndarray:
    """int ``[n]``: the route of an order: expanded by shortest paths, then repaired."""
    if order.size == 1:
        return order.copy()
    return repair(expand(nbrs, dist, order), nbrs)


def port_to(nbrs: np.ndarray, c: int, b: int) -> int:
    """The port of cell ``c`` that leads to ``b``."""
    return int(np.flatnonzero(nbrs[c] == b)[0])


def port(back: np.ndarray, nbrs: np.ndarray, a: int, c: int) -> int:
    """The port of ``c`` a robot arrives by when it moves from ``a`` to ``c``."""
    return int(back[a, port_to(nbrs, a, c)])
