"""``conscientious`` compiled: go to the open neighbour *I* entered longest ago.

The numpy twin is :mod:`qpatrol.strategies.conscientious` (``choose_min`` of the robot's
own last entries, as float64, ties by ``u[..., 1]``; every entered cell is remembered).

Pack: ``cell_i`` = the strategy's ``memory`` int64 ``[R, K, C]`` (the step at which
robot k last entered cell c; its own array, updated in place).
"""

from __future__ import annotations

from numba import njit

from qpatrol.engines.compiled.choice import at_neighbours, least
from qpatrol.engines.compiled.pack import Pack, dummy_pack


def pack(strategy) -> Pack:
    """The strategy's own ``memory`` (updated in place)."""
    return dummy_pack(cell_i=strategy.memory)


def unpack(p: Pack, strategy) -> None:
    """Nothing to copy back: ``memory`` is the strategy's own array."""


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def act(r, ur, nbrs, pos, open_mask, choosing, ask, memory, score_k):
    """``ask[k]``: each choosing robot's open neighbour of oldest ``memory[r, k]``
    (``score_k`` float64 ``[K, D]``: scratch)."""
    for k in range(choosing.shape[0]):
        if not choosing[k]:
            ask[k] = -1
            continue
        c = pos[r, k]
        score = at_neighbours(score_k[k], memory[r, k], nbrs, c)
        ask[k] = least(score, open_mask, k, ur[k, 1])


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def learn(r, t, pos, moved, memory):
    """Each robot that entered a cell at step ``t`` (``moved`` bool ``[K]``) remembers it."""
    for k in range(moved.shape[0]):
        if moved[k]:
            memory[r, k, pos[r, k]] = t
