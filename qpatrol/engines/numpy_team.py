"""The numpy engine's fast step for Q-learning teams with the battery off.

The general step (:func:`qpatrol.run.advance`) loops over the robots of a team several
times per step (entering cells, measures) and over the runs whose token holder moves;
this step does the same work over all robots of all runs at once, on flat views of the
same arrays, so the two may alternate from one step to the next. Rules and arithmetic
are the general step's, operation for operation:

* what robots see and choose: :func:`qpatrol.world.begin_step`,
  :meth:`qpatrol.strategies.qlearning.Strategy.act` (a Q row is one ``take`` from the
  table viewed as ``[R K C 4, 4]``, row ``((r K + k) C + cell) 4 + heading``);
* moves: :func:`qpatrol.traffic.resolve`. A token holder whose asked cell is empty
  moves at once; one that must push runs :func:`qpatrol.traffic.holder_step`. The
  other robots of a run move in priority order into cells empty at that moment, in
  passes until none can; the outcome is computed for all runs at once, without the
  passes: which robot takes a cell several ask for follows from the order, and a robot
  moves if and only if it takes its cell and the chain of robots standing in the cells
  asked for ends in an empty cell (:meth:`Team._resolve`).
* entering cells (dots, last visits, the episode counters of each dot map in robot
  order), learning, measures and recorders as in :func:`qpatrol.world.step`,
  :meth:`~qpatrol.strategies.qlearning.Strategy.learn` and
  :meth:`qpatrol.measures.Measures.observe`.

With collision avoidance off, robots of a run may enter one cell in the same step:
the later ones (in robot order) then find its dot eaten and its last visit at this
step, as in the general step's loop over robots. A step it does not cover (a robot
without a move) is declined before anything changes.
Work per step does not grow with the map; no ``[runs, cells]`` array is allocated.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from qpatrol import traffic
from qpatrol.engines.deferred import Deferred
from qpatrol.engines.flat import FIRST_OF_CODE, any4, code, max4, pick, view
from qpatrol.measures import Measures
from qpatrol.records import Recorder, Tail, update_cols
from qpatrol.timeline import Timeline
from qpatrol.world import Params, State, _end_episodes, per_row


def covers(p: Params, strategy: object) -> bool:
    """True when :class:`Team` applies: qlearning, battery off, on a map where no cell
    is its own neighbour."""
    if p.battery or getattr(strategy, "name", "") != "qlearning":
        return False
    return not (p.neighbors == np.arange(p.n_cells)[:, None]).any()


class Team:
    """The fast step of one batch: constants and flat views (valid for the whole loop:
    neither step rebinds these arrays).

    ``R`` runs, ``K`` robots, ``C`` cells, ``G`` dot maps per run; a robot's flat index
    is ``r K + k``, a cell of run r ``r C + cell`` and a cell of dot map g of run r
    ``(r G + g) C + cell``.
    """

    def __init__(self, p: Params, s: State, strategy: object, m: Measures, defer: bool = True):
        # epsilon: a float, or float [R] per run (np.any once, not every step)
        self.explores = bool(np.any(np.asarray(strategy.epsilon) > 0.0))
        n_runs, k, c, g = s.n_runs, p.n_agents, p.n_cells, p.n_groups
        self.p, self.s, self.strategy, self.m = p, s, strategy, m
        self.taken = 0  # fast steps taken (for tests)
        # one shared map: the world's last visits are the measures'
        self.deferred = Deferred(s, m, defer, last=p.n_groups == 1, occ=False)
        runs = np.arange(n_runs, dtype=np.int64)
        robots = np.arange(n_runs * k, dtype=np.int64)
        self.run_of = robots // k  # int [R K]: run of each robot
        self.k_of = robots % k  # int [R K]: robot index within its run
        self.ks = np.arange(k)  # int [K]
        # int [K, R, K]: at steps t with t % K = j, each robot's place in the turn order
        # when no robot of its run waits, (k - t) % K (see _rank)
        self.rank_by_turn = np.stack(
            [np.broadcast_to((self.ks - j) % k, (n_runs, k)) for j in range(k)]
        )
        self.cell0 = runs * c  # int [R]: first cell of run r in [R C] maps
        self.cell0_rk = self.run_of * c  # int [R K]: the same for each robot
        self.q_row0 = (robots * (c * 4)).reshape(n_runs, k)  # int [R, K]: first Q row
        group = self.run_of * g + (0 if p.communication else self.k_of)
        self.map0 = group * c  # int [R K]: first cell of each robot's dot map
        self.visit0 = robots * c  # int [R K]: first cell of each robot in [R K C] counts
        self.robot0 = (runs * k)[:, None]  # int [R, 1]: flat index of robot 0 of run r
        self.claim = np.zeros(n_runs * c, dtype=np.int64)  # int [R C]: scratch of _resolve
        self.movable = np.ones(k, dtype=bool)  # nobody charges: every robot may be pushed
        self.earlier = np.tri(k, k, -1, dtype=bool)  # bool [K, K]: robot j < robot k
        self.all_runs = np.ones(n_runs, dtype=bool)
        self.nb = p.neighbors  # int [C, 4]: next cell per direction, -1 = wall
        dir_of = (p.neighbors[:, None, :] == p.neighbors[:, :, None]).argmax(axis=2)
        self.dir_of = dir_of.reshape(-1)  # int [C 4]: the first direction to the same cell
        self.nbrs = p.neighbors.reshape(-1)  # int [C 4]
        self.legal = p.wall_legal  # bool [C, 4]
        self.q2 = view(strategy.q, (-1, 4))  # float [R K C 4, 4]
        self.q1 = view(strategy.q, -1)  # float [R K C 4 4]
        self.n1 = view(strategy.n, -1)  # int32 [R K C 4 4]
        self.pos1 = view(s.pos, -1)  # int [R K]
        self.head1 = view(s.head, -1)  # int [R K]
        self.occ = view(s.occ, -1)  # int [R C]
        self.dots = view(s.dots, -1)  # bool [R G C]
        self.last = view(s.last, -1)  # int [R G C]
        self.ep_seen = view(s.ep_seen, -1)  # bool [R G C]
        self.ep_seen_state = view(s.ep_seen_state, -1)  # bool [R G C 4]
        self.m_last = view(m.last, -1)  # int [R C]
        self.visits = view(m.visits, -1)  # int [R K C]
        self.window_visits = view(m.window_visits, -1)  # int [R K C]

    def step(self, u: np.ndarray, rec: Recorder, tail: Tail, timeline: Timeline) -> bool:
        """One team step of every run (all active), in place; False if it does not
        apply this step, and then nothing was changed.

        ``u``: float ``[R, K, 2]``, this step's uniforms.
        """
        s, p, strategy = self.s, self.p, self.strategy
        n_runs, k = s.pos.shape
        pos = s.pos
        # --- what the robots see (world.begin_step) and choose (qlearning.act) -----------
        nb = self.nb.take(pos, axis=0)  # int [R, K, 4]
        legal = nb >= 0
        if p.avoid_collisions:
            occupied = self.occ.take(self.cell0[:, None, None] + np.maximum(nb, 0)) >= 0
            holder = (self.ks == s.token[:, None])[..., None]  # sees every legal move open
            open_ = legal & ~(occupied & ~holder)
            prefer = np.where(any4(open_)[..., None], open_, legal)
        else:
            prefer = legal
        row = self.q_row0 + (pos * 4 + (s.head if strategy.use_heading else 0))
        masked = np.where(prefer, self.q2.take(row, axis=0), -np.inf)
        cand = prefer & (masked == max4(masked)[..., None])
        if self.explores:
            eps = strategy.epsilon if np.ndim(strategy.epsilon) == 0 else strategy.epsilon[:, None]
            cand = np.where((u[..., 0] < eps)[..., None], prefer, cand)
        a, count = pick(cand.reshape(-1, 4), u[..., 1].reshape(-1))
        if np.count_nonzero(count) < count.size:  # a robot without a move
            return False
        a = a.reshape(n_runs, k)  # the asked direction of every robot
        ca = pos * 4 + a  # int [R, K]: flat (cell, direction) index
        want = self.nbrs.take(ca)  # int [R, K]: the cell it asks for
        # --- moves (traffic.resolve) ----------------------------------------------------------
        self.taken += 1
        self.deferred.mark()
        t = s.t = s.t + 1
        prev_pos = self.pos1.copy()  # int [R K]
        prev_head = self.head1.copy()
        after = None  # bool [R K]: an earlier robot of the run entered the same cell
        if p.avoid_collisions:
            res = self._resolve(want)
        else:
            pos[...] = want
            every = np.ones((n_runs, k), dtype=bool)
            res = traffic.Resolution(every, every, np.zeros(n_runs, dtype=bool))
            if k > 1:
                same = (want[:, :, None] == want[:, None, :]) & self.earlier
                after = same.any(axis=2).reshape(-1)
        # --- entering a cell: dots, visits, reward, heading (world.step) ----------------------
        mv = _nonzero(res.moved)  # robots that moved, run by run
        done = _nonzero(res.as_asked)  # a subset of mv: those that moved as asked
        c1 = self.pos1.take(mv)
        if done.size == mv.size:  # traffic.direction_of: the first direction to c1
            d = self.dir_of.take(ca.reshape(-1).take(mv))
        else:
            d = FIRST_OF_CODE.take(code(self.nb.take(prev_pos.take(mv), axis=0) == c1[:, None]))
        gc = self.map0.take(mv) + c1  # the cell on the robot's dot map
        ate = self.dots.take(gc)
        last = (self.m_last if p.n_groups == 1 else self.last).take(gc)  # the same for G = 1
        if after is not None and p.n_groups == 1:  # the earlier robot ate, and visited at t
            ate &= ~after
            last = np.where(after, t, last)
        self.dots[gc] = False
        idle = t - last
        if not self.deferred.last:
            self.last[gc] = t
        self.ep_seen[gc] = True
        self.ep_seen_state[gc * 4 + d] = True
        ep_dots, ep_visits = self._episode_counts(mv, ate, res.moved)
        run = mv // k  # the batch row of each robot that moved (per-run reward weights)
        reward = (
            np.where(ate, p.dot_value.take(c1), 0.0)
            + per_row(p.incremental_value, run)
            * np.minimum(1.0, idle / per_row(p.idle_horizon, run))
            + per_row(p.lambda_weight, run) * ep_dots / ep_visits
        )
        self.head1[mv] = d
        # --- waits, the right of way, episodes ------------------------------------------------
        failed = ~res.as_asked  # every robot asked for a move
        s.wait = np.where(failed, s.wait + 1, 0)
        if p.avoid_collisions and k > 1:
            blocked_by = np.where(failed, self.occ.take(self.cell0[:, None] + want), -1)
            self._pass_token(res, blocked_by)
        s.steps_done.fill(t)
        ended = np.count_nonzero(s.dots_left) < s.dots_left.size
        if p.max_episode_steps and not ended:
            ended = np.minimum.reduce(s.ep_start, axis=None) <= t - p.max_episode_steps
        if ended:
            rec.episodes(t, _end_episodes(s, p))
        # --- learn (qlearning.learn): robots that made the move they chose -------------------
        if done.size:
            if done.size != mv.size:
                reward = self._dense(mv, reward, 0.0).take(done)
            self._learn(t, done, prev_pos, prev_head, a.reshape(-1), reward, rec, mv, ate)
        # --- measures (Measures.observe), recorders --------------------------------------------
        self._measure(t, mv, c1, last if p.n_groups == 1 else None, after)
        if tail.n:
            tail.observe(s)
        if timeline.window:
            seen = SimpleNamespace(t=t, moved=res.moved, pos=s.pos.copy(), active=self.all_runs)
            timeline.observe(seen)
        return True

    def _resolve(self, want: np.ndarray) -> traffic.Resolution:
        """:func:`qpatrol.traffic.resolve` with collision avoidance, every robot asking."""
        s = self.s
        n_runs, k = s.pos.shape
        pos = s.pos
        moved = np.zeros((n_runs, k), dtype=bool)
        as_asked = np.zeros((n_runs, k), dtype=bool)
        res = traffic.Resolution(moved, as_asked, np.zeros(n_runs, dtype=bool))
        # 1. token holders: into an empty asked cell, or pushing the robot in it into an
        # empty neighbour of that cell (the first, N E S W, that is not the holder's: the
        # push search's first find); other pushes one run at a time
        hr = _nonzero(s.token >= 0)
        if hr.size:
            hk = s.token[hr]
            hw = want[hr, hk]
            free = self.occ.take(self.cell0[hr] + hw) < 0
            self._holder_moves(hr[free], hk[free], hw[free], None, want, res)
            hr, hk, hw = hr[~free], hk[~free], hw[~free]
            if hr.size:
                own = pos[hr, hk]
                beyond = self.nb.take(hw, axis=0)  # int [B, 4]: around the asked cell
                there = self.occ.take(self.cell0[hr, None] + np.maximum(beyond, 0))
                empty = (beyond >= 0) & (beyond != own[:, None]) & (there < 0)
                key = code(empty)
                one = key != 0
                to = self.nbrs.take(hw * 4 + FIRST_OF_CODE.take(key))
                self._holder_moves(hr[one], hk[one], hw[one], to[one], want, res)
                for r in hr[~one].tolist():
                    traffic.holder_step(s, self.p, r, int(s.token[r]), want, self.movable, res)
        # 2. the others in turn (priority order, passes until none can move), each into
        # its asked cell if empty at that moment. The outcome, without the turns: of the
        # robots asking for one cell, the first in turn takes it, or if a robot stands
        # in it, the first in turn after that robot (the cell frees up at its turn); a
        # winner moves if its cell is empty or the robot in it moves.
        wanting = ~moved
        in_way = self.occ.take(self.cell0[:, None] + want)  # int [R, K]: robot in the cell
        ahead = self.robot0 + np.maximum(in_way, 0)  # int [R, K]: its flat index
        if k == 1:
            go = wanting & (in_way < 0)
        else:
            rank = self._rank(s.t)
            key = np.where(in_way < 0, rank, (rank - rank.reshape(-1).take(ahead) - 1) % k)
            key = np.where(wanting, key, k)
            cell = self.cell0[:, None] + want
            self.claim[cell] = k  # the least key of the robots asking for each cell
            np.minimum.at(self.claim, cell, key)
            wins = wanting & (key == self.claim.take(cell))
            go = wins & (in_way < 0)
            chain = wins & (in_way >= 0)
            if np.count_nonzero(chain):
                while True:
                    more = go | (chain & go.reshape(-1).take(ahead))
                    if np.array_equal(more, go):
                        break
                    go = more
        g = _nonzero(go)
        if g.size:
            gr, gw = self.run_of.take(g), want.reshape(-1).take(g)
            self.occ[self.cell0.take(gr) + self.pos1.take(g)] = -1
            self.occ[self.cell0.take(gr) + gw] = self.k_of.take(g)
            self.pos1[g] = gw
            moved |= go
            as_asked |= go
        return res

    def _holder_moves(
        self,
        hr: np.ndarray,
        hk: np.ndarray,
        hw: np.ndarray,
        to: np.ndarray | None,
        want: np.ndarray,
        res: traffic.Resolution,
    ) -> None:
        """Token holders ``hk`` of runs ``hr`` (int ``[B]``) move into their asked cells
        ``hw``, the robots standing there (if ``to`` is given) one cell on, into ``to``
        (as :func:`qpatrol.traffic.holder_step` with a push path ``[hw, to]``)."""
        pos, base = self.s.pos, self.cell0.take(hr)
        if to is not None:
            pushed = self.occ.take(base + hw)
            self.occ[base + to] = pushed
            pos[hr, pushed] = to
            res.moved[hr, pushed] = True
            res.as_asked[hr, pushed] = want[hr, pushed] == to
        self.occ[base + pos[hr, hk]] = -1
        self.occ[base + hw] = hk
        pos[hr, hk] = hw
        res.moved[hr, hk] = res.as_asked[hr, hk] = True

    def _rank(self, t: int) -> np.ndarray:
        """int ``[R, K]``: each robot's place (0: first) in the turn order of step t,
        ``argsort(-traffic.priority)``: every robot patrols (battery off), so the longest
        wait goes first, then the turn; in a run where no robot waits, the turn alone."""
        k = self.ks.size
        rank = self.rank_by_turn[t % k]  # (k - t) % K, read-only
        waits = _nonzero(self.s.wait) // k  # the run of each waiting robot, in order
        if waits.size:
            first = np.empty(waits.size, dtype=bool)  # its first waiting robot
            first[0] = True
            np.not_equal(waits[1:], waits[:-1], out=first[1:])
            rows = waits[first]  # runs where a robot waits (np.unique of a sorted array)
            turn = (k - 1) - rank[0]
            prio = (1 << 40) + np.minimum(self.s.wait[rows], 1 << 30) * k + turn
            rank = rank.copy()
            rank[rows] = np.argsort(np.argsort(-prio, axis=1, kind="stable"), axis=1)
        return rank

    def _pass_token(self, res: traffic.Resolution, blocked_by: np.ndarray) -> None:
        """:func:`qpatrol.traffic.pass_token`, every robot of every run having asked for a
        move; ``blocked_by`` int ``[R, K]``: the robot in the way of a failed move, -1."""
        s = self.s
        tok = s.token
        k = self.ks.size
        blocked = ~res.as_asked
        had = tok >= 0
        failed = had & res.push_failed
        # the blocked robot of highest priority at t + 1 in each run (not a holder whose
        # push failed), -1 if none: traffic.priority of the few blocked robots only
        best = np.full(tok.size, -1, dtype=np.int64)
        bl = _nonzero(blocked)
        if bl.size:
            runs, ks = self.run_of.take(bl), self.k_of.take(bl)
            ok = ~(failed.take(runs) & (ks == tok.take(runs)))
            bl, runs, ks = bl[ok], runs[ok], ks[ok]
            turn = (k - 1) - (ks - (s.t + 1)) % k
            key = (1 << 40) + np.minimum(s.wait.reshape(-1).take(bl), 1 << 30) * k + turn
            top = np.full(tok.size, -1, dtype=np.int64)
            np.maximum.at(top, runs, key)
            first = key == top.take(runs)
            best[runs[first]] = ks[first]
        held = self.robot0[:, 0] + np.maximum(tok, 0)  # flat index of the holder
        blocker = np.where(had, blocked_by.reshape(-1).take(held), -1)
        waits = blocked.reshape(-1).take(self.robot0[:, 0] + np.maximum(blocker, 0))
        blocker_waits = (blocker >= 0) & waits
        keep = had & res.as_asked.reshape(-1).take(held) & (s.token_held < self.p.diameter)
        new = np.where(keep, tok, np.where(failed & blocker_waits, blocker, best))
        s.token_held = np.where((new == tok) & (new >= 0), s.token_held + 1, 0)
        s.token = new

    def _episode_counts(
        self, mv: np.ndarray, ate: np.ndarray, moved: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Count the moves ``mv`` into their dot maps' episodes (dots left, dots eaten,
        cells entered); ``(dots, cells)`` int ``[M]``: each robot's episode counts just
        after its own move, robots of a shared map counted in robot order."""
        s = self.s
        if self.p.n_groups == 1:
            n_runs, k = moved.shape
            eaten = _cumsum(self._dense(mv, ate.astype(np.int64), 0).reshape(n_runs, k))
            entered = _cumsum(moved.astype(np.int64))
            dots = (s.ep_dots + eaten).reshape(-1).take(mv)  # ep_dots [R, 1]
            cells = (s.ep_visits + entered).reshape(-1).take(mv)
            s.dots_left -= eaten[:, -1:]
            s.ep_dots += eaten[:, -1:]
            s.ep_visits += entered[:, -1:]
            return dots, cells
        dots_left, ep_dots, ep_visits = (view(x, -1) for x in (s.dots_left, s.ep_dots, s.ep_visits))
        dots_left[mv] -= ate
        ep_dots[mv] += ate
        ep_visits[mv] += 1
        return ep_dots.take(mv), ep_visits.take(mv)

    def _dense(self, idx: np.ndarray, values: np.ndarray, fill: object) -> np.ndarray:
        """``[R K]``: ``values`` at robots ``idx``, ``fill`` elsewhere."""
        out = np.full(self.pos1.size, fill, dtype=values.dtype)
        out[idx] = values
        return out

    def _learn(
        self,
        t: int,
        done: np.ndarray,
        prev_pos: np.ndarray,
        prev_head: np.ndarray,
        asked: np.ndarray,
        reward: np.ndarray,
        rec: Recorder,
        mv: np.ndarray,
        ate: np.ndarray,
    ) -> None:
        """The Q-updates of robots ``done`` (int ``[B]``) that made the move they chose:
        ``reward`` float ``[B]``; ``prev_pos``, ``prev_head``, ``asked`` int ``[R K]``."""
        strategy = self.strategy
        ca = prev_pos.take(done)
        aa = asked.take(done)
        if strategy.use_heading:
            ha, hb = prev_head.take(done), aa
        else:
            ha = hb = np.zeros_like(aa)
        cb = self.pos1.take(done)  # the cell each entered, as asked
        first = self.q_row0.reshape(-1).take(done)
        q_next = self.q2.take(first + cb * 4 + hb, axis=0)
        gamma = per_row(strategy.gamma, done // self.s.pos.shape[1])  # float, or [B] per run
        bootstrap = gamma * max4(np.where(self.legal.take(cb, axis=0), q_next, -np.inf))
        target = reward + bootstrap
        idx = (first + ca * 4 + ha) * 4 + aa
        q_before = self.q1.take(idx)
        n_after = self.n1.take(idx) + 1
        alpha = 1.0 / n_after
        q_after = q_before + alpha * (target - q_before)
        self.q1[idx] = q_after
        self.n1[idx] = n_after
        if rec.wants_updates:
            dot = self._dense(mv, ate, False).take(done)
            q_row = self.q2.take(first + ca * 4 + ha, axis=0)
            cols = update_cols(
                ca, ha, aa, reward, cb, hb, alpha, q_before, q_after, bootstrap, dot, q_row
            )
            rec.updates(t, self.run_of.take(done), self.k_of.take(done), cols)

    def _measure(
        self,
        t: int,
        mv: np.ndarray,
        c1: np.ndarray,
        last: np.ndarray | None,
        after: np.ndarray | None,
    ) -> None:
        """:meth:`qpatrol.measures.Measures.observe` of the moves ``mv`` into cells ``c1``
        (int ``[M]``). ``last``: their cells' last visits as each robot saw them, when every
        robot shares one map (then they are the measures' too), else None; ``after``: bool
        ``[M]``, an earlier robot of the run entered the same cell (None: no two did)."""
        m, s = self.m, self.s
        gm = self.cell0_rk.take(mv) + c1
        if last is not None:
            prev = last
        else:
            prev = self.m_last.take(gm)
            if after is not None:
                prev = np.where(after, t, prev)
        self.m_last[gm] = t
        runs = self.run_of.take(mv)
        np.add.at(m.last_sum, runs, t - prev)
        vi = self.visit0.take(mv) + c1
        if t > m.warmup and self.deferred.count_window():
            np.add.at(self.window_visits, vi, 1)
        np.add.at(self.visits, vi, 1)
        if t > m.warmup:
            seen = prev > 0
            gap = np.where(seen, t - prev, 0)
            np.add.at(m.gap_sum, runs, gap)
            np.add.at(m.gap_count, runs, seen.astype(np.int64))
            np.maximum.at(m.gap_max, runs, gap)
            if t - 1 > m.warmup:
                np.maximum.at(m.worst, runs, t - 1 - prev)
            m.idle_total += m.n_cells * t - m.last_sum
            m.measured += 1
            waiting = _nonzero(s.wait)  # robots with a wait > 0 (max_wait >= 0)
            if waiting.size:
                who = self.run_of.take(waiting)
                np.maximum.at(m.max_wait, who, s.wait.reshape(-1).take(waiting))
                np.add.at(m.wait_total, who, 1)


def _cumsum(x: np.ndarray) -> np.ndarray:
    """``x.cumsum(axis=1)`` of int ``[R, K]`` in place, one column at a time (a reduction
    along a short last axis is slow in numpy)."""
    for j in range(1, x.shape[1]):
        x[:, j] += x[:, j - 1]
    return x


def _nonzero(x: np.ndarray) -> np.ndarray:
    """int ``[N]``: ``np.flatnonzero(x)`` of a C-contiguous ``x``, without its wrappers."""
    return x.reshape(-1).nonzero()[0]
