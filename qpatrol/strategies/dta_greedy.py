"""``dta-greedy``: see :mod:`qpatrol.strategies.dta`."""

from __future__ import annotations

from qpatrol.strategies.dta import Greedy as Strategy

__all__ = ["Strategy"]
