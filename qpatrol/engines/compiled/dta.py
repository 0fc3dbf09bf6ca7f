"""``dta-greedy``, ``dta-ssi`` and ``dta-ssi-part`` compiled: goal followers whose goal
may be any target.

The numpy twin is :class:`qpatrol.strategies.dta.DTA` (:class:`~qpatrol.strategies.dta.Greedy`,
:class:`~qpatrol.strategies.dta.SSI`, :class:`~qpatrol.strategies.dta.PartSSI`),
operation for operation: per robot in robot order, drop a goal in another robot's held
pocket, choose a goal where needed (utilities in float64 in the twin's order; the
allowed candidates of greatest utility, else every candidate's, ties by ``u[k, 1]``;
``dta-ssi-part``: auctions in decreasing utility, :func:`_choose_part`), then travel as
:mod:`~qpatrol.engines.compiled.goals`.

Pack: ``ipar = [kind (GREEDY, SSI, PART)]``; ``fpar = [theta_idleness,
theta_navigation, theta_origin]``; ``robot_i`` int64 ``[R, K, 4]`` each robot's goal,
start cell and (``dta-ssi-part``) center and number of tasks (copied; goals and centers
back by :func:`unpack`); ``cell_i`` int64 ``[R, 2, C]`` (``dta-ssi-part``) each
target's owner (copied, and back), then a scratch row (a robot's tasks, listed);
``row_i`` int64 ``[C]`` the targets (0/1); ``dist`` int64 ``[C, C]``; ``row_f`` float64
``[R, C]`` scratch, each run's candidates' utilities (written and read within one
choice).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from qpatrol.engines.compiled import goals
from qpatrol.engines.compiled.pack import Pack, dummy_pack

GREEDY, SSI, PART = 0, 1, 2
KINDS = {"dta-greedy": GREEDY, "dta-ssi": SSI, "dta-ssi-part": PART}


def pack(strategy) -> Pack:
    """The strategy's weights, targets, distances, goals and start cells (and
    ``dta-ssi-part``'s centers and owners)."""
    kind = KINDS[strategy.name]
    center = strategy.center if kind == PART else strategy.origin
    tasks = np.zeros_like(strategy.goal)
    if kind == PART:
        tasks = (strategy.owner[:, None, :] == np.arange(strategy.n_agents)[None, :, None]).sum(2)
    robot = np.stack([strategy.goal, strategy.origin, center, tasks], axis=2)
    fields = {
        "ipar": np.array([kind], dtype=np.int64),
        "fpar": strategy.theta.astype(np.float64),
        "robot_i": np.ascontiguousarray(robot, dtype=np.int64),
        "row_i": strategy.is_target.astype(np.int64),
        "dist": np.ascontiguousarray(strategy.dist, dtype=np.int64),
        "row_f": np.zeros((strategy.n_runs, strategy.is_target.size)),
    }
    if kind == PART:
        owner = np.stack([strategy.owner, np.zeros_like(strategy.owner)], axis=1)
        fields["cell_i"] = np.ascontiguousarray(owner, dtype=np.int64)
    return dummy_pack(**fields)


def unpack(p: Pack, strategy) -> None:
    """Copy the goals back (and ``dta-ssi-part``'s centers and owners)."""
    strategy.goal = p.robot_i[..., 0].copy()
    if strategy.name == "dta-ssi-part":
        strategy.center = p.robot_i[..., 2].copy()
        strategy.owner = p.cell_i[:, 0, :].copy()


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def _utility(r, k, t, c, x, communication, last, robot, dist, fpar):
    """Robot k's utility of target x from cell c (greater is better)."""
    idle = t - last[r, 0 if communication else k, x]
    u = fpar[0] * np.float64(idle) + fpar[1] * np.float64(dist[c, x])
    if fpar[2] != 0.0:
        u = u + fpar[2] * np.float64(dist[robot[r, k, 1], x])
    return u


@njit(cache=True, nogil=True, _nrt=False)
def _allowed(kind, r, k, c, x, pos, mode, robot, dist):
    """``dta-greedy``: no other robot has x as its goal; ``dta-ssi``: robot k wins x's
    auction (no other robot bids less than its ``dist[c, x]``; a robot that failed,
    ``mode`` GONE, bids nothing)."""
    n_agents = robot.shape[1]
    if kind == GREEDY:
        for j in range(n_agents):
            if j != k and robot[r, j, 0] == x:
                return False
        return True
    mine = dist[c, x]
    for j in range(n_agents):
        if j == k or mode[r, j] == goals.GONE:
            continue
        g = robot[r, j, 0]
        pj = pos[r, j]
        if g == x:
            b = 0
        elif g >= 0:
            b = dist[pj, g] + dist[g, x]
        else:
            b = dist[pj, x]
        if b < mine:
            return False
    return True


@njit(cache=True, nogil=True, _nrt=False)
def _choose(kind, r, k, t, uu, c, battery, p, s, robot, is_target, dist, fpar, score):
    """Robot k's new goal from cell c (``score`` float64 ``[C]``: scratch, the run's own
    row); -1 without a candidate."""
    pos = s.pos
    exchange = p.communication and robot.shape[1] > 1
    best_c = -np.inf
    n_cand = 0
    best_a = -np.inf
    n_allowed = 0
    for x in range(is_target.shape[0]):
        if not is_target[x] or x == c:
            continue
        if battery and goals._held_by_other(r, k, x, p.pocket_of, s.reserved):
            continue
        sc = _utility(r, k, t, c, x, p.communication, s.last, robot, dist, fpar)
        score[x] = sc
        n_cand += 1
        if sc > best_c:
            best_c = sc
        if exchange and _allowed(kind, r, k, c, x, pos, s.mode, robot, dist):
            n_allowed += 1
            if sc > best_a:
                best_a = sc
    if n_cand == 0:
        return -1
    use_allowed = n_allowed > 0
    best = best_a if use_allowed else best_c
    count = 0
    for x in range(is_target.shape[0]):
        if not is_target[x] or x == c:
            continue
        if battery and goals._held_by_other(r, k, x, p.pocket_of, s.reserved):
            continue
        if score[x] != best:
            continue
        if use_allowed and not _allowed(kind, r, k, c, x, pos, s.mode, robot, dist):
            continue
        count += 1
    j = min(np.int64(uu * count), count - 1)
    for x in range(is_target.shape[0]):
        if not is_target[x] or x == c:
            continue
        if battery and goals._held_by_other(r, k, x, p.pocket_of, s.reserved):
            continue
        if score[x] != best:
            continue
        if use_allowed and not _allowed(kind, r, k, c, x, pos, s.mode, robot, dist):
            continue
        if j == 0:
            return x
        j -= 1
    return -1


@njit(cache=True, nogil=True, _nrt=False)
def _center(r, j, here, owner, dist):
    """Robot j's center: the cell among ``here`` and its tasks (the targets it owns) of
    least sum of moves to its tasks (``here``, then the first in cell order, on a tie).
    Lists the tasks in ``owner[r, 1]`` (scratch) first."""
    n_cells = owner.shape[2]
    n_tasks = 0
    for i in range(n_cells):
        if owner[r, 0, i] == j:
            owner[r, 1, n_tasks] = i
            n_tasks += 1
    best = here
    best_sum = 0
    for a in range(n_tasks):
        best_sum += dist[here, owner[r, 1, a]]
    for a in range(n_tasks):
        x = owner[r, 1, a]
        total = 0
        for b in range(n_tasks):
            total += dist[x, owner[r, 1, b]]
        if total < best_sum:
            best_sum = total
            best = x
    return best


@njit(cache=True, nogil=True, _nrt=False)
def _auction(r, k, x, pos, mode, robot, owner, dist):
    """Target x auctioned by robot k (``dta-ssi-part``): the winner (k on a tie, else
    the lowest bidder of least index; a robot that failed, ``mode`` GONE, bids nothing)
    becomes its owner, and the centers of the robots whose tasks changed are computed
    again. Returns the winner."""
    n_agents = robot.shape[1]
    mine = 0
    best = -1
    best_bid = 0
    for j in range(n_agents):
        if j != k and mode[r, j] == goals.GONE:
            continue
        if robot[r, j, 0] == x:
            b = 0
        else:
            b = dist[robot[r, j, 2], x] * (robot[r, j, 3] + 1)
        if j == k:
            mine = b
        elif best < 0 or b < best_bid:
            best = j
            best_bid = b
    winner = k if best < 0 or mine <= best_bid else best
    before = owner[r, 0, x]
    owner[r, 0, x] = winner
    if before != winner:
        robot[r, winner, 3] += 1
        robot[r, winner, 2] = _center(r, winner, pos[r, winner], owner, dist)
        if before >= 0:
            robot[r, before, 3] -= 1
            robot[r, before, 2] = _center(r, before, pos[r, before], owner, dist)
    return winner


@njit(cache=True, nogil=True, _nrt=False)
def _choose_part(r, k, t, uu, c, battery, p, s, robot, owner, is_target, dist, fpar, score):
    """``dta-ssi-part``: robot k auctions its candidates by decreasing utility (equal
    utilities in cell order from ``floor(u C)``, wrapping) until it wins one; the first
    candidate when it wins none (or without communication); -1 without a candidate."""
    n_cells = is_target.shape[0]
    n_cand = 0
    for x in range(n_cells):
        score[x] = -np.inf
        if not is_target[x] or x == c:
            continue
        if battery and goals._held_by_other(r, k, x, p.pocket_of, s.reserved):
            continue
        score[x] = _utility(r, k, t, c, x, p.communication, s.last, robot, dist, fpar)
        n_cand += 1
    if n_cand == 0:
        return -1
    o = min(np.int64(uu * n_cells), n_cells - 1)
    auction = p.communication and robot.shape[1] > 1
    first = -1
    for _ in range(n_cand):
        x = -1
        for y in range(n_cells):
            if score[y] == -np.inf:
                continue
            if x < 0 or score[y] > score[x]:
                x = y
            elif score[y] == score[x] and (y - o + n_cells) % n_cells < (x - o + n_cells) % n_cells:
                x = y
        if first < 0:
            first = x
            if not auction:
                return x
        if _auction(r, k, x, s.pos, s.mode, robot, owner, dist) == k:
            return x
        score[x] = -np.inf
    return first


@njit(cache=True, nogil=True, _nrt=False)
def act(r, t, ur, battery, p, s, w, ipar, fpar, robot, owner, is_target, dist, scratch):
    """``w.ask[k]`` for each robot of run ``r`` at step ``t``: goals chosen robot by
    robot, then the move towards the goal; -1 for robots not choosing."""
    kind = ipar[0]
    pos, open_mask, choosing, ask = s.pos, w.open_mask, w.choosing, w.ask
    goals.forget_gone(r, s.mode, robot)
    for k in range(choosing.shape[0]):
        if not choosing[k]:
            ask[k] = -1
            continue
        c = pos[r, k]
        g = robot[r, k, 0]
        if battery and goals._held_by_other(r, k, g, p.pocket_of, s.reserved):
            g = -1
        if (g < 0 or g == c) and kind == PART:
            g = _choose_part(r, k, t, ur[k, 1], c, battery, p, s, robot, owner, is_target,
                             dist, fpar, scratch[r])  # fmt: skip
        elif g < 0 or g == c:
            g = _choose(kind, r, k, t, ur[k, 1], c, battery, p, s, robot, is_target, dist, fpar,
                        scratch[r])  # fmt: skip
        robot[r, k, 0] = g
        ask[k] = goals._travel(r, k, c, g, battery, p, s, open_mask, dist)
