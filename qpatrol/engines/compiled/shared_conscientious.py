"""``shared-conscientious`` compiled: go to the open neighbour the team entered longest
ago.

The numpy twin is :mod:`qpatrol.strategies.shared_conscientious` (``choose_min`` of the
world's last visits of the robot's group, as float64, ties by ``u[..., 1]``). It keeps
nothing: the pack is all dummies, and it reads the world's ``last`` int ``[R, G, C]``.
"""

from __future__ import annotations

from numba import njit

from qpatrol.engines.compiled.choice import at_neighbours, least
from qpatrol.engines.compiled.pack import Pack, dummy_pack


def pack(strategy) -> Pack:
    """A pack of dummies: the strategy keeps nothing."""
    return dummy_pack()


def unpack(p: Pack, strategy) -> None:
    """Nothing to copy back."""


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def act(r, ur, nbrs, communication, pos, last, open_mask, choosing, ask, score_k):
    """``ask[k]``: each choosing robot's open neighbour of oldest ``last[r, g]`` (``g`` =
    0 with communication, else k; ``score_k`` float64 ``[K, D]``: scratch)."""
    for k in range(choosing.shape[0]):
        if not choosing[k]:
            ask[k] = -1
            continue
        c = pos[r, k]
        score = at_neighbours(score_k[k], last[r, 0 if communication else k], nbrs, c)
        ask[k] = least(score, open_mask, k, ur[k, 1])
