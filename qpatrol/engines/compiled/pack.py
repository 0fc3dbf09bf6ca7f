"""The arrays a compiled strategy keeps, in one fixed layout for every strategy.

The compiled loop is one function for all strategies; each strategy's ``act`` and
``learn`` read the fields of a :class:`Pack` they need, and the others are tiny
dummies of the same dtype and rank, so the loop compiles once.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Pack(NamedTuple):
    """A compiled strategy's arrays (``R`` runs, ``K`` robots, ``C`` cells).

    Attributes:
        fpar: float64 ``[F]``, scalar parameters (e.g. evaporation powers).
        row_f: float64 ``[R, F]``, parameters that may differ between runs (e.g. gamma,
            epsilon).
        ipar: int64 ``[I]``, integer parameters and flags.
        q: float64 ``[R, P, C, S, D]``, a value per (table, cell, state slot, move).
        n: int32 ``[R, P, C, S, D]``, visit counts of the same entries.
        cell_i: int64 ``[R, X, C]``, an integer map per robot or group (e.g. last visits).
        cell_f: float64 ``[R, X, C]``, a float map per robot or group (e.g. pheromone).
        cell_b: bool ``[R, X, C]``, a flag map per robot or group (e.g. dots).
        robot_i: int64 ``[R, K, J]``, integers per robot (e.g. walk, target).
        table_i: int64 ``[W, L]``, a constant table (e.g. walks' cells).
        row_i: int64 ``[W]``, a constant row (e.g. walks' lengths).
        dist: int64 ``[C, C]`` shortest-path lengths (``[1, 1]`` when unused).
        slot: int32 ``[R, K, C + 1]``, the rows of tables kept lazily (``qlearning``).
    """

    fpar: np.ndarray
    row_f: np.ndarray
    ipar: np.ndarray
    q: np.ndarray
    n: np.ndarray
    cell_i: np.ndarray
    cell_f: np.ndarray
    cell_b: np.ndarray
    robot_i: np.ndarray
    table_i: np.ndarray
    row_i: np.ndarray
    dist: np.ndarray
    slot: np.ndarray


#: The fields with a leading runs axis (a strategy's state); the others are constants
#: of the batch. A placeholder of a per-run field has one row whatever the runs.
PER_RUN = ("row_f", "q", "n", "cell_i", "cell_f", "cell_b", "robot_i", "slot")

#: Each field's dtype and rank: every pack has the same, so the loop compiles once.
LAYOUT = {
    "fpar": (np.float64, 1),
    "row_f": (np.float64, 2),
    "ipar": (np.int64, 1),
    "q": (np.float64, 5),
    "n": (np.int32, 5),
    "cell_i": (np.int64, 3),
    "cell_f": (np.float64, 3),
    "cell_b": (np.bool_, 3),
    "robot_i": (np.int64, 3),
    "table_i": (np.int64, 2),
    "row_i": (np.int64, 1),
    "dist": (np.int64, 2),
    "slot": (np.int32, 3),
}


def dummy_pack(**fields: np.ndarray) -> Pack:
    """A :class:`Pack` with the given fields (C-contiguous, of the :data:`LAYOUT`
    dtype and rank) and tiny placeholders for the others."""
    out = {}
    for name, (dtype, rank) in LAYOUT.items():
        a = fields.pop(name, None)
        if a is None:
            a = np.zeros((1,) * rank, dtype=dtype)
        if a.dtype != dtype or a.ndim != rank or not a.flags.c_contiguous:
            raise TypeError(f"Pack.{name}: {a.dtype} rank {a.ndim}; wanted C {dtype} rank {rank}")
        out[name] = a
    if fields:
        raise TypeError(f"Pack has no field {sorted(fields)}")
    return Pack(**out)
