"""The measures in the compiled loop (:meth:`qpatrol.measures.Measures.observe`, the
idleness timeline :class:`qpatrol.measures.timeline.Timeline` and the trajectory ring), after
each team step of a run."""

from __future__ import annotations

from numba import njit

GONE = 4  # qpatrol.world.battery.GONE: a robot that failed


@njit(cache=True, nogil=True, _nrt=False)
def visit(c, t, warmup, p, rows_r, visits_k, window_visits_k, sums):
    """Measures.observe of a robot's visit to cell ``c`` at step ``t``: the robot's visit
    counts ``visits_k`` ``[C]`` take it; if ``c`` is a target (``p.target``) so do the
    run's last visits and per-target intervals (``rows_r``, :func:`rows_of`), the robot's
    ``window_visits_k`` ``[C]`` and the run's ``sums`` (:func:`sums_of`: last_sum,
    gap_sum, gap_count, gap_max, worst, gap_sq, cycle_start, cycle_seen, cycles), which
    it returns updated (inside the window, step ``t`` > ``warmup``, with the visit's gap,
    the worst idleness it ends and the patrol cycle it may complete)."""
    visits_k[c] += 1
    if not p.target[c]:
        return sums
    last_sum, gap_sum, gap_count, gap_max, worst, gap_sq, c_start, c_seen, cycles = sums
    m_last_r, tgap_sum_r, tgap_count_r = rows_r
    prev = m_last_r[c]
    m_last_r[c] = t
    last_sum += t - prev
    if t > warmup:
        window_visits_k[c] += 1
        gap = t - prev if prev > 0 else 0
        gap_sum += gap
        gap_sq += gap * gap
        tgap_sum_r[c] += gap
        if prev > 0:
            gap_count += 1
            tgap_count_r[c] += 1
        gap_max = max(gap_max, gap)
        if t - 1 > warmup:
            worst = max(worst, t - 1 - prev)
        if t >= c_start and prev < c_start:  # a target new to the cycle under way
            c_seen += 1
            if c_seen == p.n_targets:
                cycles += 1
                c_start = t + 1
                c_seen = 0
    return last_sum, gap_sum, gap_count, gap_max, worst, gap_sq, c_start, c_seen, cycles


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def intruders(r, t, prev_pos, pos_r, moved, target, m, mode_r, failing):
    """Measures.intruders: the step's arrivals, then its departures (robots ``[K]``:
    cells before ``prev_pos`` and after ``pos_r``, ``moved``), for the intruder
    measures of ``m`` (off without attack durations). With ``failing`` (the step at
    whose end robots fail), a robot whose mode ``mode_r`` ``[K]`` is GONE leaves the
    cell it stood on before the step and enters none."""
    if m.attack.shape[0] == 0:
        return
    for k in range(moved.shape[0]):  # arrivals, before any departure
        if moved[k] and not (failing and mode_r[k] == GONE):
            arrive(r, pos_r[k], t, target, m)
    for k in range(moved.shape[0]):
        if moved[k] or (failing and mode_r[k] == GONE):
            leave(r, prev_pos[k], t, target, m)


@njit(cache=True, nogil=True, _nrt=False)
def intruders_called(r, t, prev_pos, pos_r, moved, target, m, mode_r, failing):
    """:func:`intruders` compiled once, for the general loop to call (inlined into each
    of its specialisations it made their cold compile longer; the Q-learning team's loop
    inlines it)."""
    intruders(r, t, prev_pos, pos_r, moved, target, m, mode_r, failing)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def arrive(r, c, t, target, m):
    """A robot of run ``r`` entered cell ``c`` in step ``t``: an empty target's empty
    stretch closes (:func:`close`); ``m.empty_since`` counts the robots on it."""
    if target[c]:
        v = m.empty_since[r, c]
        if v >= 0:
            close(r, c, v, t, m)
            m.empty_since[r, c] = -1
        else:
            m.empty_since[r, c] = v - 1


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def leave(r, c, t, target, m):
    """A robot of run ``r`` left cell ``c`` in step ``t``: a target left empty is a
    departure at ``t``."""
    if target[c]:
        v = m.empty_since[r, c] + 1
        m.empty_since[r, c] = t if v == 0 else v


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def close(r, c, e, b, m):
    """Measures._close (:func:`qpatrol.measures.empty_stretch`): target ``c`` of run
    ``r``, empty from the end of step ``e`` on, is entered in step ``b``. Nothing before
    the window. A stretch that began in the window goes to the run's bucket of its gap;
    one that began before it adds the random intruders it hid (the durations
    ascending: none from the first D that leaves none). Its departure goes to the
    target's bucket of its gap, or near the horizon per duration."""
    w = m.warmup
    if b <= w:
        return
    attack = m.attack
    n = attack.shape[0]
    gap = b - e
    j = 0
    while j < n and attack[j] < gap:  # the bucket: the durations below the gap
        j += 1
    if e > w:
        m.stretch_count[r, j] += 1
        m.stretch_sum[r, j] += gap
        if j < n and attack[j] == gap:
            m.stretch_equal[r, j] += 1
    else:
        for i in range(n):
            hid = b - attack[i] - w
            if hid <= 0:
                break
            m.random_missed[r, i] += hid
    if e >= 1 and e >= w:
        if e <= m.horizon - attack[n - 1]:  # counted for every D
            m.gaps[r, c, j] += 1
        else:
            for i in range(n):
                if e <= m.horizon - attack[i]:
                    m.tail_departures[r, c, i] += 1
                    if gap > attack[i]:
                        m.tail_missed[r, c, i] += 1


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def rows_of(m, r):
    """Run ``r``'s rows ``[C]`` of the measures ``m`` that :func:`visit` writes: last
    visits, per-target interval sums and counts."""
    return m.last[r], m.target_gap_sum[r], m.target_gap_count[r]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def sums_of(m, r):
    """The run's sums that :func:`visit` updates, read from the measures ``m``."""
    return (
        m.last_sum[r], m.gap_sum[r], m.gap_count[r], m.gap_max[r], m.worst[r], m.gap_sq[r],
        m.cycle_start[r], m.cycle_seen[r], m.cycles[r],
    )  # fmt: skip


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def store_sums(m, r, sums):
    """Store :func:`visit`'s sums of run ``r`` into the measures ``m``."""
    (
        m.last_sum[r], m.gap_sum[r], m.gap_count[r], m.gap_max[r], m.worst[r], m.gap_sq[r],
        m.cycle_start[r], m.cycle_seen[r], m.cycles[r],
    ) = sums  # fmt: skip


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def blocked(w):
    """Robots that asked for a move (``w.ask``) and did not make it (``w.as_asked``):
    the step's interferences."""
    n = 0
    for k in range(w.ask.shape[0]):
        if w.ask[k] >= 0 and not w.as_asked[k]:
            n += 1
    return n


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def step_measures(r, t, n_targets, sums_last, waiting, longest, m):
    """The step's idleness (``n_targets t - last_sum``) and waits, inside the window."""
    if t > m.warmup:
        m.idle_total[r] += n_targets * t - sums_last
        m.measured[r] += 1
        m.max_wait[r] = max(m.max_wait[r], longest)
        m.wait_total[r] += waiting


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def stalls(r, t, s, m):
    """The run's longest stretch without progress (``m.max_stall``) takes this step's:
    ``t - since`` of each robot on the map (not failed)."""
    for k in range(s.pos.shape[1]):
        if s.mode[r, k] != GONE:
            m.max_stall[r] = max(m.max_stall[r], t - s.since[r, k])


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def trail(r, t, pos_r, mode_r, o):
    """The trajectory ring ``o.tail_pos`` ``[R, N, K]`` takes the robots' cells (-1 for a
    robot that failed: ``mode_r`` ``[K]`` GONE)."""
    if o.tail_n > 0:
        slot = (t - 1) % o.tail_n
        for k in range(pos_r.shape[0]):
            o.tail_pos[r, slot, k] = -1 if mode_r[k] == GONE else pos_r[k]


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def timeline(r, t, tl_window, pos_r, moved, target, n_targets, o, n_tl):
    """Timeline.observe: its own last visits ``o.tl_last`` ``[R, C]`` of the targets
    (``target`` bool ``[C]``, ``n_targets`` of them), peaks inside t's window; a window that closes
    (``Timeline._close``) is a row of ``o.tl_buf`` (run, window, first step, last step,
    idleness sum, worst). Returns the rows written."""
    n_cells = o.tl_last.shape[1]
    start = ((t - 1) // tl_window) * tl_window + 1
    for k in range(pos_r.shape[0]):
        if not moved[k] or not target[pos_r[k]]:
            continue
        c = pos_r[k]
        prev = o.tl_last[r, c]
        o.tl_last[r, c] = t
        o.tl_last_sum[r] += t - prev
        if t - 1 >= start:
            o.tl_worst[r] = max(o.tl_worst[r], t - 1 - prev)
    o.tl_idle_sum[r] += n_targets * t - o.tl_last_sum[r]
    o.tl_steps[r] += 1
    if t % tl_window == 0:
        low = t
        for c in range(n_cells):
            if target[c]:
                low = min(low, o.tl_last[r, c])
        row = o.tl_buf[n_tl]
        row[0] = r
        row[1] = (t - 1) // tl_window
        row[2] = t - o.tl_steps[r] + 1
        row[3] = t
        row[4] = o.tl_idle_sum[r]
        row[5] = max(o.tl_worst[r], t - low)
        n_tl += 1
        o.tl_idle_sum[r] = 0
        o.tl_worst[r] = 0
        o.tl_steps[r] = 0
    return n_tl
