"""Robot failures in the compiled loop: :func:`qpatrol.world.failures.apply`, one run at a
time, operation for operation.

At the end of team step ``p.fail_at`` the robots ``s.failed[r]`` of run ``r`` take mode
``GONE``: no wait, no charging countdown or departure, no station (one they held or
were heading for is free again), no right of way (the token goes to nobody), and their
cell is emptied in ``s.occ`` (``s.pos`` keeps it).
"""

from __future__ import annotations

from numba import njit

GONE = 4  # battery.GONE


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def apply(r, s):
    """The robots ``s.failed[r]`` (int ``[F]``) of run ``r`` fail now. Returns ``(robots
    waiting, longest wait)`` after it (:func:`qpatrol.engines.compiled.moves.waits`'s
    count, for the step's measures)."""
    for i in range(s.failed.shape[1]):
        k = s.failed[r, i]
        s.mode[r, k] = GONE
        s.wait[r, k] = 0
        s.rest[r, k] = 0
        s.depart_left[r, k] = 0
        s.goal[r, k] = -1
        for h in range(s.reserved.shape[1]):
            if s.reserved[r, h] == k:
                s.reserved[r, h] = -1
        if s.token[r] == k:
            s.token[r] = -1
            s.token_held[r] = 0
        c = s.pos[r, k]
        if s.occ[r, c] == k:
            s.occ[r, c] = -1
    waiting = 0
    longest = 0
    for k in range(s.wait.shape[1]):
        if s.wait[r, k] > 0:
            waiting += 1
        longest = max(longest, s.wait[r, k])
    return waiting, longest
