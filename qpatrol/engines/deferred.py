"""Arrays a fast step of the numpy engine may leave behind while only fast steps run.

Some arrays are written on every step but read only by the general step or at the end
of a run: the world's last visits when one map is shared (they equal the measures'),
a lone robot's occupancy (nothing can be in its way) and the window visit counts (the
visit counts since the window began). A fast step may skip those writes; :meth:`sync`
brings the arrays up to date, in O(runs x cells), and the loop calls it before a
general step and after the last step, and a checkpointer calls it just before it saves
(:attr:`qpatrol.checkpoint.Checkpointer.before_save`: a checkpoint may save the state
after any step).
"""

from __future__ import annotations

import numpy as np

from qpatrol.measures import Measures
from qpatrol.world import State


class Deferred:
    """What a batch's fast step defers, and how to catch up.

    Args:
        s, m: the world and the measures.
        on: defer at all (False: every array is written on every step).
        last: the world's last visits ``s.last`` ``[R, 1, C]`` are the measures'
            ``m.last`` ``[R, C]`` (one map shared by every robot), kept in ``m.last``.
        occ: the occupancy ``s.occ`` ``[R, C]`` follows from ``s.pos`` ``[R, 1]`` (a lone
            robot).

    Attributes:
        base: int ``[R, K, C]``, the visit counts when window counting was deferred
            (None: not deferred); window visits are ``window_visits + visits - base``.
    """

    def __init__(self, s: State, m: Measures, on: bool, last: bool, occ: bool):
        self.s, self.m = s, m
        self.last = on and last
        self.occ = on and occ
        self.on = on
        self.stale = False  # a fast step deferred something since the last sync
        self.base: np.ndarray | None = None

    def mark(self) -> None:
        """Call in every fast step: its deferred writes are pending."""
        self.stale = self.on

    def count_window(self) -> bool:
        """Call before counting a window step's visits: True if the fast step counts
        window visits itself, False if they are deferred (from now on, until sync)."""
        if not self.on:
            return True
        if self.base is None:
            self.base = self.m.visits.copy()
        return False

    def sync(self) -> None:
        """Bring every deferred array up to date."""
        if not self.stale:
            return
        self.stale = False
        s, m = self.s, self.m
        if self.last:
            s.last[:, 0, :] = m.last
        if self.occ:
            s.occ.fill(-1)
            s.occ[np.arange(s.n_runs), s.pos[:, 0]] = 0
        if self.base is not None:
            m.window_visits += m.visits - self.base
            self.base = None
