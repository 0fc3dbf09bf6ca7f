"""The compiled world stepped from outside, a batch at a time: the kernel under
:class:`qpatrol.envs.PatrolVectorEnv` on the compiled engine.

:func:`qpatrol.engines.numba_core.run_block` runs whole blocks of team steps, a
strategy choosing inside the loop. An environment needs the loop cut where a strategy
chooses: the caller sees every run's open moves, then gives a move per robot. So
:func:`step_batch` takes one team step of every active run of a batch in two halves,
each the run_block's phases in run_block's order, called as they are there:

* **finish step t** with the caller's moves (``actions`` ``[B, K]``, the act of an
  "external" strategy: a choosing robot asks for its action when it is a port with a
  move, as :func:`qpatrol.world.step` reads a choice; any other robot asks for none),
  then the battery's asks, the moves (``moves.resolve``, ``moves.meet`` under
  interference), entering cells, the battery's costs and stations, waits and the right
  of way, episodes, robot failures, and the measures, timeline and trajectory;
* **begin step t + 1**: the step's uniforms from each run's PCG64 stream (``pcg``), the
  battery's begin (``stations.begin``), the open moves (``moves.open_moves``) and the
  robots travelling a graph's edge (``moves.travellers``); the action mask is written.

No rule is written here: every rule is a phase's, so a change of a rule reaches the
environment as it reaches ``train``. The list of phase calls is run_block's, and
``tests/test_vector_env.py`` checks that it stays so (the calls of both functions, read
from their source) and that the environment driven by a strategy's choices writes
``train``'s files to the bit.

Each run keeps its step's working arrays between the halves: ``wb``, a
:class:`~qpatrol.engines.compiled.bundles.Work` whose arrays have a leading runs axis
(:func:`batched_work`); the search arrays ``[C]`` (push paths, meetings) are scratch,
shared by the runs of a lane (:func:`row`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from qpatrol.engines import compiled
from qpatrol.engines.compiled import (
    bundles,
    enter,
    episodes,
    fail,
    moves,
    observe,
    pcg,
    stations,
)

#: Fields of :class:`bundles.Work` that are a step's scratch, shared by a lane's runs
#: (the rest are per run: ``wb`` holds them with a leading runs axis).
SCRATCH = ("order", "key", "parent", "seen", "queue", "path", "sink", "score", "mark", "stamp")

#: Columns of the per-step outcome buffer ``out_i`` ``[B, K, OUT_I]``: ask, moved,
#: as_asked, eaten, blocked_by, prev_pos, prev_head, choosing, travelling, waiting for
#: a station.
OUT_I = 10
ASK, MOVED, AS_ASKED, EATEN, BLOCKED_BY, PREV_POS, PREV_HEAD, CHOOSING, TRAVEL, WAITING = range(
    OUT_I
)


def batched_work(n_runs: int, n_agents: int, n_groups: int, n_cells: int, n_ports: int):
    """``(wb, scratch)``: the per-run working arrays (:class:`bundles.Work`, each field
    ``[B, ...]``; scratch fields ``[1, ...]`` placeholders) and one lane's scratch
    (a :class:`bundles.Work` of one run's arrays)."""
    one = bundles.work(n_agents, n_groups, n_cells, n_ports)
    fields = []
    for name, a in zip(bundles.Work._fields, one, strict=True):
        rows = 1 if name in SCRATCH else n_runs
        fields.append(np.ascontiguousarray(np.broadcast_to(a, (rows, *a.shape))).copy())
    return bundles.Work(*fields), one


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def row(wb, x, r):
    """Run ``r``'s :class:`bundles.Work`: its own rows of ``wb``, the scratch ``x``'s."""
    return bundles.Work(
        wb.want[r], wb.ask[r], wb.prev_pos[r], wb.prev_head[r], wb.moved[r], wb.as_asked[r],
        wb.reward[r], wb.eaten[r], wb.blocked_by[r], wb.choosing[r], wb.yielding[r],
        wb.held_back[r], x.order, x.key, wb.open_mask[r], wb.ended[r], x.parent, x.seen,
        x.queue, x.path, wb.uniforms[r], x.sink, x.score, wb.travel[r], x.mark, x.stamp,
        wb.aim[r], wb.swapped[r], wb.progressed[r], wb.mode0[r],
    )  # fmt: skip


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def step_batch(
    lo, hi, t, finish, begin, actions, words, tok_b, p, s, m, o, wb, x, mask, out_i, out_f
):
    """Runs ``lo..hi-1`` of a batch: with ``finish``, team step ``t`` of every active
    run with ``actions`` int ``[B, K]``; with ``begin`` (and the run still active), the
    beginning of step ``t + 1`` (``t`` = 0 with ``finish`` False: the first step's).

    ``words`` uint64 ``[B, 4]``: the runs' PCG64 states, stepped in place; ``tok_b``
    int ``[B]``: each run's holder of the right of way as its step began; ``p``, ``s``,
    ``m``, ``o``: as :func:`~qpatrol.engines.numba_core.run_block`'s; ``wb``, ``x``:
    :func:`batched_work`. Writes ``mask`` int8 ``[B, K, D]`` (1: a move the robot may
    choose, its open moves; all 0 for a robot that does not choose), and the outcome of
    step ``t`` ``out_i`` int ``[B, K, OUT_I]`` and ``out_f`` float ``[B, K]`` (reward).
    Episode ends go to ``o.ep_buf`` and timeline windows to ``o.tl_buf``, as rows of
    the batch. Returns ``(episode rows, timeline rows)``.
    """
    n_agents = s.pos.shape[1]
    battery, avoid, tl_window = p.battery, p.avoid, o.tl_window
    n_ep = np.int64(0)
    n_tl = 0
    for r in range(lo, hi):
        if not s.active[r]:  # (sat out: no outcome, no choice)
            for k in range(n_agents):
                out_f[r, k] = 0.0
                for j in range(OUT_I):
                    out_i[r, k, j] = -1 if j == ASK or j == BLOCKED_BY else 0
                out_i[r, k, PREV_POS] = s.pos[r, k]
                out_i[r, k, PREV_HEAD] = s.head[r, k]
                for d in range(mask.shape[2]):
                    mask[r, k, d] = 0
            continue
        w = row(wb, x, r)
        if finish:
            # --- the act: each choosing robot asks for its action (a port with a move)
            for k in range(n_agents):
                a = actions[r, k]
                ok = w.choosing[k] and a >= 0 and a < p.nbrs.shape[1]
                w.ask[k] = a if ok and p.nbrs[s.pos[r, k], a] >= 0 else -1
                out_i[r, k, CHOOSING] = w.choosing[k]
                out_i[r, k, TRAVEL] = w.travel[k] >= 0
            # --- the rest of step t: run_block's phases, in its order
            tok = tok_b[r]
            t_mod = t % n_agents
            t_next_mod = (t + 1) % n_agents
            never = t + 1
            when = episodes.deadline(s.ep_start[r], p.max_ep, never)
            sums = observe.sums_of(m, r)
            rows_r = observe.rows_of(m, r)
            for k in range(n_agents):  # (a policy's robots are reactive: no goal)
                w.aim[k] = -1
            if p.travels:
                moves.travel_asks(w)
            if battery:
                stations.ask(r, p, s, w)
            for k in range(n_agents):
                w.want[k] = p.nbrs[s.pos[r, k], w.ask[k]] if w.ask[k] >= 0 else -1
            moves.tasks(r, battery, p, s, w)
            handoff = moves.resolve(r, t, tok, t_mod, battery, avoid, p, s, w)
            if p.interaction == bundles.INTERFERENCE:
                moves.meet(r, t, p, s, w)
            if handoff >= 0 and w.swapped[handoff] >= 0 and p.travels:
                moves.turn_back(r, p, s, w)
            enter.all_enter(r, t, p, s, w)
            if battery:
                stations.pay(r, p, s, w)
                stations.end(r, p, s, w)
            moves.progress(r, t, p, s, w)
            waiting, longest = moves.waits(r, battery, avoid, s, w)
            if avoid and n_agents > 1:
                s.token[r], s.token_held[r] = moves.pass_token(
                    r, t + 1, t_next_mod, tok, s.token_held[r], handoff, s, w
                )
            s.steps_done[r] = t
            n_ep, when = episodes.step(r, t, p, s, o.ep_buf, n_ep, w.ended, when, never)
            if t == p.fail_at:  # robots fail, before the step is measured
                waiting, longest = fail.apply(r, s)
            for k in range(n_agents):
                if w.moved[k]:
                    c, vk, wk = s.pos[r, k], m.visits[r, k], m.window_visits[r, k]
                    sums = observe.visit(c, t, m.warmup, p, rows_r, vk, wk, sums)
            failing = t == p.fail_at
            observe.intruders_called(
                r, t, w.prev_pos, s.pos[r], w.moved, p.target, m, s.mode[r], failing
            )
            if tl_window > 0:
                n_tl = observe.timeline(
                    r, t, tl_window, s.pos[r], w.moved, p.target, p.n_targets, o, n_tl
                )
            if battery:
                stations.lowest_charge(r, s, m.min_charge)
            observe.step_measures(r, t, p.n_targets, sums[0], waiting, longest, m)
            if t > m.warmup:
                m.interferences[r] += observe.blocked(w)
                observe.stalls(r, t, s, m)
            observe.trail(r, t, s.pos[r], s.mode[r], o)
            observe.store_sums(m, r, sums)
            # --- the step's outcome, before the next step's beginning clears it
            for k in range(n_agents):
                out_i[r, k, ASK] = w.ask[k]
                out_i[r, k, MOVED] = w.moved[k]
                out_i[r, k, AS_ASKED] = w.as_asked[k]
                out_i[r, k, EATEN] = w.eaten[k]
                out_i[r, k, BLOCKED_BY] = w.blocked_by[k]
                out_i[r, k, PREV_POS] = w.prev_pos[k]
                out_i[r, k, PREV_HEAD] = w.prev_head[k]
                out_i[r, k, WAITING] = battery and (
                    s.mode[r, k] == stations.QUEUED or w.held_back[k]
                )
                out_f[r, k] = w.reward[k]
        for k in range(n_agents):
            for d in range(mask.shape[2]):
                mask[r, k, d] = 0
        if not begin or not s.active[r]:
            continue
        # --- the beginning of step t + 1 (run_block's, up to the strategy's act) -----------
        s_lo, s_hi, inc_lo, inc_hi = words[r, 0], words[r, 1], words[r, 2], words[r, 3]
        inc2_lo, inc2_hi = pcg.double_inc(inc_lo, inc_hi)
        s_lo, s_hi = pcg.step_uniforms((s_lo, s_hi, inc_lo, inc_hi, inc2_lo, inc2_hi), w.uniforms)
        words[r, 0], words[r, 1] = s_lo, s_hi
        tok = s.token[r]
        tok_b[r] = tok
        if battery:
            stations.begin(r, t + 1, p, s, w)
            stations.close_tasks(r, t + 1, p, s)
        moves.open_moves(r, tok, battery, avoid, p, s, w)
        if p.travels:
            moves.travellers(r, p, s, w)
        for k in range(n_agents):
            if w.choosing[k]:
                for d in range(mask.shape[2]):
                    mask[r, k, d] = w.open_mask[k, d]
    return n_ep, n_tl


compiled.key_cache(step_batch, __file__)
