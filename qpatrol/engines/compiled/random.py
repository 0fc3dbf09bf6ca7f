"""``random`` compiled: a uniformly random open move each step.

The numpy twin is :mod:`qpatrol.strategies.random` (``choose_min`` of equal scores over
the open moves, the tie broken by ``u[..., 1]``). No state: the pack is all dummies.
"""

from __future__ import annotations

from numba import njit

from qpatrol.engines.compiled.choice import any_open
from qpatrol.engines.compiled.pack import Pack, dummy_pack


def pack(strategy) -> Pack:
    """A pack of dummies: the strategy keeps nothing."""
    return dummy_pack()


def unpack(p: Pack, strategy) -> None:
    """Nothing to copy back."""


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def act(ur, open_mask, choosing, ask):
    """``ask[k]``: a uniform open move of each choosing robot (by its step's uniform
    ``ur[k, 1]``, ``ur`` float ``[K, 2]``), -1 for the others."""
    for k in range(choosing.shape[0]):
        ask[k] = any_open(open_mask, k, ur[k, 1]) if choosing[k] else -1
