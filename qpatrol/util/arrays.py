"""Reading and writing a batch's arrays by flat position, and reductions over ports.

The world's, strategies' and measures' arrays are C-contiguous, with a leading runs
axis ``R``. Picking one element per run, ``a[rows, k, cells]``, is a fancy index over
several arrays, which numpy resolves slowly; the same elements by their flat
position, ``flat(a)[at(a.shape, rows, k, cells)]``, are one gather (and a
scatter when assigned). Reductions over a short last axis (a cell's D ports) are
likewise slow as ``a.max(axis=-1)`` and fast as D elementwise steps
(:func:`port_max`, :func:`port_any`), with the same result.
"""

from __future__ import annotations

import numpy as np


def at(shape: tuple[int, ...], *index: np.ndarray | int) -> np.ndarray:
    """int: the flat (C-order) position of element ``index`` among the leading
    ``len(index)`` axes of an array of ``shape`` (``index``: int arrays and ints,
    broadcast together): ``flat(a, a.ndim - len(index))[at(a.shape, i, j)]`` is
    ``a[i, j]``."""
    pos = index[0]
    for axis in range(1, len(index)):
        pos = pos * shape[axis] + index[axis]
    return pos


def flat(a: np.ndarray, keep: int = 0) -> np.ndarray:
    """``a`` as a view with its leading axes merged into one and its last ``keep`` axes
    kept (``keep=0``: 1-D), to read and write elements by :func:`at`. Raises
    ValueError if ``a`` is not C-contiguous (a copy would lose the writes)."""
    if not a.flags.c_contiguous:
        raise ValueError(f"flat: an array of shape {a.shape} is not C-contiguous")
    return a.reshape((-1, *a.shape[a.ndim - keep :]))


def take_rows(a: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """``flat(a, 1)[pos]``: the rows (last axis) of ``a`` at flat positions ``pos``
    (:func:`at` of ``a.shape[:-1]``), shape ``pos.shape + a.shape[-1:]``; one
    ``np.take``, several times faster than the fancy index."""
    return np.take(flat(a, 1), pos, axis=0)


def port_max(a: np.ndarray) -> np.ndarray:
    """``a.max(axis=-1)`` (the same values, taken left to right) for a short last axis.
    The sign of a zero maximum among zeros of both signs is unspecified, as in numpy."""
    out = a[..., 0].copy()
    for d in range(1, a.shape[-1]):
        np.maximum(out, a[..., d], out=out)
    return out


def port_any(a: np.ndarray) -> np.ndarray:
    """bool: ``a.any(axis=-1)`` for a short last axis."""
    out = a[..., 0].copy()
    for d in range(1, a.shape[-1]):
        out |= a[..., d]
    return out
