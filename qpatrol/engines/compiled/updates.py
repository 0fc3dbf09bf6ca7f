"""The Q-update recorder of the compiled loop
(:meth:`qpatrol.measures.records.Recorder.updates`)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def wanted(o, ca):
    """Whether an update of a state at cell ``ca`` is recorded (every update, or the
    watched cells ``o.watched`` bool ``[C]``)."""
    return o.record_all or o.watched[ca]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def record(o, n_up, ints, floats, q_row):
    """Write an update as row ``n_up`` of ``o.up_int`` and ``o.up_float``: ``ints`` (run,
    step, agent, cell, heading, action, next cell, next heading, dot eaten as 0/1),
    ``floats`` (reward, alpha, q_before, q_after, bootstrap) and ``q_row``, the state's
    values after the update (the first four: N, E, S, W on a grid; NaN for actions past
    the map's D). Returns the number of rows now written."""
    ri = o.up_int[n_up]
    for j in range(9):
        ri[j] = ints[j]
    rf = o.up_float[n_up]
    for j in range(5):
        rf[j] = floats[j]
    for d in range(4):
        rf[5 + d] = q_row[d] if d < q_row.shape[0] else np.nan
    return n_up + 1
