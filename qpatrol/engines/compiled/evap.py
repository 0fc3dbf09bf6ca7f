"""``evap`` compiled: ant-like patrol by pheromone evaporation.

The numpy twin is :mod:`qpatrol.strategies.evap`: a robot moves to the open neighbour
with the least pheromone ``amount x keep ** (t - since)`` (ties by ``u[..., 1]``) and
drops one unit on every cell it enters, robots in index order.

``keep ** n`` is not computed here: numba's float ** int multiplies by repeated
squaring, and even float ** float need not be numpy's ``np.power`` (which may use SIMD
code on some CPUs). The pack holds the table ``keep ** arange(...)`` computed by numpy
with the twin's own expression, so every power is numpy's to the bit.

Pack: ``cell_f`` = the strategy's ``amount`` float64 ``[R, G, C]`` and ``cell_i`` = its
``since`` int64 ``[R, G, C]`` (its own arrays, updated in place); ``fpar`` = the powers
``keep ** n`` float64 ``[N]``, n = 0 .. N - 1 (N - 1 = the run's steps, or the first n
where the power is 0.0, beyond which it stays 0.0).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from qpatrol.engines.compiled.choice import least
from qpatrol.engines.compiled.pack import Pack, dummy_pack
from qpatrol.engines.sizes import EVAP_POWERS_MAX


def powers(keep: float, steps: int) -> np.ndarray:
    """float64 ``[N]``: ``keep ** n`` as numpy computes it, for n up to ``steps`` or to
    the first power that is 0.0 (at most :data:`qpatrol.engines.sizes.EVAP_POWERS_MAX` + 1
    entries; longer tables are refused by :func:`qpatrol.engines.compiled_gap`)."""
    table = keep ** np.arange(min(steps, EVAP_POWERS_MAX) + 1, dtype=np.int64)
    zero = np.flatnonzero(table == 0.0)
    if zero.size:
        return np.ascontiguousarray(table[: zero[0] + 1])
    if steps > EVAP_POWERS_MAX:
        raise ValueError(f"evap: {steps} steps need more than {EVAP_POWERS_MAX} powers")
    return table


def pack(strategy) -> Pack:
    """The strategy's own ``amount`` and ``since``, and the powers of ``keep``."""
    return dummy_pack(
        fpar=powers(strategy.keep, int(strategy.cfg["steps"])),
        cell_f=strategy.amount,
        cell_i=strategy.since,
    )


def unpack(p: Pack, strategy) -> None:
    """Nothing to copy back: ``amount`` and ``since`` are the strategy's own arrays."""


@njit(cache=True, nogil=True, _nrt=False)
def _level(amount, since, pw, c, now):
    """The pheromone of cell ``c`` at step ``now`` (``amount``, ``since``: ``[C]``)."""
    return amount[c] * pw[min(now - since[c], pw.shape[0] - 1)]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def act(r, t, ur, nbrs, communication, pos, open_mask, choosing, ask, amount, since, pw, score_k):
    """``ask[k]``: each choosing robot's open neighbour of least pheromone as step ``t``
    starts (at ``t - 1``; ``score_k`` float64 ``[K, D]``: scratch)."""
    now = t - 1
    for k in range(choosing.shape[0]):
        if not choosing[k]:
            ask[k] = -1
            continue
        c = pos[r, k]
        g = 0 if communication else k
        a = amount[r, g]
        s = since[r, g]
        score = score_k[k]
        for d in range(nbrs.shape[1]):
            score[d] = _level(a, s, pw, max(nbrs[c, d], 0), now)
        ask[k] = least(score, open_mask, k, ur[k, 1])


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def learn(r, t, communication, pos, moved, target, amount, since, pw):
    """Each robot that entered a target cell at step ``t`` (``moved`` bool ``[K]``;
    ``target`` bool ``[C]``: every grid cell, a graph's vertices), in index order, adds
    one unit to its group's evaporated pheromone there."""
    for k in range(moved.shape[0]):
        if not moved[k] or not target[pos[r, k]]:
            continue
        g = 0 if communication else k
        c = pos[r, k]
        amount[r, g, c] = _level(amount[r, g], since[r, g], pw, c, t) + 1.0
        since[r, g, c] = t
