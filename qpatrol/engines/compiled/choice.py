"""Choosing among a robot's open moves, shared by the compiled strategies.

The numpy twins are :func:`qpatrol.strategies.base.choose_min` (:func:`least`) and
:func:`qpatrol.strategies.learner.choose` (:func:`greatest`), both with
:func:`qpatrol.strategies.learner.pick`:
the open port of least (greatest) score, the j-th of the tied ones in port order (N,
E, S, W on a grid) taken, ``j = floor(u x ties)``; and
:func:`qpatrol.strategies.base.neighbour_values` (:func:`at_neighbours`).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numba.core import types
from numba.extending import overload

from qpatrol.strategies.learner import _NTH, MAX_PORTS

#: The j-th set bit of a candidate mask of up to 8 ports (port p is bit ``1 << p``; on a
#: grid N=1, E=2, S=4, W=8): a port. int64 ``[256, 8]``.
NTH = _NTH.astype(np.int64)
#: The number of set bits of a mask of ports, int64 ``[256]``.
POPCOUNT = np.array([bin(b).count("1") for b in range(1 << MAX_PORTS)], dtype=np.int64)
#: What a score of each direction gets added to leave out the directions not in a 4-bit
#: mask: float64 ``[16, 4]``, 0.0 where direction ``d`` is in mask ``b``, -inf where it
#: is not. ``max`` over ``score[d] + MASKED[b, d]`` is the greatest score of the mask's
#: directions with no branch per direction. Adding 0.0 leaves a finite number as it is
#: but for the sign of a zero (-0.0 + 0.0 is +0.0), which no comparison sees and which a
#: Q-target ``r + gamma x max`` does not see either (its reward is never -0.0).
MASKED = np.array([[0.0 if b >> d & 1 else -np.inf for d in range(4)] for b in range(16)])
#: :data:`MASKED` for masks of up to 8 ports (a patrol graph's): float64 ``[256, 8]``.
MASKED_PORTS = np.array(
    [[0.0 if b >> d & 1 else -np.inf for d in range(MAX_PORTS)] for b in range(1 << MAX_PORTS)]
)


def legal_bits(nbrs: np.ndarray) -> np.ndarray:
    """Each cell's legal moves as a mask of ports (bit ``1 << p``; on a grid N=1, E=2,
    S=4, W=8): int64 ``[C]``, from the neighbours ``nbrs`` int ``[C, D]`` (-1 for a wall,
    D <= 8)."""
    return ((nbrs >= 0) << np.arange(nbrs.shape[1])).sum(axis=1).astype(np.int64)


def ports_of(entry, nd):
    """D, the ports of a cell: 4, a constant of the compiled code, where ``entry`` is
    None (a grid's: :func:`qpatrol.engines.compiled.bundles.compiled_entry`), else
    ``nd`` (the second dimension of the neighbours). Compiled by :func:`_ports_of`."""
    return 4 if entry is None else nd


# (not ``inline="always"``: numba's inlining of these overloads into the loops compiled
# a step of the Q-learning loop with recorders wrongly, tests/test_engines.py's
# test_recorders; as calls they are trivial and the compiler inlines them)
@overload(ports_of)
def _ports_of(entry, nd):
    if isinstance(entry, types.NoneType):
        return lambda entry, nd: 4
    return lambda entry, nd: nd


def heading_of(entry, c, a):
    """The heading after the move out of cell ``c`` by port ``a``: ``entry[c, a]``
    (``Map.entry``, int ``[C, D]``), or on a grid, where ``entry`` is None (the heading
    is the move), ``a`` itself, without a load. Compiled by :func:`_heading_of`."""
    return a if entry is None else entry[c, a]


@overload(heading_of)
def _heading_of(entry, c, a):
    if isinstance(entry, types.NoneType):
        return lambda entry, c, a: a
    return lambda entry, c, a: entry[c, a]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def pick(bits, count, uu):
    """The ``floor(uu x count)``-th port of the mask ``bits`` (``count`` set bits),
    as :func:`qpatrol.strategies.learner.pick`; -1 when ``count`` is 0."""
    if count == 1:  # floor(uu x 1) is 0: the one direction, without the float work
        return NTH[bits, 0]
    if count == 0:
        return -1
    return NTH[bits, min(np.int64(uu * count), count - 1)]


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def any_open(open_mask, k, uu):
    """A uniform choice among robot k's open moves (``open_mask`` bool ``[K, D]``), as
    ``choose_min`` with equal scores; -1 where none is open."""
    bits = 0
    count = 0
    for d in range(open_mask.shape[1]):
        if open_mask[k, d]:
            bits |= 1 << d
            count += 1
    return pick(bits, count, uu)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def least(score, open_mask, k, uu):
    """Robot k's open port of least ``score`` (float64 ``[D]``, in port order: N, E, S,
    W on a grid), ties broken by ``uu``; -1 where none is open (``choose_min`` for one
    robot)."""
    best = np.inf
    for d in range(open_mask.shape[1]):
        if open_mask[k, d] and score[d] < best:
            best = score[d]
    bits = 0
    count = 0
    for d in range(open_mask.shape[1]):
        if open_mask[k, d] and score[d] == best:
            bits |= 1 << d
            count += 1
    return pick(bits, count, uu)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def greatest(score, open_mask, k, explore, uu):
    """Robot k's open port of greatest ``score`` (float64 ``[D]``, port order), or with
    ``explore`` any open port, ties broken by ``uu``; -1 where none is open
    (``learner.choose`` for one robot)."""
    best = -np.inf
    for d in range(open_mask.shape[1]):
        if open_mask[k, d] and score[d] > best:
            best = score[d]
    bits = 0
    count = 0
    for d in range(open_mask.shape[1]):
        if open_mask[k, d] and (explore or score[d] == best):
            bits |= 1 << d
            count += 1
    return pick(bits, count, uu)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def at_neighbours(out, values, nbrs, c):
    """A per-cell map ``values`` ``[C]`` read at the D neighbours of cell ``c`` (cell 0
    for a wall, never chosen), as float64 in port order, into ``out`` ``[D]``; returns
    ``out``."""
    for d in range(nbrs.shape[1]):
        out[d] = np.float64(values[max(nbrs[c, d], 0)])
    return out
