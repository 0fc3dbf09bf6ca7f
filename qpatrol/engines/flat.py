"""Building blocks of the numpy engine's fast steps: flat views, a 4-way max, tie-breaks.

Each is the general step's operation (:mod:`qpatrol.learner`) in fewer or cheaper numpy
calls, with the same result to the bit: ``take`` instead of fancy indexing (several
times faster on 2-D tables), a maximum over four columns as three elementwise maxima
instead of a reduction over a short last axis, and the candidate mask of a tie-break
read from the four bytes of a bool row at once.
"""

from __future__ import annotations

import numpy as np

from qpatrol.learner import _NTH


def view(a: np.ndarray, shape: int | tuple[int, ...]) -> np.ndarray:
    """``a`` reshaped without a copy (writes through to ``a``; raises rather than copy)."""
    v = a.view()
    v.shape = shape
    return v


def max4(x: np.ndarray) -> np.ndarray:
    """float ``[...]``: ``x.max(axis=-1)`` of float ``[..., 4]``, the same floats (signed
    zeros included: numpy's reduction keeps the later of equal values, as ``np.maximum``
    does)."""
    return np.maximum(np.maximum(x[..., 0], x[..., 1]), np.maximum(x[..., 2], x[..., 3]))


#: A bool row ``[4]`` read as one uint32 (its bytes), modulo CODE_MOD, is unique per
#: pattern of four booleans: the key of the tables below.
CODE_MOD = 18


def _code(rows: np.ndarray) -> np.ndarray:
    """int ``[B]``: the key of each bool row of ``rows`` ``[B, 4]`` (C-contiguous)."""
    return view(np.ascontiguousarray(rows, dtype=bool), (-1, 4)).view(np.uint32)[:, 0] % CODE_MOD


_PATTERNS = np.array([[m >> d & 1 for d in range(4)] for m in range(16)], dtype=bool)
#: int [CODE_MOD]: the 4-bit mask (N=1, E=2, S=4, W=8) of each key (0 for unused keys).
MASK_OF_CODE = np.zeros(CODE_MOD, dtype=np.int64)
MASK_OF_CODE[_code(_PATTERNS)] = np.arange(16)
assert np.unique(_code(_PATTERNS)).size == 16
#: int [CODE_MOD]: candidates of each key; int [CODE_MOD 4]: its j-th candidate direction.
COUNT_OF_CODE = np.array([bin(int(m)).count("1") for m in MASK_OF_CODE], dtype=np.int64)
NTH_OF_CODE = _NTH[MASK_OF_CODE].reshape(-1)
#: int [CODE_MOD]: the first True of each key, as ``argmax`` gives it (0 for none).
FIRST_OF_CODE = _PATTERNS[MASK_OF_CODE].argmax(axis=1)


def code(rows: np.ndarray) -> np.ndarray:
    """int ``[...]``: the key of each row of bool ``rows`` ``[..., 4]`` (C-contiguous)."""
    return rows.view(np.uint32)[..., 0] % CODE_MOD


def any4(rows: np.ndarray) -> np.ndarray:
    """bool ``[...]``: ``rows.any(axis=-1)`` of bool ``[..., 4]`` (C-contiguous)."""
    return rows.view(np.uint32)[..., 0] != 0


#: float [CODE_MOD]: COUNT_OF_CODE as floats (the same products ``u * count``, without
#: converting the counts on every step).
COUNTF_OF_CODE = COUNT_OF_CODE.astype(np.float64)


def _nth(key: np.ndarray, u: np.ndarray, count: np.ndarray) -> np.ndarray:
    """int ``[B]``: the ``floor(u * count)``-th candidate of each key (0 where count is 0);
    ``count``: the keys' candidates, int or float (the same products)."""
    # learner.pick clips j at count - 1; for u < 1 and count <= 4, u * count rounds to
    # below count, so j never needs it (tests/test_numpy_fast.py checks u = 1 - 2**-53)
    j = (u * count).astype(np.int64)
    return NTH_OF_CODE.take(key * 4 + j)


def pick(cand: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(action [B], count [B])``: :func:`qpatrol.learner.pick` of bool ``cand`` ``[B, 4]``
    (C-contiguous) with uniforms ``u`` ``[B]``; the action is 0 where count is 0."""
    key = code(cand)
    count = COUNT_OF_CODE.take(key)
    return _nth(key, u, count), count


def pick_among(cand: np.ndarray, u: np.ndarray) -> np.ndarray:
    """int ``[B]``: the action of :func:`pick` where every row of ``cand`` has a
    candidate (no counts returned)."""
    key = code(cand)
    return _nth(key, u, COUNTF_OF_CODE.take(key))
